"""Complete skeletons: joints the triangulation missed are placed from their rigid neighbours.

A face seen from behind, a foot hidden by the other athlete, a joint no view detected: the
filter bridges short gaps in time, but a joint that is missing for long (or always) stays
invalid, and every consumer (the fit's inputs, the Shelf head, the viewer) then lacks it.
Here such a joint is placed where the person's *own* skeleton puts it:

1. Each joint belongs to a rigid group (``RIGID_GROUPS``: the face with the shoulders, a
   foot with its ankle, knee and the pelvis, the torso), whose other members are the anchors.
2. For a frame where the joint is missing but at least ``min_anchors`` anchors are valid,
   the nearest frames in time where the joint *and* those anchors were measured are the
   exemplars. Each exemplar's anchors are aligned rigidly (Kabsch) onto the frame's anchors,
   and the joint follows; the exemplars are averaged, weighted by how well they aligned.
3. A person whose joint was never measured gets it from an average adult template
   (``TEMPLATE_M``) aligned with a similarity (rotation, translation, scale).

Filled joints are flagged (``Keypoints3D.filled``), valid, with a confidence of
``confidence_scale`` times the mean confidence of their anchors, lowered by the alignment
residual. Nothing measured is changed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.schema.keypoints3d import Keypoints3D

_FACE = ("nose", "left_eye", "right_eye", "left_ear", "right_ear")
_PELVIS = ("left_hip", "right_hip")

RIGID_GROUPS: tuple[tuple[tuple[str, ...], tuple[str, ...]], ...] = (
    (_FACE, _FACE + ("left_shoulder", "right_shoulder") + _PELVIS),
    (("left_shoulder", "right_shoulder", "left_hip", "right_hip"), ("left_shoulder", "right_shoulder") + _PELVIS),
    (
        ("left_heel", "left_big_toe", "left_small_toe"),
        ("left_heel", "left_big_toe", "left_small_toe", "left_ankle", "left_knee") + _PELVIS,
    ),
    (
        ("right_heel", "right_big_toe", "right_small_toe"),
        ("right_heel", "right_big_toe", "right_small_toe", "right_ankle", "right_knee") + _PELVIS,
    ),
)
"""(joints filled, anchors) pairs: a joint of the first tuple is placed from the valid
members of the second (itself excluded)."""

# An average adult standing upright facing +y (so the right side is +x), metres, z up.
TEMPLATE_M: dict[str, tuple[float, float, float]] = {
    "nose": (0.0, 0.10, 1.62),
    "left_eye": (-0.03, 0.08, 1.65),
    "right_eye": (0.03, 0.08, 1.65),
    "left_ear": (-0.075, 0.0, 1.63),
    "right_ear": (0.075, 0.0, 1.63),
    "left_shoulder": (-0.19, 0.0, 1.43),
    "right_shoulder": (0.19, 0.0, 1.43),
    "left_elbow": (-0.22, 0.0, 1.12),
    "right_elbow": (0.22, 0.0, 1.12),
    "left_wrist": (-0.23, 0.0, 0.86),
    "right_wrist": (0.23, 0.0, 0.86),
    "left_hip": (-0.10, 0.0, 0.93),
    "right_hip": (0.10, 0.0, 0.93),
    "left_knee": (-0.10, 0.01, 0.50),
    "right_knee": (0.10, 0.01, 0.50),
    "left_ankle": (-0.10, -0.01, 0.08),
    "right_ankle": (0.10, -0.01, 0.08),
    "left_big_toe": (-0.11, 0.15, 0.02),
    "left_small_toe": (-0.15, 0.12, 0.02),
    "left_heel": (-0.10, -0.06, 0.02),
    "right_big_toe": (0.11, 0.15, 0.02),
    "right_small_toe": (0.15, 0.12, 0.02),
    "right_heel": (0.10, -0.06, 0.02),
}


@dataclass(frozen=True)
class FillConfig:
    """Filling of joints missing after the temporal filter."""

    enabled: bool = True
    """False leaves missing joints invalid."""
    min_anchors: int = 3
    """Valid anchors (>= 3: a rigid alignment needs three points) for a joint to be placed."""
    min_person_joints: int = 6
    """A frame counts as one where the person is seen when at least this many joints are valid."""
    exemplars: int = 6
    """Nearest measured frames (in time) averaged per filled joint (>= 1)."""
    max_residual_m: float = 0.06
    """An exemplar whose anchors align worse than this (RMS, m, > 0) is not used."""
    confidence_scale: float = 0.5
    """Confidence of a filled joint relative to the mean of its anchors', in (0, 1]."""

    def __post_init__(self) -> None:
        if self.min_anchors < 3 or self.exemplars < 1 or self.min_person_joints < 1:
            raise ValueError(
                "FillConfig: min_anchors must be >= 3, exemplars and min_person_joints >= 1, got "
                f"{self.min_anchors}, {self.exemplars}, {self.min_person_joints}"
            )
        if not self.max_residual_m > 0 or not 0 < self.confidence_scale <= 1:
            raise ValueError(
                f"FillConfig: max_residual_m must be > 0 and confidence_scale in (0, 1], got "
                f"{self.max_residual_m}, {self.confidence_scale}"
            )


def rigid_align(src: np.ndarray, dst: np.ndarray, scale: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares transform mapping ``src`` onto ``dst`` (..., n, 3) (Kabsch / Umeyama).

    Returns ``(s, R, t)`` with ``dst ≈ s * src @ R.T + t``: s (...,), R (..., 3, 3) a proper
    rotation, t (..., 3); ``s`` is 1 unless ``scale``.
    """
    mu_s, mu_d = src.mean(axis=-2), dst.mean(axis=-2)
    a, b = src - mu_s[..., None, :], dst - mu_d[..., None, :]
    H = np.einsum("...ni,...nj->...ij", a, b)
    U, S, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("...ij,...jk->...ik", U, Vt)))
    D = np.ones(S.shape)
    D[..., -1] = d
    R = np.einsum("...ji,...j,...kj->...ik", Vt, D, U)
    var = np.maximum((a**2).sum(axis=(-2, -1)), 1e-12)
    s = (S * D).sum(axis=-1) / var if scale else np.ones(S.shape[:-1])
    t = mu_d - s[..., None] * np.einsum("...ij,...j->...i", R, mu_s)
    return s, R, t


def run(kp: Keypoints3D, cfg: FillConfig = FillConfig()) -> Keypoints3D:
    """``kp`` with missing joints of the persons it sees filled (see the module docstring).

    Only joints of ``RIGID_GROUPS`` that are in ``kp.joint_names`` are filled, only in frames
    where the person has ``min_person_joints`` valid joints and ``min_anchors`` valid anchors.
    """
    if not cfg.enabled or kp.n_frames == 0:
        return kp
    names = kp.joint_names
    xyz, valid, conf = kp.xyz_m.copy(), kp.valid.copy(), kp.confidence.copy()
    filled = kp.filled.copy()
    seen = kp.valid.sum(axis=-1) >= cfg.min_person_joints  # (F, P)
    for members, anchors in RIGID_GROUPS:
        for name in members:
            if name not in names:
                continue
            j = names.index(name)
            anc = [names.index(a) for a in anchors if a in names and a != name]
            if len(anc) < cfg.min_anchors:
                continue
            for p in range(kp.n_persons):
                _fill_joint(kp, p, j, np.array(anc), seen[:, p], cfg, xyz, valid, conf, filled)
    return kp.replace(xyz_m=xyz, valid=valid, confidence=conf, filled=filled)


def _fill_joint(
    kp: Keypoints3D,
    p: int,
    j: int,
    anc: np.ndarray,
    seen: np.ndarray,
    cfg: FillConfig,
    xyz: np.ndarray,
    valid: np.ndarray,
    conf: np.ndarray,
    filled: np.ndarray,
) -> None:
    """Fill joint ``j`` of person ``p`` in place (from measured data only: ``kp``)."""
    a_ok = kp.valid[:, p][:, anc]  # (F, A)
    missing = np.flatnonzero(seen & ~kp.valid[:, p, j] & (a_ok.sum(axis=1) >= cfg.min_anchors))
    if missing.size == 0:
        return
    measured = np.flatnonzero(kp.valid[:, p, j] & (a_ok.sum(axis=1) >= cfg.min_anchors))
    for f in missing.tolist():
        if measured.size:
            cand = measured[np.argsort(np.abs(measured - f), kind="stable")]
            cand = cand[(a_ok[cand] & a_ok[f]).sum(axis=1) >= cfg.min_anchors][: cfg.exemplars]
        else:
            cand = measured
        pos, res = _from_exemplars(kp, p, j, anc, f, cand, a_ok) if cand.size else (None, np.inf)
        if pos is None or res > cfg.max_residual_m:
            pos, res = _from_template(kp, p, j, anc, f, a_ok[f])
        if pos is None or res > 2 * cfg.max_residual_m:
            continue
        xyz[f, p, j] = pos
        valid[f, p, j] = True
        filled[f, p, j] = True
        a_conf = kp.confidence[f, p, anc[a_ok[f]]].mean()
        conf[f, p, j] = cfg.confidence_scale * a_conf * float(np.exp(-res / cfg.max_residual_m))


def _from_exemplars(
    kp: Keypoints3D, p: int, j: int, anc: np.ndarray, f: int, cand: np.ndarray, a_ok: np.ndarray
) -> tuple[np.ndarray | None, float]:
    """Weighted mean of the joint carried over from each exemplar frame; (None, inf) if none aligns."""
    pts, res = [], []
    for g in cand:
        use = anc[a_ok[g] & a_ok[f]]
        src, dst = kp.xyz_m[g, p, use], kp.xyz_m[f, p, use]
        s, R, t = rigid_align(src, dst)
        r = float(np.sqrt(np.mean(np.sum((src @ R.T + t - dst) ** 2, axis=-1))))
        pts.append(R @ kp.xyz_m[g, p, j] + t)
        res.append(r)
    if not pts:
        return None, np.inf
    r_arr = np.array(res)
    w = 1.0 / (r_arr + 1e-3) ** 2
    return (np.array(pts) * w[:, None]).sum(axis=0) / w.sum(), float(r_arr.min())


def _from_template(
    kp: Keypoints3D, p: int, j: int, anc: np.ndarray, f: int, a_ok_f: np.ndarray
) -> tuple[np.ndarray | None, float]:
    """The joint from the average-adult template aligned (with scale) on the frame's anchors."""
    names = kp.joint_names
    if names[j] not in TEMPLATE_M:
        return None, np.inf
    use = [int(a) for a in anc[a_ok_f] if names[a] in TEMPLATE_M]
    if len(use) < 3:
        return None, np.inf
    src = np.array([TEMPLATE_M[names[a]] for a in use])
    dst = kp.xyz_m[f, p, use]
    s, R, t = rigid_align(src, dst, scale=True)
    r = float(np.sqrt(np.mean(np.sum((s * src @ R.T + t - dst) ** 2, axis=-1))))
    return s * R @ np.array(TEMPLATE_M[names[j]]) + t, r
