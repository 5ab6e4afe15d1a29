"""Fit SMPL / SMPL-X (the user's model files, ``smpl.body``) to every person's 2D and 3D
keypoints over a whole sequence: the same driver, passes and loss as anny
(``fitting.sequence.fit_sequence``), with SMPL entering through ``SmplFitBody``.

What is SMPL's own: the shape is 10 betas per person (from the triangulated limb lengths,
shared over the sequence, refined jointly); the pelvis is the root; hips/knees/ankles/
shoulders/elbows drive the swing initialisation; keypoints are skeleton joints and skinned
landmark vertices (``smpl.body.keypoints``, pose blend shapes included); the soft joint
limits below act on SMPL's parent-local axis-angle; the mesh moments ignore the pose blend
shapes.

Pose prior: without user files, the soft joint limits below plus ``Lreg``. With files: a GMM
(``FitConfig.pose_prior_path``: our npz layout, or SMPLify's ``gmm_08.pkl``) over the body
pose, and/or VPoser v2 (``FitConfig.vposer_path``, see ``smpl.vposer``), both weighted by ``w_prior``.
The shipped anny prior (``pose_prior_path="builtin"``) is for anny's rig and is skipped here.
"""

from __future__ import annotations

import logging
import pickle
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch

from pipeline.backends.anny.priors import GMMPrior, joint_limit_penalty
from pipeline.backends.fitting.body_model import FitState, PriorFn, Rest, Skeleton
from pipeline.backends.fitting.common import (
    SHAPE_LIMBS,
    PersonObservations,
    ProgressFn,
    joint_idx,
    lbs_moment_factors,
    observed_lengths,
    run_lbfgs,
)
from pipeline.backends.fitting.config import FitConfig
from pipeline.backends.fitting.sequence import FitOutput, fit_sequence
from pipeline.backends.smpl.body import N_BETAS, SmplBody, forward, keypoints, skin, smpl_body
from pipeline.schema.joints import COCO17_FEET

logger = logging.getLogger(__name__)

__all__ = ["SMPL_LIMITS", "SmplFitBody", "SmplFitOutput", "fit_smpl", "load_gmm_prior", "smpl_fit_model"]

_BETA_SCALE = 0.15
"""Scale of the betas among the L-BFGS variables, relative to √frames."""

# Soft joint limits (radians) on SMPL's parent-local axis-angle, in SMPL's canonical axes
# (x: subject's left, y: up, z: forward). Legs and spine flex about x (knee: +x bends the
# shin back; hip: -x lifts the thigh forward; spine: +x bends forward); arms (along +-x in
# the T-pose) twist about x, swing forward/back about y and up/down about z; the elbow
# flexes about y (left: negative, right: positive). Generous ranges (cf. ``anny.priors``):
# they forbid hyper-extended knees/elbows, twisted limbs and a folded spine.
SMPL_LIMITS: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    "left_hip": ((-2.3, 0.6), (-0.8, 0.8), (-0.6, 1.0)),
    "right_hip": ((-2.3, 0.6), (-0.8, 0.8), (-1.0, 0.6)),
    "spine1": ((-0.3, 0.45), (-0.35, 0.35), (-0.3, 0.3)),
    "left_knee": ((-0.05, 2.6), (-0.5, 0.5), (-0.12, 0.12)),
    "right_knee": ((-0.05, 2.6), (-0.5, 0.5), (-0.12, 0.12)),
    "spine2": ((-0.3, 0.45), (-0.35, 0.35), (-0.3, 0.3)),
    "left_ankle": ((-0.8, 0.9), (-0.5, 0.5), (-0.5, 0.5)),
    "right_ankle": ((-0.8, 0.9), (-0.5, 0.5), (-0.5, 0.5)),
    "spine3": ((-0.3, 0.45), (-0.35, 0.35), (-0.3, 0.3)),
    "left_foot": ((-0.6, 0.6), (-0.2, 0.2), (-0.2, 0.2)),
    "right_foot": ((-0.6, 0.6), (-0.2, 0.2), (-0.2, 0.2)),
    "neck": ((-0.5, 0.5), (-0.5, 0.5), (-0.35, 0.35)),
    "left_collar": ((-0.4, 0.4), (-0.5, 0.5), (-0.4, 0.5)),
    "right_collar": ((-0.4, 0.4), (-0.5, 0.5), (-0.5, 0.4)),
    "head": ((-0.6, 0.6), (-0.7, 0.7), (-0.5, 0.5)),
    "left_shoulder": ((-1.6, 1.6), (-2.6, 2.6), (-2.6, 2.6)),
    "right_shoulder": ((-1.6, 1.6), (-2.6, 2.6), (-2.6, 2.6)),
    "left_elbow": ((-1.3, 1.3), (-2.6, 0.05), (-0.15, 0.15)),
    "right_elbow": ((-1.3, 1.3), (-0.05, 2.6), (-0.15, 0.15)),
    "left_wrist": ((-1.0, 1.0), (-0.6, 0.6), (-1.2, 1.2)),
    "right_wrist": ((-1.0, 1.0), (-0.6, 0.6), (-1.2, 1.2)),
    "left_hand": ((-0.5, 0.5), (-0.5, 0.5), (-0.5, 0.5)),
    "right_hand": ((-0.5, 0.5), (-0.5, 0.5), (-0.5, 0.5)),
}

# (driver joint, child keypoint) for the swing initialisation, in FK order.
IK_DRIVERS: tuple[tuple[str, str], ...] = (
    ("left_hip", "left_knee"),
    ("right_hip", "right_knee"),
    ("left_knee", "left_ankle"),
    ("right_knee", "right_ankle"),
    ("left_ankle", "left_big_toe"),
    ("right_ankle", "right_big_toe"),
    ("left_shoulder", "left_elbow"),
    ("right_shoulder", "right_elbow"),
    ("left_elbow", "left_wrist"),
    ("right_elbow", "right_wrist"),
)


class SmplFitOutput(FitOutput):
    """The SMPL fit's output (``FitOutput``): ``shape`` (persons, 10) betas; ``pose_aa``
    (frames, persons, joints, 3) the world pelvis orientation, then ``body_pose``; ``root_m``
    the world pelvis position; see ``smpl_body`` for the frames."""

    @property
    def joint_names(self) -> tuple[str, ...]:
        """SMPL's name for ``bone_names``."""
        return self.bone_names


class _ArrayUnpickler(pickle.Unpickler):
    """Unpickles only numpy arrays and plain containers (SMPLify's ``gmm_08.pkl``)."""

    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("_codecs", "encode"),  # bytes in protocol-2 pickles written by Python 3
        ("numpy", "dtype"),
        ("numpy.core.multiarray", "scalar"),
        ("numpy._core.multiarray", "scalar"),
    }

    def find_class(self, module: str, name: str) -> type:
        if (module, name) in self._ALLOWED:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refusing to unpickle {module}.{name}")


def load_gmm_prior(path: str | Path, n_body_joints: int) -> tuple[GMMPrior, int]:
    """A GMM over the flattened body pose and how many joints (after the pelvis) it covers.

    ``path``: our npz (``means``, ``precisions``, ``weights``) or SMPLify's ``gmm_08.pkl``
    (``means``, ``covars``, ``weights``; 69 dims = SMPL joints 1..23). A 69-dim GMM on a
    21-joint SMPL-X body is marginalised to its first 63 dims (exact for Gaussians).
    ``ValueError`` naming the path when unreadable or of the wrong dimension."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{p}: GMM pose prior file not found (FitConfig.pose_prior_path)")
    if p.suffix == ".pkl":
        try:
            with open(p, "rb") as fh:
                raw = _ArrayUnpickler(fh, encoding="latin1").load()
            means, covars, weights = (
                np.asarray(raw[k], dtype=np.float64) for k in ("means", "covars", "weights")
            )
        except (pickle.UnpicklingError, KeyError, TypeError, EOFError, OSError) as e:
            raise ValueError(f"{p}: not an SMPLify GMM pickle (means, covars, weights): {e}") from e
    else:
        try:
            with np.load(p, allow_pickle=False) as z:
                means, precisions, weights = (
                    np.asarray(z[k], dtype=np.float64) for k in ("means", "precisions", "weights")
                )
                rig = str(z["rig"]) if "rig" in z.files else ""
        except (OSError, KeyError, ValueError) as e:
            raise ValueError(
                f"{p}: cannot read a GMM pose prior (needs means, precisions, weights): {e}"
            ) from e
        if rig and not rig.startswith("smpl"):
            raise ValueError(f"{p}: this GMM pose prior was fitted for rig {rig!r}, not SMPL/SMPL-X")
        covars = np.asarray(np.linalg.inv(precisions), dtype=np.float64)
    d = means.shape[1]
    if d % 3 or d // 3 > n_body_joints:
        if d // 3 == 23 and n_body_joints == 21:
            means, covars, d = means[:, :63], covars[:, :63, :63], 63
        else:
            raise ValueError(f"{p}: GMM of dimension {d} does not fit a body of {n_body_joints} joints")
    return GMMPrior(means, np.linalg.inv(covars), weights / weights.sum()), d // 3


def _lever_arms(body: SmplBody, rest_kp: np.ndarray, rest_joints: np.ndarray) -> np.ndarray:
    """(joints,) RMS distance from each joint to the keypoints its rotation moves (>= 5 cm)."""
    nj = body.n_joints
    anc = np.eye(nj, dtype=bool)  # anc[c, b]: b is c or an ancestor of c
    for c in range(1, nj):
        anc[c] |= anc[body.parents[c]]
    w = body.keypoint_vertices.weights.numpy() > 1e-9
    moved = np.zeros((len(COCO17_FEET), nj), dtype=bool)
    for k in range(len(COCO17_FEET)):
        j = body.kp_joint[k]
        if j >= 0:  # a joint is moved by its strict ancestors
            moved[k] = anc[j] & (np.arange(nj) != j)
        else:
            moved[k] = (w[body.kp_vertex[k]].astype(float) @ anc.astype(float)) > 0
    out = np.full(nj, 0.05)
    for b in range(nj):
        sel = np.flatnonzero(moved[:, b])
        if sel.size:
            out[b] = max(
                0.05, float(np.sqrt((np.linalg.norm(rest_kp[sel] - rest_joints[b], axis=1) ** 2).sum()))
            )
    return out


def _sole_vertices(body: SmplBody, per_foot: int = 24) -> np.ndarray:
    """Up to ``per_foot`` vertices spread over each sole: the lowest 1.5 cm (rest pose, SMPL
    y-up) of the vertices dominated by an ankle or foot joint, heel to toe."""
    v = body.v_template_all
    out = []
    for side in ("left", "right"):
        js = [body.joint_names.index(f"{side}_ankle"), body.joint_names.index(f"{side}_foot")]
        cand = np.flatnonzero(np.isin(body.lbs_weights.argmax(dim=1).numpy(), js))
        sole = cand[v[cand, 1] <= v[cand, 1].min() + 0.015]
        sole = sole[np.argsort(v[sole, 2])]
        out.append(sole[np.linspace(0, len(sole) - 1, min(per_foot, len(sole))).astype(int)])
    return np.concatenate(out)


def _mesh_moments(body: SmplBody, betas: torch.Tensor) -> torch.Tensor:
    """Factor ``L`` (persons, joints * 4, rank) with ``sum_v |dv|^2 = |Z L|^2`` for LBS
    transform differences (as ``anny.fit_terms.MeshMoments``; pose blend shapes ignored)."""
    m = body.module
    rest = [
        m.v_template.detach().double() + torch.einsum("vdb,b->vd", m.shapedirs.detach().double(), b) for b in betas
    ]
    return lbs_moment_factors(rest, body.lbs_weights)


def _fit_betas(body: SmplBody, observations: list[PersonObservations], cfg: FitConfig) -> torch.Tensor:
    """(persons, 10) betas minimising the limb-length differences to the observations."""
    lengths, weights = zip(*(observed_lengths(o) for o in observations), strict=True)
    L, W = torch.as_tensor(np.stack(lengths)), torch.as_tensor(np.stack(weights))
    ia = torch.as_tensor(joint_idx(tuple(a for a, _ in SHAPE_LIMBS)))
    ib = torch.as_tensor(joint_idx(tuple(b for _, b in SHAPE_LIMBS)))
    betas = torch.zeros(len(observations), N_BETAS, dtype=torch.float64, requires_grad=True)

    def closure() -> torch.Tensor:
        kp = _rest_keypoints(body, betas)
        model_len = (kp[:, ia] - kp[:, ib]).norm(dim=-1)
        return (W * (model_len - L).square()).sum() + 1e-4 * betas.square().sum()

    run_lbfgs([betas], closure, cfg.shape_iters, cfg)
    return betas.detach()


def _rest_keypoints(body: SmplBody, betas: torch.Tensor) -> torch.Tensor:
    """(persons, 23, 3) zero-pose keypoints, SMPL frame, pelvis at the origin."""
    n = betas.shape[0]
    J = body.rest_joints(betas)
    eye = torch.eye(3, dtype=torch.float64).expand(n, 3, 3)
    G, x, R = forward(
        body,
        J,
        eye,
        torch.zeros(n, body.n_joints - 1, 3, dtype=torch.float64),
        torch.zeros(n, 3, dtype=torch.float64),
    )
    return keypoints(body, betas, J, G, x, R)


@dataclass(frozen=True)
class _SmplSkeleton(Skeleton):
    """``Skeleton`` plus the local rotation matrices (rows, joints - 1, 3, 3) of the pose
    blend shapes, which skinning the soles needs again."""

    R_local: torch.Tensor


class SmplFitBody:
    """SMPL/SMPL-X (``SmplBody``, float64) for ``fitting.sequence.fit_sequence``; one fit at a
    time (``bind`` fixes the persons)."""

    dtype = torch.float64

    def __init__(self, body: SmplBody) -> None:
        self.body = body
        self.name = self.rig = body.rig
        self.bone_names = body.joint_names
        self.bone_parents = body.parents
        self.neutral_shape = np.zeros(N_BETAS)
        self.ik_drivers = tuple((body.joint_names.index(j), COCO17_FEET.index(k)) for j, k in IK_DRIVERS)
        vertex_bone = body.keypoint_vertices.weights.numpy().argmax(1)[np.maximum(body.kp_vertex, 0)]
        self.landmark_bones = torch.as_tensor(np.where(body.kp_joint >= 0, body.kp_joint, vertex_bone))

    def init_shape(self, observations: list[PersonObservations], cfg: FitConfig) -> torch.Tensor:
        return _fit_betas(self.body, observations, cfg)

    def bind(self, shape: torch.Tensor, row_person: torch.Tensor, cfg: FitConfig) -> None:
        body, nb = self.body, self.body.n_joints
        self._rows, self._betas0 = row_person, shape
        with torch.no_grad():
            self._rest_kp = _rest_keypoints(body, shape).numpy()
            self._rest_J = body.rest_joints(shape).numpy()
        self._rest0 = Rest(torch.as_tensor(self._rest_J)[row_person], shape[row_person])
        lo = torch.full((nb - 1, 3), -1e6, dtype=torch.float64)
        hi = torch.full((nb - 1, 3), 1e6, dtype=torch.float64)
        for j, name in enumerate(body.joint_names[1:]):
            if name in SMPL_LIMITS:
                lo[j] = torch.as_tensor([r[0] for r in SMPL_LIMITS[name]])
                hi[j] = torch.as_tensor([r[1] for r in SMPL_LIMITS[name]])
        self._limits = (torch.eye(3, dtype=torch.float64).expand(nb - 1, 3, 3), lo, hi)
        self._priors: dict[str, PriorFn] = {}
        if cfg.pose_prior_path == "builtin":
            logger.info("smpl fit: the shipped GMM pose prior is for anny's rig; not used for %s", body.body_model)
        elif cfg.pose_prior_path:
            gmm, gmm_joints = load_gmm_prior(cfg.pose_prior_path, nb - 1)
            self._priors["prior"] = lambda state: gmm(state.pose[:, :gmm_joints].reshape(state.pose.shape[0], -1))
        if cfg.vposer_path:
            from pipeline.backends.smpl.vposer import load_vposer

            vposer = load_vposer(cfg.vposer_path)
            self._priors["vposer"] = lambda state: vposer(state.pose[:, :21])
        self._soles = body.vertex_set(_sole_vertices(body))

    def rest_keypoints(self) -> np.ndarray:
        return self._rest_kp

    def lever_arms(self) -> np.ndarray:
        return _lever_arms(self.body, self._rest_kp[0], self._rest_J[0] - self._rest_J[0, 0])

    def landmark_scale(self, cfg: FitConfig) -> float:
        return 1.0  # FitConfig.landmark_step is anny's

    def encode_shape(self, shape: torch.Tensor, s: float) -> torch.Tensor:
        return shape * (_BETA_SCALE * s)

    def decode_shape(self, v: torch.Tensor, s: float) -> torch.Tensor:
        return v / (_BETA_SCALE * s)

    def shape_of(self, u: torch.Tensor) -> torch.Tensor:
        return u

    def shape_deviation(self, u: torch.Tensor) -> torch.Tensor:
        return u

    def rest(self, u: torch.Tensor | None) -> Rest:
        if u is None:
            return self._rest0
        b_rows = u[self._rows]
        return Rest(self.body.rest_joints(u)[self._rows], b_rows)

    def forward(self, rest: Rest, G_root: torch.Tensor, pose: torch.Tensor, root: torch.Tensor) -> Skeleton:
        if rest.shape is None:
            raise ValueError("SmplFitBody.forward: needs the rows' betas (Rest.shape), as SmplFitBody.rest gives")
        G, x, R_local = forward(self.body, rest.joints, G_root, pose, root)
        return _SmplSkeleton(G, x, keypoints(self.body, rest.shape, rest.joints, G, x, R_local), R_local)

    def mesh_moment_factors(self) -> torch.Tensor:
        return _mesh_moments(self.body, self._betas0)

    def sole_heights(self, state: FitState) -> torch.Tensor:
        sk = state.skeleton
        if not isinstance(sk, _SmplSkeleton) or state.rest.shape is None:
            raise ValueError("SmplFitBody.sole_heights: the state was not posed by SmplFitBody.forward")
        return skin(self._soles, state.rest.shape, state.rest.joints, sk.G, sk.x, sk.R_local)[..., 2]

    def joint_limit_penalty(self, state: FitState) -> torch.Tensor:
        return joint_limit_penalty(state.pose, *self._limits)

    def pose_priors(self) -> dict[str, PriorFn]:
        return self._priors


def smpl_fit_model(cfg: FitConfig, body: SmplBody | None = None) -> SmplFitBody:
    """SMPL/SMPL-X for ``fit_sequence``: ``body``, or the model ``cfg.body_model``,
    ``body_model_path`` and ``smpl_gender`` name (``ValueError`` naming what is missing)."""
    return SmplFitBody(body or smpl_body(cfg.body_model, cfg.body_model_path, cfg.smpl_gender))


def fit_smpl(
    observations: list[PersonObservations],
    P_px: np.ndarray,
    cfg: FitConfig,
    body: SmplBody | None = None,
    progress: ProgressFn | None = None,
) -> SmplFitOutput:
    """Fit betas and per-frame pose of every person (``fit_sequence`` with SMPL/SMPL-X).

    Args:
        observations: one entry per person (same frame count), ``COCO17_FEET`` order.
        P_px: (views, 3, 4) projection matrices to *undistorted* pixels.
        cfg: the stage config; ``body_model``, ``body_model_path`` and ``smpl_gender`` pick the
            model unless ``body`` is given.
    Raises ``ValueError`` on inconsistent inputs or missing/unreadable model or prior files.
    """
    out = fit_sequence(smpl_fit_model(cfg, body), observations, P_px, cfg, progress)
    return SmplFitOutput(**{f.name: getattr(out, f.name) for f in fields(out)})
