"""The anny body model (torch): the model and its cache, forward kinematics, pose priors, the
fit and the humanoid built from the body mesh."""
