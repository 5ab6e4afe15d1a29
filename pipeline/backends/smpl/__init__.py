"""SMPL / SMPL-X (the user's model files, torch): the body, the fit and the VPoser prior."""
