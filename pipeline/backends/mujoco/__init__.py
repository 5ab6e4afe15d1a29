"""The physics stage's MuJoCo backend: humanoids, the scene, the reference, iLQR tracking.

The package and ``config`` (the stage's settings) and ``skeleton`` (pure numpy) import no mujoco."""
