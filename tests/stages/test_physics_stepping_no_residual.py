"""A walking humanoid tracked with no residual root force stays up and on target (issue 38).

The input is mocap: athlete 0 of the DeepMimic ``walk`` scene (the pybullet wheel's clip
retargeted to a synthetic boxer, ``make_mocap_scene``), resampled at 100 fps and read at
50 fps: a walk at half speed, 0.48 m/s (Shelf's actors walk at 0.2 m/s). In its 72 frames
(1.44 s) the right foot lifts off, swings 1.23 m and lands. The clip stops before the walk's
loop seam (frame 73 on, where both planted feet jump 8-14 cm sideways); the clip's own
discontinuity (between two key frames the hips and shoulders turn 12 degrees and the landing
left foot jumps 9 cm) falls at the right foot's lift-off and stays in. The physics stage
tracks it with the residual-free recipe of docs/design/physics-effort.md
(``residual.mode: off``, ``solver.ilqr`` ``{max_iter: 30, jacobian_reuse: 2, deriv_every: 1,
fd_interval_s: 0}``), about 20 s here.

Every bound is about 1.5x the largest of five measurements: this clip, and the same with
10 um of Gaussian noise on the input in four draws (the iLQR's result moves with it). At full
speed (1 m/s) the recipe tracks the same swing at 35-41 mm (38 frames, three draws), with
frames up to 62 mm, near the untrackable tolerance (``residual.fallback_tol_m``, 50 mm over
a window), so the test plays it at half speed.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

pytest.importorskip("mujoco")

from pipeline.backends.mujoco.config import ILQRConfig, ResidualConfig, SolverConfig  # noqa: E402
from pipeline.schema.joints import COCO17_FEET  # noqa: E402
from pipeline.schema.keypoints3d import Keypoints3D  # noqa: E402
from pipeline.stages.physics import PhysicsConfig, PhysicsInputs, PhysicsOutput, run  # noqa: E402
from pipeline.synthetic.config import SyntheticConfig  # noqa: E402
from pipeline.synthetic.mocap_scene import make_mocap_scene  # noqa: E402

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("pybullet_data") is None, reason="pybullet (DeepMimic clips) not installed"
)

FPS = 50.0
SLOW = 2
"""The clip is resampled at SLOW x FPS and read at FPS: played SLOW times slower."""
SKIP = 20
"""Frames of the resampled scene before the clip (the right foot planted before its step)."""
N_FRAMES = 72
"""Frames of the clip at FPS; frame 73 on is the loop seam."""
RECIPE = ILQRConfig(max_iter=30, jacobian_reuse=2, deriv_every=1, fd_interval_s=0.0)
"""The residual-free solver settings (``solver.ilqr``) of docs/design/physics-effort.md."""

OFF_FLOOR_M = 0.05
"""A foot whose lowest point (heel, toes) is above this is off the floor (the input's swing
peaks at 8 cm, its stance at 1-3 cm)."""
ON_FLOOR_M = 0.03
"""A foot whose lowest point is below this and moves slower than ``PLANTED_SPEED_M_S`` is planted."""
PLANTED_SPEED_M_S = 0.3
"""Horizontal speed of the foot's centre below which a foot on the floor counts as planted
(the swing peaks at 1.8 m/s)."""
MIN_STEP_M = 0.15
"""Shortest step the input must contain (foot centre, lift-off to landing)."""

MEAN_ERROR_M = 0.034
"""Bound on the mean keypoint-site error against the input (m); measured 17-23 mm."""
PELVIS_DZ_M = 0.033
"""Bound on the simulated root's (pelvis) height difference from the input's pelvis in any
frame (m); measured 19-22 mm (a fall drops it by tens of centimetres)."""
STEP_MISMATCH_M = 0.12
"""Bound on the difference between the simulated and the input step length (m); measured
1.4-7.8 cm, the simulated foot landing short."""
STEP_FRAMES = 2
"""Bound on the difference between the simulated and the input lift-off and landing frames;
measured 0-1."""


def _hips_mid(xyz: np.ndarray) -> np.ndarray:
    """(frames, 3) midpoint of the hips of (frames, joints, 3) ``COCO17_FEET`` points."""
    return 0.5 * (xyz[:, COCO17_FEET.index("left_hip")] + xyz[:, COCO17_FEET.index("right_hip")])


def _foot(xyz: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
    """(frames,) height of the lowest of the foot's heel and toes (m), and (frames, 2)
    horizontal centre of the three, of (frames, joints, 3) points."""
    idx = [COCO17_FEET.index(f"{side}_{k}") for k in ("heel", "big_toe", "small_toe")]
    return xyz[:, idx, 2].min(axis=1), xyz[:, idx, :2].mean(axis=1)


def _steps(xyz: np.ndarray, fps: float) -> dict[str, tuple[int, int, float]]:
    """Each foot that takes a full step in (frames, joints, 3) points: side -> (last planted
    frame before it leaves the floor, first planted frame after it lands, step length in m)."""
    out = {}
    for side in ("left", "right"):
        low, centre = _foot(xyz, side)
        speed = np.r_[0.0, np.linalg.norm(np.diff(centre, axis=0), axis=1) * fps]
        planted = (low < ON_FLOOR_M) & (speed < PLANTED_SPEED_M_S)
        off = np.flatnonzero(low > OFF_FLOOR_M)
        if off.size == 0:
            continue
        before = np.flatnonzero(planted[: off[0]])
        after = np.flatnonzero(planted[off[-1] :]) + off[-1]
        if before.size and after.size:
            lift, land = int(before[-1]), int(after[0])
            out[side] = (lift, land, float(np.linalg.norm(centre[land] - centre[lift])))
    return out


@pytest.fixture(scope="module")
def walk() -> Keypoints3D:
    """The half-speed walk (see the module docstring), one person, ``source="fit"``."""
    scene = make_mocap_scene(
        ("walk", "walk"), SyntheticConfig(seed=0, n_frames=SKIP + N_FRAMES, fps=SLOW * FPS)
    )
    gt, rows = scene.gt, slice(SKIP, SKIP + N_FRAMES)
    return gt.replace(
        person_ids=gt.person_ids[:1],
        frame_indices=np.arange(N_FRAMES),
        fps=FPS,
        xyz_m=gt.xyz_m[rows, :1],
        valid=gt.valid[rows, :1],
        confidence=gt.confidence[rows, :1],
        n_views=gt.n_views[rows, :1],
        reproj_err_px=gt.reproj_err_px[rows, :1],
        source="fit",
    )


@pytest.fixture(scope="module")
def tracked(walk: Keypoints3D) -> PhysicsOutput:
    """The walk tracked by the physics stage with no residual and the recipe's solver."""
    cfg = PhysicsConfig(
        skeleton="keypoints", residual=ResidualConfig(mode="off"), solver=SolverConfig(ilqr=RECIPE)
    )
    return run(PhysicsInputs(walk), cfg)


def test_the_input_takes_a_full_step(walk: Keypoints3D) -> None:
    steps = _steps(walk.xyz_m[:, 0], walk.fps)
    assert "right" in steps, f"no foot lifts off and lands in the clip: {steps}"
    lift, land, length = steps["right"]
    assert length >= MIN_STEP_M and 0 < lift < land < N_FRAMES - 1
    pelvis = _hips_mid(walk.xyz_m[:, 0])
    assert np.linalg.norm(pelvis[-1, :2] - pelvis[0, :2]) / (N_FRAMES / FPS) > 0.3  # walks, m/s


def test_no_window_is_untrackable_and_no_root_force_is_applied(tracked: PhysicsOutput) -> None:
    s = tracked.stats
    assert s["residual_mode"] == "off" and s["windows"] >= 5
    assert s["untrackable_windows"] == 0, f"{s['untrackable_windows']} of {s['windows']} windows untrackable"
    assert s["untrackable_frames"] == 0
    assert s["windows_with_residual"] == 0 and s["kinematic_frames"] == 0 and s["resets"] == 0
    assert s["residual_force_mean_frac_bw"] == 0.0 and s["residual_force_max_frac_bw"] == 0.0
    assert np.abs(tracked.result.residual_root_force).max() == 0.0


def test_stays_up(walk: Keypoints3D, tracked: PhysicsOutput) -> None:
    # One person: qpos = [root xyz, root quaternion, hinges], the root body at the pelvis.
    dz = tracked.result.qpos[:, 2] - _hips_mid(walk.xyz_m[:, 0])[:, 2]
    worst = int(np.abs(dz).argmax())
    assert abs(dz[worst]) < PELVIS_DZ_M, (
        f"root {dz[worst] * 1000:.0f} mm off the input's pelvis height at frame {worst}"
    )


def test_on_target(walk: Keypoints3D, tracked: PhysicsOutput) -> None:
    err = np.linalg.norm(tracked.keypoints.xyz_m - walk.xyz_m, axis=-1)
    assert err.mean() < MEAN_ERROR_M, f"mean keypoint error {err.mean() * 1000:.1f} mm"


def test_the_simulated_foot_steps_too(walk: Keypoints3D, tracked: PhysicsOutput) -> None:
    """A humanoid standing still, or sliding its feet along the floor, takes no step here."""
    lift, land, length = _steps(walk.xyz_m[:, 0], walk.fps)["right"]
    sim = tracked.keypoints.xyz_m[:, 0]
    steps = _steps(sim, walk.fps)
    assert "right" in steps, (
        f"the simulated right foot does not lift off and land (highest {_foot(sim, 'right')[0].max() * 1000:.0f} mm)"
    )
    sim_lift, sim_land, sim_length = steps["right"]
    assert abs(sim_lift - lift) <= STEP_FRAMES and abs(sim_land - land) <= STEP_FRAMES, (
        f"simulated lift-off / landing at frames {sim_lift} / {sim_land}, input {lift} / {land}"
    )
    assert abs(sim_length - length) < STEP_MISMATCH_M, (
        f"step {sim_length:.2f} m simulated, {length:.2f} m input"
    )
