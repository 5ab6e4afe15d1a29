"""Pose priors we can ship for anny's reduced rig: soft anatomical joint limits and a GMM.

Joint limits. Each bone gets a local frame built from the rest skeleton: ``y`` along the
bone (head -> tail), ``x`` the main flexion axis ``unit(y x f)`` where ``f`` is the direction
the bone's tip moves when the joint flexes (knee: backwards, elbow/hip: forwards, ankle: up),
``z = x x y``. A bone's rotation vector, expressed in that frame, is penalised quadratically
outside ``[lo, hi]`` per component (x = flexion, y = twist, z = ab/adduction). Ranges are
generous (typical active ranges of motion, e.g. AAOS tables); they mainly forbid knee and
elbow hyper-extension, twisted limbs and spine folding, which 3D noise otherwise produces.

The statistical prior is a Gaussian mixture over the flattened non-root pose; none is
shipped (the SMPLify GMM and VPoser are under the SMPL licence); users can load their own.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

_FWD = np.array([0.0, -1.0, 0.0])
_BACK = np.array([0.0, 1.0, 0.0])
_UP = np.array([0.0, 0.0, 1.0])

# (name prefix, flexion direction, (lo, hi) x, y, z in radians)
_LIMITS: tuple[tuple[str, np.ndarray, tuple[tuple[float, float], ...]], ...] = (
    ("pelvis", _FWD, ((-0.2, 0.2), (-0.2, 0.2), (-0.2, 0.2))),
    ("upperleg01", _FWD, ((-0.6, 2.3), (-0.8, 0.8), (-0.9, 0.9))),
    ("upperleg02", _FWD, ((-0.1, 0.1), (-0.6, 0.6), (-0.1, 0.1))),
    ("lowerleg01", _BACK, ((-0.05, 2.6), (-0.5, 0.5), (-0.12, 0.12))),
    ("lowerleg02", _BACK, ((-0.1, 0.1), (-0.5, 0.5), (-0.1, 0.1))),
    ("foot", _UP, ((-0.8, 0.9), (-0.5, 0.5), (-0.5, 0.5))),
    ("spine", _FWD, ((-0.3, 0.45), (-0.35, 0.35), (-0.3, 0.3))),
    ("neck", _FWD, ((-0.45, 0.5), (-0.5, 0.5), (-0.35, 0.35))),
    ("head", _FWD, ((-0.6, 0.6), (-0.7, 0.7), (-0.5, 0.5))),
    ("clavicle", _UP, ((-0.4, 0.5), (-0.4, 0.4), (-0.4, 0.4))),
    ("shoulder01", _UP, ((-0.5, 0.6), (-0.5, 0.5), (-0.5, 0.5))),
    ("upperarm01", _FWD, ((-2.6, 2.6), (-1.6, 1.6), (-2.6, 2.6))),
    ("upperarm02", _FWD, ((-0.1, 0.1), (-1.3, 1.3), (-0.1, 0.1))),
    ("lowerarm01", _FWD, ((-0.05, 2.6), (-1.3, 1.3), (-0.15, 0.15))),
    ("lowerarm02", _FWD, ((-0.1, 0.1), (-1.3, 1.3), (-0.1, 0.1))),
    ("wrist", _FWD, ((-1.2, 1.2), (-0.6, 0.6), (-0.8, 0.8))),
)


def _bone_frame(direction: np.ndarray, flex: np.ndarray) -> np.ndarray:
    """(3, 3) matrix whose rows are the local x, y, z axes in world coordinates."""
    y = direction / max(np.linalg.norm(direction), 1e-9)
    x = np.cross(y, flex)
    if np.linalg.norm(x) < 1e-6:  # bone parallel to the flexion direction
        x = np.cross(y, _FWD if abs(y @ _FWD) < 0.9 else _UP)
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    return np.stack([x, y, z])


def joint_limit_tables(
    bone_names: tuple[str, ...], heads: np.ndarray, tails: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-bone local frames and ranges from the rest skeleton.

    Returns frames (bones, 3, 3) (rows = local axes), lo (bones, 3), hi (bones, 3); the
    root is unconstrained (``lo = -inf``, ``hi = inf``).
    """
    nb = len(bone_names)
    frames = np.tile(np.eye(3), (nb, 1, 1))
    lo = np.full((nb, 3), -np.inf)
    hi = np.full((nb, 3), np.inf)
    for b, name in enumerate(bone_names):
        for prefix, flex, ranges in _LIMITS:
            if name.startswith(prefix):
                frames[b] = _bone_frame(tails[b] - heads[b], flex)
                lo[b] = [r[0] for r in ranges]
                hi[b] = [r[1] for r in ranges]
                break
    return frames, lo, hi


def joint_limit_penalty(
    pose_aa: torch.Tensor, frames: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor
) -> torch.Tensor:
    """Sum of squared excess of ``pose_aa`` (n, bones, 3) beyond ``[lo, hi]`` in the local frames."""
    local = torch.einsum("bij,nbj->nbi", frames, pose_aa)
    excess = torch.relu(local - hi) + torch.relu(lo - local)
    return excess.square().sum()


class GMMPrior:
    """Negative log-likelihood (up to a constant) of a Gaussian mixture over poses.

    Uses the max-component approximation of SMPLify: ``min_k 0.5 x^T P_k x - log w_k + c_k``.
    """

    def __init__(self, means: np.ndarray, precisions: np.ndarray, weights: np.ndarray) -> None:
        k, d = means.shape
        if precisions.shape != (k, d, d) or weights.shape != (k,):
            raise ValueError(
                f"GMM prior: means {means.shape}, precisions {precisions.shape}, weights {weights.shape} are inconsistent"
            )
        if np.any(weights <= 0):
            raise ValueError("GMM prior: weights must be positive")
        self.means = torch.as_tensor(means, dtype=torch.float64)
        self.precisions = torch.as_tensor(precisions, dtype=torch.float64)
        sign, logdet = np.linalg.slogdet(precisions)
        if np.any(sign <= 0):
            raise ValueError("GMM prior: precisions must be positive definite")
        self.offset = torch.as_tensor(-np.log(weights / weights.sum()) - 0.5 * logdet, dtype=torch.float64)
        self.dim = d

    @classmethod
    def load(cls, path: str | Path) -> GMMPrior:
        try:
            with np.load(path, allow_pickle=False) as z:
                return cls(np.asarray(z["means"]), np.asarray(z["precisions"]), np.asarray(z["weights"]))
        except (OSError, KeyError) as e:
            raise ValueError(
                f"{path}: cannot read a GMM pose prior (needs means, precisions, weights): {e}"
            ) from e

    @classmethod
    def fit(cls, poses: np.ndarray, n_components: int = 8, seed: int = 0, reg: float = 1e-3) -> GMMPrior:
        """Fit to (n, D) flattened poses with a few EM iterations (full covariances)."""
        rng = np.random.default_rng(seed)
        n, d = poses.shape
        if n < n_components * 2:
            raise ValueError(f"GMM prior: {n} poses are too few for {n_components} components")
        mu = poses[rng.choice(n, n_components, replace=False)]
        cov = np.tile(np.cov(poses.T) + reg * np.eye(d), (n_components, 1, 1))
        w = np.full(n_components, 1.0 / n_components)
        for _ in range(50):
            prec = np.linalg.inv(cov)
            diff = poses[:, None, :] - mu[None]
            maha = np.einsum("nki,kij,nkj->nk", diff, prec, diff)
            logp = np.log(w) - 0.5 * maha + 0.5 * np.linalg.slogdet(prec)[1]
            logp -= logp.max(axis=1, keepdims=True)
            r = np.exp(logp)
            r /= r.sum(axis=1, keepdims=True)
            nk = r.sum(axis=0) + 1e-9
            w = nk / n
            mu = (r.T @ poses) / nk[:, None]
            diff = poses[:, None, :] - mu[None]
            cov = np.einsum("nk,nki,nkj->kij", r, diff, diff) / nk[:, None, None] + reg * np.eye(d)
        return cls(mu, np.linalg.inv(cov), w)

    def save(self, path: str | Path) -> None:
        w = torch.exp(-(self.offset + 0.5 * torch.logdet(self.precisions)))
        np.savez(
            path, means=self.means.numpy(), precisions=self.precisions.numpy(), weights=(w / w.sum()).numpy()
        )

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """(n, D) -> scalar sum over rows of the min-component NLL."""
        if x.shape[-1] != self.dim:
            raise ValueError(f"GMM prior expects poses of dimension {self.dim}, got {x.shape[-1]}")
        diff = x[:, None, :] - self.means[None]
        maha = torch.einsum("nki,kij,nkj->nk", diff, self.precisions, diff)
        return (0.5 * maha + self.offset[None]).min(dim=1).values.sum()


def pose_prior_from_poses(
    pose_aa: np.ndarray, valid: np.ndarray, n_components: int = 8, seed: int = 0
) -> GMMPrior:
    """A GMM over the flattened non-root pose, fitted to trusted fits.

    pose_aa: (frames, persons, bones, 3) (``BodyFit.pose``); valid: (frames, persons) bool.
    Save it with ``GMMPrior.save`` and pass the file as ``FitConfig.pose_prior_path``.
    """
    sel = pose_aa[valid][:, 1:].reshape(int(valid.sum()), -1)
    return GMMPrior.fit(sel, n_components=n_components, seed=seed)
