"""Pose priors we can ship for anny's reduced rig: soft anatomical joint limits and a GMM.

Joint limits. Each bone gets a local frame built from the rest skeleton: ``y`` along the
bone (head -> tail), ``x`` the main flexion axis ``unit(y x f)`` where ``f`` is the direction
the bone's tip moves when the joint flexes (knee: backwards, elbow/hip: forwards, ankle: up),
``z = x x y``. A bone's rotation vector, expressed in that frame, is penalised quadratically
outside ``[lo, hi]`` per component (x = flexion, y = twist, z = ab/adduction). Ranges are
generous (typical active ranges of motion, e.g. AAOS tables); they mainly forbid knee and
elbow hyper-extension, twisted limbs and spine folding, which 3D noise otherwise produces.

The statistical prior is a Gaussian mixture over the axis-angle of a set of bones. The
SMPLify GMM and VPoser are under the SMPL licence, so we ship our own, fitted to the freely
licensed DeepMimic clips (``pipeline.priors.build``, ``data/anny_pose_gmm.npz``); users can load
their own file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from scipy.linalg import solve_triangular

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


BUILTIN_PRIOR = Path(__file__).parent / "data" / "anny_pose_gmm.npz"
"""The shipped GMM pose prior (``FitConfig.pose_prior_path = "builtin"``); rebuilt by
:func:`pipeline.priors.build.build_pose_prior` from DeepMimic clips (zlib)."""


class GMMPrior:
    """Negative log-likelihood of a Gaussian mixture over (a subset of the bones of) a pose.

    ``nll(x) = -log sum_k w_k N(x; mu_k, P_k^-1) - floor`` per frame (nats), with ``floor``
    the smallest value of the mixture's per-component NLL at its own means, so that a frame
    at the most likely mode costs about 0 and a pose ``s`` standard deviations away along
    one axis costs about ``s^2 / 2``. Exact log-sum-exp (smooth, unlike SMPLify's
    max-component approximation), so L-BFGS sees a continuous gradient.

    ``bone_names``: the bones whose axis-angle (3 values each, in this order) make up ``x``;
    None means every non-root bone of the rig (files without metadata).
    """

    def __init__(
        self,
        means: np.ndarray,
        precisions: np.ndarray,
        weights: np.ndarray,
        bone_names: tuple[str, ...] | None = None,
        rig: str = "",
        meta: dict[str, str] | None = None,
    ) -> None:
        k, d = means.shape
        if precisions.shape != (k, d, d) or weights.shape != (k,):
            raise ValueError(
                f"GMM prior: means {means.shape}, precisions {precisions.shape}, weights {weights.shape} are inconsistent"
            )
        for name, arr in (("means", means), ("precisions", precisions), ("weights", weights)):
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"GMM prior: {name} contain NaN or infinite values")
        if np.any(weights <= 0):
            raise ValueError("GMM prior: weights must be positive")
        if bone_names is not None and 3 * len(bone_names) != d:
            raise ValueError(f"GMM prior: {len(bone_names)} bones do not match dimension {d}")
        sign, logdet = np.linalg.slogdet(precisions)
        if np.any(sign <= 0):
            raise ValueError("GMM prior: precisions must be positive definite")
        self.weights = np.asarray(weights, dtype=np.float64) / np.sum(weights)
        self.means = torch.as_tensor(means, dtype=torch.float64)
        self.precisions = torch.as_tensor(precisions, dtype=torch.float64)
        # Cholesky factors: maha = |L^T (x - mu)|^2 with P = L L^T
        self._chol = torch.linalg.cholesky(self.precisions)
        self._chol_cat = self._chol.permute(1, 0, 2).reshape(d, k * d)  # [L_1 | ... | L_K]
        self._mu_chol = torch.einsum("ki,kij->kj", self.means, self._chol)  # (K, D)
        offset = -np.log(self.weights) - 0.5 * logdet
        self.floor = float(offset.min())
        self.offset = torch.as_tensor(offset - self.floor, dtype=torch.float64)
        self.dim = d
        self.bone_names = tuple(bone_names) if bone_names is not None else None
        self.rig = rig
        self.meta = dict(meta or {})
        self._bone_index: torch.Tensor | None = None
        self._cast: dict[torch.dtype, tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}

    @classmethod
    def load(cls, path: str | Path) -> GMMPrior:
        try:
            with np.load(path, allow_pickle=False) as z:
                bones = tuple(str(b) for b in z["bone_names"]) if "bone_names" in z else None
                meta = {k[5:]: str(z[k]) for k in z.files if k.startswith("meta_")}
                return cls(
                    np.asarray(z["means"]),
                    np.asarray(z["precisions"]),
                    np.asarray(z["weights"]),
                    bone_names=bones,
                    rig=str(z["rig"]) if "rig" in z else "",
                    meta=meta,
                )
        except (OSError, KeyError, ValueError) as e:
            raise ValueError(
                f"{path}: cannot read a GMM pose prior (needs means, precisions, weights): {e}"
            ) from e

    @classmethod
    def fit(
        cls, poses: np.ndarray, n_components: int = 8, seed: int = 0, reg: float = 1e-3, max_iter: int = 200
    ) -> GMMPrior:
        """EM on (n, D) flattened poses, full covariances plus ``reg`` on the diagonal
        (rad^2; keeps every component well conditioned and the prior broad enough to
        generalise to unseen motion). k-means++ seeding, deterministic; stops when the mean
        log-likelihood gains less than 1e-6 (relative) or after ``max_iter`` iterations."""
        rng = np.random.default_rng(seed)
        n, d = poses.shape
        if n < n_components * 2:
            raise ValueError(f"GMM prior: {n} poses are too few for {n_components} components")
        seeds = [poses[rng.integers(n)]]
        for _ in range(1, n_components):  # k-means++
            d2 = np.min([((poses - m) ** 2).sum(1) for m in seeds], axis=0)
            seeds.append(poses[rng.choice(n, p=d2 / d2.sum())])
        mu = np.stack(seeds)
        cov = np.tile(np.cov(poses.T) + reg * np.eye(d), (n_components, 1, 1))
        w = np.full(n_components, 1.0 / n_components)
        prev = -np.inf
        for _ in range(max_iter):
            logp = np.empty((n, n_components))
            for k in range(n_components):  # log w_k + log N(x; mu_k, cov_k) up to a constant
                L = np.linalg.cholesky(cov[k])
                z = solve_triangular(L, (poses - mu[k]).T, lower=True)
                logp[:, k] = np.log(w[k]) - 0.5 * (z * z).sum(0) - np.log(np.diag(L)).sum()
            top = logp.max(axis=1, keepdims=True)
            ll = float((top[:, 0] + np.log(np.exp(logp - top).sum(1))).mean())
            r = np.exp(logp - top)
            r /= r.sum(axis=1, keepdims=True)
            nk = r.sum(axis=0) + 1e-9
            w = nk / n
            mu = (r.T @ poses) / nk[:, None]
            for k in range(n_components):
                diff = poses - mu[k]
                cov[k] = (diff * r[:, k : k + 1]).T @ diff / nk[k] + reg * np.eye(d)
            if ll - prev < 1e-6 * abs(ll):
                break
            prev = ll
        return cls(mu, np.linalg.inv(cov), w)

    def save(self, path: str | Path) -> None:
        extra: dict[str, np.ndarray] = {f"meta_{k}": np.asarray(v) for k, v in self.meta.items()}
        if self.bone_names is not None:
            extra["bone_names"] = np.asarray(self.bone_names)
        if self.rig:
            extra["rig"] = np.asarray(self.rig)
        np.savez_compressed(
            path,
            means=self.means.numpy(),
            precisions=self.precisions.numpy(),
            weights=self.weights,
            **extra,  # type: ignore[arg-type]
        )

    def bind(self, rig_bone_names: tuple[str, ...], rig: str = "") -> None:
        """Resolve ``bone_names`` against the rig's bones (``ValueError`` if they differ)."""
        if self.rig and rig and self.rig != rig:
            raise ValueError(
                f"GMM prior was fitted for rig {self.rig!r}, not {rig!r}: set FitConfig.pose_prior_path "
                'to "" or to a prior built for that rig'
            )
        names = self.bone_names if self.bone_names is not None else rig_bone_names[1:]
        missing = [b for b in names if b not in rig_bone_names]
        if missing or 3 * len(names) != self.dim:
            raise ValueError(
                f"GMM prior of dimension {self.dim} does not match the rig's bones (missing {missing})"
            )
        self._bone_index = torch.as_tensor([rig_bone_names.index(b) for b in names])

    def pose_nll(self, pose_aa: torch.Tensor) -> torch.Tensor:
        """(n, rig bones, 3) full poses (root included) -> sum over frames of the NLL; needs
        :meth:`bind` first."""
        if self._bone_index is None:
            raise ValueError("GMM prior: call bind(rig bone names) before pose_nll")
        return self(pose_aa[:, self._bone_index].reshape(pose_aa.shape[0], -1))

    def per_frame(self, x: torch.Tensor) -> torch.Tensor:
        """(n, D) -> (n,) NLL per frame."""
        if x.shape[-1] != self.dim:
            raise ValueError(f"GMM prior expects poses of dimension {self.dim}, got {x.shape[-1]}")
        if not x.is_floating_point():
            x = x.to(self.means.dtype)
        chol_cat, mu_chol, offset = self._factors(x.dtype)
        # z_k = L_k^T (x - mu_k) for every component in one matrix product
        z = (x @ chol_cat).reshape(x.shape[0], *mu_chol.shape) - mu_chol[None]
        e = 0.5 * z.square().sum(-1) + offset[None]
        return -torch.logsumexp(-e, dim=1)

    def _factors(self, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The Cholesky stack, the means in its frame and the offsets in ``dtype`` (the fit
        may run in float32; they are computed in float64 once, then cast and cached)."""
        if dtype not in self._cast:
            self._cast[dtype] = (self._chol_cat.to(dtype), self._mu_chol.to(dtype), self.offset.to(dtype))
        return self._cast[dtype]

    def nll_numpy(self, x: np.ndarray) -> np.ndarray:
        """(n, D) numpy -> (n,) NLL per frame."""
        with torch.no_grad():
            return self.per_frame(torch.as_tensor(x, dtype=torch.float64)).numpy()

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """(n, D) -> scalar sum over rows of the NLL."""
        return self.per_frame(x).sum()


def load_pose_prior(path: str, rig_bone_names: tuple[str, ...], rig: str = "") -> GMMPrior | None:
    """``FitConfig.pose_prior_path`` -> a bound prior: ``"builtin"`` the shipped file, ``""``
    none, anything else a user file (``ValueError`` if unreadable or for another rig)."""
    if not path:
        return None
    file = BUILTIN_PRIOR if path == "builtin" else Path(path)
    if not file.is_file():
        raise ValueError(f"{file}: GMM pose prior file not found (FitConfig.pose_prior_path={path!r})")
    prior = GMMPrior.load(file)
    prior.bind(rig_bone_names, rig)
    return prior


def pose_prior_from_poses(
    pose_aa: np.ndarray, valid: np.ndarray, n_components: int = 8, seed: int = 0
) -> GMMPrior:
    """A GMM over the flattened non-root pose, fitted to trusted fits.

    pose_aa: (frames, persons, bones, 3) (``BodyFit.pose``); valid: (frames, persons) bool.
    Save it with ``GMMPrior.save`` and pass the file as ``FitConfig.pose_prior_path``.
    """
    sel = pose_aa[valid][:, 1:].reshape(int(valid.sum()), -1)
    return GMMPrior.fit(sel, n_components=n_components, seed=seed)
