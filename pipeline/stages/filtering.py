"""Temporal filtering of triangulated joints (paper section 3.2, last paragraph).

``run(raw, cfg) -> filtered`` (``source="filtered"``), in three steps:

1. **Bone lengths**: per person and rigid bone, the robust (median) length over the
   sequence; in frames where a bone deviates by more than ``bone_tolerance`` (relative),
   the less trustworthy endpoint (lower confidence) is dropped so it gets re-filled below.
2. **Cubic splines** (Catmull-Rom) fill short gaps (``spline_max_gap_s``) of each joint trajectory.
3. **Kalman smoother** (constant acceleration, per joint, the three axes together)
   smooths the trajectories and bridges longer gaps (``kalman_max_gap_s``) where
   triangulation failed. The model is linear, so the paper's "extended" Kalman filter
   reduces to the exact linear one; it is solved in batch form (the RTS smoother's
   estimate as one banded linear solve per trajectory). Constraints: measurements that
   jump farther than ``outlier_dist_m`` from the smoothed trajectory are rejected and the
   trajectory re-solved; positions stay above the floor (``z >= floor_z_m``).

The only loop is over trajectories (persons x joints, one banded solve each).
Failure modes: gaps longer than ``kalman_max_gap_s`` and the parts before the first /
after the last measurement of a joint stay invalid (no extrapolation).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.linalg import solveh_banded

from pipeline.geometry.dlt import inv_sym3
from pipeline.schema.bones import BoneLengths
from pipeline.schema.joints import BONES, RIGID_BONES, bone_indices
from pipeline.schema.keypoints3d import Keypoints3D


@dataclass(frozen=True)
class FilterConfig:
    """Temporal filter parameters (times in seconds, so they hold from 25 to 120 fps)."""

    enabled: bool = True
    """False returns the raw keypoints relabelled ``source="filtered"``."""
    bone_tolerance: float = 0.25
    """Relative deviation from the median bone length above which a frame is an outlier
    (0 disables the bone check)."""
    hold_bone_rel: float = 0.02
    """On a re-run with the previous run's bone lengths (``run_holding``'s ``held``), a
    person's median bone length that moved by at most this fraction (>= 0), or by at most
    ``hold_bone_m``, keeps its previous value, so a local edit leaves the other frames
    exactly as they were; both 0 = never."""
    hold_bone_m: float = 0.01
    """The same hold in metres (>= 0): short bones (eyes, heels) move by more than 2 % when
    a few frames change."""
    spline_max_gap_s: float = 0.2
    """Gaps up to this long are filled by cubic-spline interpolation."""
    smoother: Literal["kalman", "none"] = "kalman"
    """``kalman``: constant-acceleration Kalman filter + RTS smoother; ``none``: only fill gaps."""
    kalman_max_gap_s: float = 1.0
    """Gaps up to this long are bridged by the Kalman smoother (longer ones stay invalid)."""
    jerk_std: float = 100.0
    """Process noise: white jerk spectral density sqrt (m/s³/√Hz, > 0). Larger follows fast
    punches more closely, smaller smooths more."""
    meas_std_m: float = 0.012
    """Measurement noise of a triangulated joint of confidence 1 (scaled by 1/confidence)."""
    outlier_dist_m: float = 0.15
    """A measurement farther than this from the smoothed trajectory is an outlier (dropped,
    then the trajectory is re-solved): a joint cannot jump."""
    floor_z_m: float = 0.0
    """Joints never go below this height."""
    ray_iterations: int = 2
    """Gauss-Newton passes that add single-view observations (rays) of joints the
    triangulation missed (0 disables)."""
    ray_gate_px: float = 40.0
    """A single-view observation farther than this from the current estimate is ignored."""
    bone_ray_std_m: float = 0.04
    """A single-view joint next to a located joint is placed on its ray at the bone's median
    length from it (the root nearer the smoothed estimate), with this std (0 disables)."""

    def __post_init__(self) -> None:
        positive = ("jerk_std", "meas_std_m", "outlier_dist_m", "ray_gate_px")
        non_negative = (
            "bone_tolerance",
            "hold_bone_rel",
            "hold_bone_m",
            "spline_max_gap_s",
            "kalman_max_gap_s",
            "ray_iterations",
            "bone_ray_std_m",
        )
        for name in positive + non_negative:
            v = getattr(self, name)
            ok = np.isfinite(v) and (v > 0 if name in positive else v >= 0)
            if not ok:
                raise ValueError(
                    f"FilterConfig.{name} must be {'> 0' if name in positive else '>= 0'}, got {v!r}"
                )
        if self.smoother not in ("kalman", "none"):
            raise ValueError(f"FilterConfig.smoother must be 'kalman' or 'none', got {self.smoother!r}")


@dataclass(frozen=True)
class RayObservations:
    """2D observations of joints seen in a single view (no triangulation possible).

    A single view still pins a joint to its viewing ray (2 of 3 degrees of freedom); the
    smoother uses it through the projection linearised at the current trajectory
    (Gauss-Newton, the "extended" part of the filter).

    Fields:
        P: (views, 3, 4) normalised projections (``pipeline.geometry.dlt.normalized_projections``).
        offset_m: (3,) world offset of ``P``.
        focal_px: (views,) focal lengths (pixels per normalised unit).
        mask: (frames, persons, joints) bool: an observation exists.
        view: (frames, persons, joints) int view of the observation.
        xn: (frames, persons, joints, 2) normalised undistorted image coordinates.
        conf: (frames, persons, joints) 2D confidence.
        pixel_std_px: 2D noise (std, pixels) of a confidence-1 keypoint.
    """

    P: np.ndarray
    offset_m: np.ndarray
    focal_px: np.ndarray
    mask: np.ndarray
    view: np.ndarray
    xn: np.ndarray
    conf: np.ndarray
    pixel_std_px: float


def run(
    raw: Keypoints3D,
    cfg: FilterConfig = FilterConfig(),
    meas_info: np.ndarray | None = None,
    rays: RayObservations | None = None,
) -> Keypoints3D:
    """``run_holding`` without held bone lengths: the filtered keypoints only."""
    return run_holding(raw, cfg, meas_info, rays)[0]


def run_holding(
    raw: Keypoints3D,
    cfg: FilterConfig = FilterConfig(),
    meas_info: np.ndarray | None = None,
    rays: RayObservations | None = None,
    held: BoneLengths | None = None,
) -> tuple[Keypoints3D, BoneLengths]:
    """Filter ``raw`` (any source) into ``source="filtered"`` keypoints of the same extent,
    and return the per-person median bone lengths it used.

    Args:
        raw: keypoints to filter (``frame_indices`` consecutive).
        cfg: filter config.
        meas_info: optional (frames, persons, joints, 3, 3) information matrices of the raw
            points (``pipeline.geometry.dlt.point_information``); without it every point is
            isotropic with std ``meas_std_m / confidence``.
        rays: optional single-view observations of joints the raw data lacks (used only
            with the Kalman smoother, for ``ray_iterations`` Gauss-Newton passes).
        held: bone lengths of a previous run of the same persons: a median within
            ``hold_bone_rel`` of its held value keeps the held value (``hold_lengths``).
    Raises ``ValueError`` if ``raw.frame_indices`` are not consecutive (the filter needs a
    uniform time step) or ``meas_info`` has the wrong shape.
    """
    if raw.n_frames > 1 and np.any(np.diff(raw.frame_indices) != 1):
        raise ValueError(
            f"filtering needs consecutive frame_indices, got gaps in {raw.frame_indices[:10]}..."
        )
    same = held is not None and np.array_equal(held.person_ids, raw.person_ids)
    rigid = hold_lengths(
        bone_medians(raw.xyz_m, raw.valid, raw.joint_names, "rigid"),
        held.rigid_m if same and held else None,
        cfg.hold_bone_rel,
        cfg.hold_bone_m,
    )
    limbs = (
        held.limbs_m
        if same and held
        else np.full((raw.n_persons, len(bone_indices(raw.joint_names, BONES))), np.nan)
    )
    if not cfg.enabled or raw.n_frames == 0:
        return raw.replace(source="filtered"), BoneLengths(raw.person_ids.copy(), rigid, limbs)
    valid = raw.valid.copy()
    conf = raw.confidence.copy()
    if cfg.bone_tolerance > 0:
        valid &= ~bone_outliers(raw.xyz_m, valid, conf, raw.joint_names, cfg.bone_tolerance, rigid)
    fps = raw.fps
    xyz, filled = fill_gaps_spline(raw.xyz_m, valid, max(0, int(round(cfg.spline_max_gap_s * fps))))
    meas = valid | filled
    limbs = hold_lengths(
        bone_medians(xyz, meas, raw.joint_names, "limbs"),
        limbs if same else None,
        cfg.hold_bone_rel,
        cfg.hold_bone_m,
    )
    meas_conf = np.where(valid, conf, np.where(filled, 0.5 * _neighbour_conf(conf, valid), 0.0))
    if cfg.smoother == "kalman":
        iso = (np.maximum(meas_conf, 0.05) / cfg.meas_std_m) ** 2
        info = iso[..., None, None] * np.eye(3)
        if meas_info is not None:
            if meas_info.shape != raw.valid.shape + (3, 3):
                raise ValueError(
                    f"meas_info: expected shape {raw.valid.shape + (3, 3)}, got {meas_info.shape}"
                )
            # Triangulation covariance (regularised to <= 1 m std) plus an isotropic floor.
            cov = inv_sym3(meas_info + np.eye(3)) + (cfg.meas_std_m / np.maximum(conf, 0.2))[
                ..., None, None
            ] ** 2 * np.eye(3)
            info = np.where(valid[..., None, None], inv_sym3(cov), info)
        est, bridged = kalman_smooth(xyz, meas, info, fps, cfg)
        if rays is not None and cfg.ray_iterations > 0:
            # Rays only where the smoother bridged a gap (the joint has a trajectory to linearise at).
            cand = rays.mask & ~meas & bridged
            if cfg.bone_ray_std_m > 0 and cand.any():
                # A ray + the bone length to a located neighbour pins the depth along the ray.
                pts, got = bone_ray_points(rays, xyz, meas, est, raw.joint_names, cand, limbs)
                if got.any():
                    xyz = np.where(got[..., None], pts, xyz)
                    info = np.where(got[..., None, None], np.eye(3) / cfg.bone_ray_std_m**2, info)
                    meas = meas | got
                    meas_conf = np.where(got, 0.5 * rays.conf, meas_conf)
                    filled = filled | got
                    cand &= ~got
                    est, bridged = kalman_smooth(xyz, meas, info, fps, cfg)
                    cand &= bridged
            ray_used = np.zeros_like(meas)
            for _ in range(cfg.ray_iterations if cand.any() else 0):
                r_info, r_g, ray_used = _ray_terms(rays, est, cand, cfg.ray_gate_px)
                if not ray_used.any():
                    break
                est_new, _ = kalman_smooth(xyz, meas, info, fps, cfg, r_info, r_g)
                est = np.where((meas | bridged)[..., None], est_new, est)
            meas_conf = np.where(ray_used, 0.5 * rays.conf, meas_conf)
            filled = filled | ray_used
            meas = meas | ray_used
            bridged = bridged & ~ray_used
        xyz = est
    else:
        bridged = np.zeros_like(meas)
    out_valid = meas | bridged
    out_conf = np.where(
        valid, conf, np.where(filled, meas_conf, np.where(bridged, 0.25 * _neighbour_conf(conf, valid), 0.0))
    )
    return raw.replace(
        xyz_m=np.where(out_valid[..., None], xyz, 0.0),
        valid=out_valid,
        confidence=np.clip(out_conf, 0.0, 1.0),
        n_views=np.where(valid, raw.n_views, 0),
        reproj_err_px=np.where(valid, raw.reproj_err_px, np.nan),
        source="filtered",
    ), BoneLengths(raw.person_ids.copy(), rigid, limbs)


def bone_medians(
    xyz: np.ndarray, located: np.ndarray, joint_names: tuple[str, ...], bone_set: str
) -> np.ndarray:
    """(persons, bones) median length (m) of each bone of ``bone_set`` (``"rigid"``:
    ``RIGID_BONES``; ``"limbs"``: ``BONES``) over the frames where both ends are located;
    NaN for a bone never located."""
    bones = bone_indices(joint_names, RIGID_BONES if bone_set == "rigid" else BONES)
    if not bones:
        return np.zeros((xyz.shape[1], 0))
    a, b = np.array(bones).T
    length = np.linalg.norm(xyz[:, :, a] - xyz[:, :, b], axis=-1)  # (F, P, B)
    ok = located[:, :, a] & located[:, :, b]
    with warnings.catch_warnings():  # bones never located give an all-NaN median
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(np.where(ok, length, np.nan), axis=0)


def hold_lengths(new: np.ndarray, held: np.ndarray | None, tol_rel: float, tol_m: float = 0.0) -> np.ndarray:
    """``new`` bone lengths, except where ``held`` (the previous run's, same shape) is within
    ``max(tol_rel * held, tol_m)`` of it: there the held length stays, so that an edit that
    barely moves a person's medians does not move every frame of the bout."""
    if held is None or held.shape != new.shape or (tol_rel <= 0 and tol_m <= 0):
        return new
    with np.errstate(invalid="ignore"):
        keep = (np.abs(new - held) <= np.maximum(tol_rel * held, tol_m)) | (np.isnan(new) & np.isnan(held))
    return np.where(keep, held, new)


def bone_outliers(
    xyz: np.ndarray,
    valid: np.ndarray,
    conf: np.ndarray,
    joint_names: tuple[str, ...],
    tol: float,
    med: np.ndarray | None = None,
) -> np.ndarray:
    """(frames, persons, joints) True where a joint is the weaker end of a bone whose length
    deviates from its per-person median (``med``, (persons, rigid bones) m; computed from
    ``xyz`` when None) by more than ``tol`` (relative)."""
    bones = bone_indices(joint_names, RIGID_BONES)
    out = np.zeros(valid.shape, bool)
    if not bones:
        return out
    a, b = np.array(bones).T
    length = np.linalg.norm(xyz[:, :, a] - xyz[:, :, b], axis=-1)  # (F, P, B)
    ok = valid[:, :, a] & valid[:, :, b]
    if med is None:
        med = bone_medians(xyz, valid, joint_names, "rigid")
    with np.errstate(invalid="ignore", divide="ignore"):
        bad = ok & (np.abs(length - med[None]) > tol * med[None])
    if not bad.any():
        return out
    f, p, k = np.nonzero(bad)
    ja, jb = a[k], b[k]
    weaker = np.where(conf[f, p, ja] <= conf[f, p, jb], ja, jb)
    out[f, p, weaker] = True
    return out


def fill_gaps_spline(xyz: np.ndarray, valid: np.ndarray, max_gap: int) -> tuple[np.ndarray, np.ndarray]:
    """Cubic-spline (Catmull-Rom) interpolation of interior gaps of at most ``max_gap`` frames.

    Each gap is bridged by the cubic Hermite segment between the samples around it, with
    tangents from the next samples out (a Catmull-Rom spline with non-uniform knots; at a
    trajectory end the tangent is the chord). Vectorised over all frames, persons, joints.

    xyz: (frames, persons, joints, 3); valid: (frames, persons, joints).
    Returns the filled positions and a mask of the filled entries.
    """
    out = xyz.copy()
    if max_gap <= 0:
        return out, np.zeros_like(valid)
    F = valid.shape[0]
    idx = np.broadcast_to(np.arange(F).reshape((F,) + (1,) * (valid.ndim - 1)), valid.shape)
    lv = np.maximum.accumulate(np.where(valid, idx, -1), axis=0)  # last valid <= t
    nv = np.flip(
        np.minimum.accumulate(np.flip(np.where(valid, idx, F), axis=0), axis=0), axis=0
    )  # next valid >= t
    need = (~valid) & (lv >= 0) & (nv < F) & (nv - lv - 1 <= max_gap)
    if not need.any():
        return out, need
    prev_strict = np.concatenate([np.full((1,) + valid.shape[1:], -1), lv[:-1]], axis=0)  # last valid < t
    next_strict = np.concatenate([nv[1:], np.full((1,) + valid.shape[1:], F)], axis=0)  # first valid > t
    f, p, j = np.nonzero(need)
    t1, t2 = lv[f, p, j], nv[f, p, j]
    t0 = prev_strict[t1, p, j]
    t3 = next_strict[t2, p, j]
    x1, x2 = xyz[t1, p, j], xyz[t2, p, j]
    x0 = xyz[np.maximum(t0, 0), p, j]
    x3 = xyz[np.minimum(t3, F - 1), p, j]
    h = (t2 - t1).astype(float)[:, None]
    chord = (x2 - x1) / h
    m1 = np.where((t0 >= 0)[:, None], (x2 - x0) / np.maximum(t2 - t0, 1)[:, None], chord)
    m2 = np.where((t3 < F)[:, None], (x3 - x1) / np.maximum(t3 - t1, 1)[:, None], chord)
    s_ = ((f - t1) / (t2 - t1))[:, None]
    s2, s3 = s_ * s_, s_ * s_ * s_
    out[f, p, j] = (
        (2 * s3 - 3 * s2 + 1) * x1
        + (s3 - 2 * s2 + s_) * h * m1
        + (-2 * s3 + 3 * s2) * x2
        + (s3 - s2) * h * m2
    )
    return out, need


def _gap_lengths(valid: np.ndarray) -> np.ndarray:
    """Length of the interior gap each invalid entry belongs to (0 for valid entries and for
    leading/trailing runs, which are not gaps). Vectorised along the frame axis."""
    F = valid.shape[0]
    idx = np.arange(F).reshape((F,) + (1,) * (valid.ndim - 1))
    last_valid = np.maximum.accumulate(np.where(valid, idx, -1), axis=0)
    next_valid = np.flip(np.minimum.accumulate(np.flip(np.where(valid, idx, F), axis=0), axis=0), axis=0)
    interior = (~valid) & (last_valid >= 0) & (next_valid < F)
    return np.where(interior, next_valid - last_valid - 1, 0)


def _neighbour_conf(conf: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Confidence carried into gaps: the smaller of the last and next measured confidences."""
    F = valid.shape[0]
    idx = np.arange(F).reshape((F,) + (1,) * (valid.ndim - 1))
    lv = np.maximum.accumulate(np.where(valid, idx, -1), axis=0)
    nv = np.flip(np.minimum.accumulate(np.flip(np.where(valid, idx, F), axis=0), axis=0), axis=0)
    c_prev = np.take_along_axis(conf, np.clip(lv, 0, F - 1), axis=0)
    c_next = np.take_along_axis(conf, np.clip(nv, 0, F - 1), axis=0)
    return np.where((lv >= 0) & (nv < F), np.minimum(c_prev, c_next), 0.0)


def bone_ray_points(
    rays: RayObservations,
    xyz: np.ndarray,
    located: np.ndarray,
    est: np.ndarray,
    joint_names: tuple[str, ...],
    cand: np.ndarray,
    med: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """3D points for single-view joints from their ray and a bone to a located neighbour.

    For a candidate joint ``j`` (``cand``) whose bone neighbour ``k`` is located (``located``,
    or placed by an earlier pass), the point on ``j``'s viewing ray at the neighbour's
    per-person median bone length from ``X_k`` (the sphere-ray intersection nearer ``est``;
    the ray point closest to ``X_k`` when the ray misses the sphere). Two passes, so a
    wrist can follow an elbow placed the same way. Returns points (frames, persons,
    joints, 3) and the mask of placed joints. Vectorised over frames and persons.
    """
    bones = bone_indices(joint_names, BONES)
    pts = np.zeros(xyz.shape)
    got = np.zeros(cand.shape, bool)
    if not bones:
        return pts, got
    a, b = np.array(bones).T
    ok = located[:, :, a] & located[:, :, b]
    n_ok = ok.sum(axis=0)
    if med is None:
        med = bone_medians(xyz, located, joint_names, "limbs")  # (persons, bones)
    med = np.where(n_ok >= 10, med, np.nan)
    # Viewing rays in the world: centre C = offset - R^T t, direction R^T [x, y, 1].
    R = rays.P[rays.view][..., :3]  # (F, P, J, 3, 3)
    t = rays.P[rays.view][..., 3]
    C = rays.offset_m - np.einsum("...ji,...j->...i", R, t)
    ray = np.concatenate([rays.xn, np.ones(rays.xn.shape[:-1] + (1,))], axis=-1)
    d = np.einsum("...ji,...j->...i", R, ray)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    anchor = located.copy()
    anchor_xyz = xyz.copy()
    for _ in range(2):
        for bi, (ja, jb) in enumerate(bones):
            for j, k in ((ja, jb), (jb, ja)):
                L = med[:, bi]  # (persons,)
                sel = cand[:, :, j] & ~got[:, :, j] & anchor[:, :, k] & np.isfinite(L)[None]
                if not sel.any():
                    continue
                Xk = anchor_xyz[:, :, k]
                w = C[:, :, j] - Xk
                bd = (d[:, :, j] * w).sum(-1)
                disc = bd * bd - ((w * w).sum(-1) - np.nan_to_num(L)[None] ** 2)
                root = np.sqrt(np.maximum(disc, 0.0))
                s1, s2 = -bd - root, -bd + root
                p1 = C[:, :, j] + s1[..., None] * d[:, :, j]
                p2 = C[:, :, j] + s2[..., None] * d[:, :, j]
                e = est[:, :, j]
                pick2 = np.linalg.norm(p2 - e, axis=-1) < np.linalg.norm(p1 - e, axis=-1)
                s_ = np.where(disc < 0, -bd, np.where(pick2, s2, s1))
                sel &= s_ > 0
                p = C[:, :, j] + s_[..., None] * d[:, :, j]
                pts[:, :, j] = np.where(sel[..., None], p, pts[:, :, j])
                got[:, :, j] |= sel
        anchor = located | got
        anchor_xyz = np.where(got[..., None], pts, xyz)
    return pts, got


def _ray_terms(
    rays: RayObservations, X_world: np.ndarray, cand: np.ndarray, gate_px: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linearised single-view terms at ``X_world``: information (..., 3, 3), vector (..., 3)
    (``s J^T (r + J X)``) and the mask of observations used (within ``gate_px``)."""
    info = np.zeros(cand.shape + (3, 3))
    g = np.zeros(cand.shape + (3,))
    used = np.zeros_like(cand)
    idx = np.nonzero(cand)
    if not idx[0].size:
        return info, g, used
    v = rays.view[idx]
    P = rays.P[v]  # (n, 3, 4)
    X = X_world[idx] - rays.offset_m
    Xc = np.einsum("nij,nj->ni", P[:, :, :3], X) + P[:, :, 3]
    z = Xc[:, 2]
    front = z > 1e-3
    zs = np.where(front, z, 1.0)
    proj = Xc[:, :2] / zs[:, None]
    r = rays.xn[idx] - proj
    R = P[:, :, :3]
    J = (
        np.stack([R[:, 0] - proj[:, :1] * R[:, 2], R[:, 1] - proj[:, 1:] * R[:, 2]], axis=1)
        / zs[:, None, None]
    )
    ok = front & (np.linalg.norm(r, axis=1) * rays.focal_px[v] <= gate_px)
    s = np.where(ok, (rays.focal_px[v] * rays.conf[idx] / rays.pixel_std_px) ** 2, 0.0)
    Xw = X_world[idx]
    info[idx] = s[:, None, None] * np.einsum("nki,nkj->nij", J, J)
    g[idx] = s[:, None] * np.einsum("nki,nk->ni", J, r + np.einsum("nkj,nj->nk", J, Xw))
    used[idx] = ok
    return info, g, used


def kalman_smooth(
    xyz: np.ndarray,
    meas: np.ndarray,
    info: np.ndarray,
    fps: float,
    cfg: FilterConfig,
    extra_info: np.ndarray | None = None,
    extra_g: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Constant-acceleration Kalman smoother over every (person, joint), with outlier gating.

    xyz: (frames, persons, joints, 3) measurements where ``meas``; info: (frames, persons,
    joints, 3, 3) their information matrices (inverse covariances, 1/m^2).
    Returns smoothed positions and the mask of bridged entries (interior gaps of at most
    ``kalman_max_gap_s``; measured entries are not in it). ``extra_info``/``extra_g``
    (same leading shape) add linearised terms (single-view rays). Measurements farther than
    ``outlier_dist_m`` from the smoothed trajectory are dropped and the trajectory re-solved
    once (the position/velocity constraint: a joint cannot jump), and positions are kept
    above the floor.
    """
    F, P, J, _ = xyz.shape
    z = xyz.reshape(F, P * J, 3)
    m = meas.reshape(F, P * J).copy()
    Lam = info.reshape(F, P * J, 3, 3)
    zf = np.where(np.isfinite(z), z, 0.0)
    xi = np.zeros((F, P * J, 3, 3)) if extra_info is None else extra_info.reshape(F, P * J, 3, 3)
    xg = np.zeros((F, P * J, 3)) if extra_g is None else extra_g.reshape(F, P * J, 3)

    def solve(cols: np.ndarray | slice) -> np.ndarray:
        L = np.where(m[:, cols, None, None], Lam[:, cols], 0.0)
        g = np.einsum("fnij,fnj->fni", L, zf[:, cols]) + xg[:, cols]
        return rts_smooth_batch(L + xi[:, cols], g, fps, cfg.jerk_std)

    out = solve(slice(None))
    resid = np.linalg.norm(out - z, axis=-1)
    bad = m & (resid > cfg.outlier_dist_m)
    if bad.any():
        redo = np.flatnonzero(bad.any(axis=0))
        m[bad] = False
        out[:, redo] = solve(redo)
    out[..., 2] = np.maximum(out[..., 2], cfg.floor_z_m)
    kept = m.reshape(F, P, J)
    gap = _gap_lengths(kept)
    bridged = (~kept) & (gap > 0) & (gap <= int(round(cfg.kalman_max_gap_s * fps)))
    out = out.reshape(F, P, J, 3)
    return np.where((kept | bridged)[..., None], out, xyz), bridged & ~meas


def ca_model(fps: float, jerk_std: float) -> tuple[np.ndarray, np.ndarray]:
    """Transition ``A`` and process noise ``Q`` of the constant-acceleration model of one axis,
    in scaled state units ``[p, v dt, a dt^2]`` (well conditioned at any frame rate)."""
    dt = 1.0 / fps
    A = np.array([[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
    # White jerk of density q: Q = q [dt^5/20 dt^4/8 dt^3/6; .. dt^3/3 dt^2/2; .. .. dt], scaled by D = diag(1, dt, dt^2).
    C = np.array([[1 / 20, 1 / 8, 1 / 6], [1 / 8, 1 / 3, 1 / 2], [1 / 6, 1 / 2, 1.0]])
    return A, jerk_std**2 * dt**5 * C


def rts_smooth_batch(info: np.ndarray, g: np.ndarray, fps: float, jerk_std: float) -> np.ndarray:
    """Smoothed positions of N independent 3D trajectories (frames, N, 3).

    This is the Rauch-Tung-Striebel smoother's estimate of the constant-acceleration model
    (state ``[p, v, a]`` in 3D per frame), computed in batch form: the maximum a posteriori
    trajectory minimises ``sum_t (p_t - z_t)^T info_t (p_t - z_t) + sum_t |s_{t+1} - A s_t|^2_{Q^-1}``,
    a block-tridiagonal (banded) linear system per trajectory, solved by one
    ``scipy.linalg.solveh_banded`` call per trajectory (no loop over frames): bandwidth 5
    with the three axes as right-hand sides when ``info`` is isotropic, else the coupled
    9-state system (bandwidth 17). Full 3x3
    ``info`` lets poorly conditioned directions (e.g. along the baseline of two opposite
    cameras) lean on the motion model. Entries with ``info = 0`` are gaps. A very vague
    prior on the first state keeps trajectories with < 3 measurements solvable (it is
    the recursive filter's initial covariance, so both give the same estimate).

    info: (frames, N, 3, 3); g: (frames, N, 3) = ``info_t z_t`` (plus linearised terms).
    A trajectory without any information (a joint never measured, e.g. the feet with a
    17-keypoint model) is not solved: its output is NaN.
    """
    F, N, _ = g.shape
    A, Q = ca_model(fps, jerk_std)
    Qi = np.linalg.inv(Q)
    D3 = np.zeros((F, 3, 3))
    D3[:-1] += A.T @ Qi @ A
    D3[1:] += Qi
    D3[0] += 1e-9 * Qi[0, 0] * np.eye(3)  # a very vague prior on the first state
    L3 = -Qi @ A  # block (t+1, t)
    out = np.full((F, N, 3), np.nan)
    observed = np.abs(info).reshape(F, N, 9).max(axis=(0, 2)) > 0
    # Isotropic trajectories (info = lambda_t I) decouple per axis: a 3-state system with
    # bandwidth 5 and the three axes as right-hand sides.
    off = np.abs(info[..., [0, 0, 1], [1, 2, 2]]).max(axis=(0, 2))
    diag = np.diagonal(info, axis1=-2, axis2=-1)
    iso = (off == 0) & (np.abs(diag - diag[..., :1]).max(axis=(0, 2)) == 0) & observed
    if iso.any():
        ab3 = _banded(D3, L3, 3)
        for n in np.flatnonzero(iso):
            abn = ab3.copy()
            abn[0, 0::3] += info[:, n, 0, 0]
            rhs = np.zeros((F, 3, 3))
            rhs[:, 0, :] = g[:, n]
            sol = _solve_banded(abn, rhs.reshape(3 * F, 3))
            out[:, n] = sol[0::3]
    if (~iso & observed).any():
        I3 = np.eye(3)
        D9 = np.einsum("fab,ij->faibj", D3, I3).reshape(F, 9, 9)  # state order [p_xyz, v_xyz, a_xyz]
        ab9 = _banded(D9, np.kron(L3, I3), 9)
        for n in np.flatnonzero(~iso & observed):
            abn = ab9.copy()
            for i in range(3):
                for j in range(i + 1):
                    abn[i - j, j::9] += info[:, n, i, j]
            rhs9 = np.zeros((F, 9))
            rhs9[:, :3] = g[:, n]
            sol = _solve_banded(abn, rhs9.reshape(-1))
            out[:, n] = sol.reshape(F, 9)[:, :3]
    return out


def _solve_banded(ab: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``solveh_banded`` of a smoother system; if rounding makes a weakly observed
    trajectory's system (a few measurements in a long sequence) lose positive
    definiteness, it is solved again with a ridge of 1e-12 of its largest diagonal entry."""
    try:
        return solveh_banded(ab, rhs, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        ridged = ab.copy()
        ridged[0] += 1e-12 * np.abs(ab[0]).max()
        return solveh_banded(ridged, rhs, lower=True, check_finite=False)


def _banded(D: np.ndarray, L: np.ndarray, b: int) -> np.ndarray:
    """Lower banded storage ``ab[k, j] = H[j + k, j]`` of a block-tridiagonal matrix with
    diagonal blocks D (frames, b, b) and constant sub-diagonal block L (b, b)."""
    F = D.shape[0]
    ab = np.zeros((2 * b, b * F))
    for c in range(b):
        for k in range(2 * b):
            r = c + k
            if r < b:
                ab[k, c::b] = D[:, r, c]
            elif r < 2 * b and F > 1:
                ab[k, c : b * (F - 1) : b] = L[r - b, c]
    return ab
