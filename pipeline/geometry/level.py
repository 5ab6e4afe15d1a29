"""Which way is up: the floor's plane in the calibration's world, from the athletes' feet.

Every later stage takes the world to be z-up with the floor at ``z = 0``
(docs/design/floor.md). A calibration solved from a board on a sloping surface, or one whose
world is a camera's frame (aniposelib's) or a board's with z into the floor (OpenCV's), breaks
that: the filter would clamp the athletes onto the wrong plane. ``level_world`` measures the
athletes' up (ankles to shoulders and nose) and the plane of their lowest sole points, and returns the
rotation that makes the floor level; ``transform_world`` applies it to a rig.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field

import numpy as np

from pipeline.geometry.floor import AthletePixels, FloorConfig
from pipeline.geometry.world import angle_deg, rotation_to_z
from pipeline.schema.camera import CameraRig

LOW_JOINTS = ("left_ankle", "right_ankle")
HIGH_JOINTS = ("left_shoulder", "right_shoulder", "nose")
"""The athletes' up is the direction from the mean of their ankles seen to the mean of their
shoulders and nose seen (with two cameras the shoulders are often seen in one view only)."""
MIN_CELL_POINTS = 10
"""Sole points (>= 1) a floor square needs to count in the plane fit."""
MIN_CELLS = 5
"""Floor squares (>= 4) the plane fit needs."""
SIGNIFICANT_SE = 3.0
"""A tilt turns the world only when it is at least this many standard errors of the slope."""

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Levelling:
    """How the calibration's world was turned so that its floor is level.

    Fields:
        rotation: (3, 3) rotation from the input world to the levelled one (identity: kept).
        tilt_deg: angle (deg, 0-180) of the floor's normal from the input world's +z; NaN when
            the feet gave no plane.
        body_tilt_deg: angle (deg, 0-180) of the athletes' median up (ankles to shoulders) from
            +z; NaN when not measured.
        reason: one sentence on the decision.
    """

    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    tilt_deg: float = float("nan")
    body_tilt_deg: float = float("nan")
    reason: str = ""

    @property
    def rotated(self) -> bool:
        """Whether the world was turned."""
        return not np.array_equal(self.rotation, np.eye(3))

    @property
    def up_measured(self) -> bool:
        """Whether the athletes' up was measured, so the levelled world is known to be z-up with
        them standing: the floor's height is then applied whatever its size (``estimate_floor``'s
        ``max_shift_m`` is for a world not known to be z-up)."""
        return bool(np.isfinite(self.body_tilt_deg))


def _plane_normal(points: np.ndarray, up: np.ndarray, cfg: FloorConfig) -> tuple[np.ndarray | None, float, str]:
    """The floor's unit normal from the lowest sole points (n, 3) (None: not measured), the
    standard error of its slope (deg; NaN) and why not: the median
    height (along ``up``) per ``cell_m`` square of floor, then a least-squares plane through
    the cells' medians weighted by the square root of their counts (a foot in the air is above
    its cell's median). The plane is used when its slope's standard error, in its least-known
    direction, is at most ``max_slope_se_deg``."""
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    a, b, h = points @ e1, points @ e2, points @ up
    cells = np.floor(a / cfg.cell_m).astype(np.int64) * 1_000_003 + np.floor(b / cfg.cell_m).astype(np.int64)
    _, inv, counts = np.unique(cells, return_inverse=True, return_counts=True)
    rows = []
    for k in np.flatnonzero(counts >= MIN_CELL_POINTS):
        m = inv == k
        rows.append((a[m].mean(), b[m].mean(), float(np.median(h[m])), np.sqrt(counts[k])))
    if len(rows) < MIN_CELLS:
        return None, float("nan"), f"the feet covered {len(rows)} floor squares of {cfg.cell_m:g} m, fewer than {MIN_CELLS}"
    A = np.array(rows)
    M = np.column_stack([A[:, 0] - A[:, 0].mean(), A[:, 1] - A[:, 1].mean(), np.ones(len(A))]) * A[:, 3:4]
    y = A[:, 2] * A[:, 3]
    coef, *_ = np.linalg.lstsq(M, y, rcond=None)
    s2 = float(np.sum((y - M @ coef) ** 2)) / (len(A) - 3)
    se = float(np.degrees(np.arctan(np.sqrt(max(np.linalg.eigvalsh(s2 * np.linalg.inv(M.T @ M)[:2, :2]).max(), 0.0)))))
    if se > cfg.max_slope_se_deg:
        return None, se, f"the floor's slope is known to {se:.2f} deg only (more than {cfg.max_slope_se_deg:g}): the feet covered too little floor"
    n = up - coef[0] * e1 - coef[1] * e2
    return n / np.linalg.norm(n), se, ""


def level_world(rig: CameraRig, pix: AthletePixels, cfg: FloorConfig) -> Levelling:
    """Measure which way is up in ``rig``'s world from the athletes' keypoints ``pix``, and the
    rotation that levels the floor.

    The athletes' up is the median direction from their ankles to their shoulders and nose. The
    floor's normal comes from their lowest sole point (along that up) per frame (``_plane_normal``).
    The floor is turned level when its normal and the athletes' up agree within
    ``max_up_gap_deg`` and it is ``min_tilt_deg`` and 3 standard errors or more off +z. When the
    feet give no plane but the athletes stand more than ``max_body_tilt_deg`` off +z, the
    calibration is not z-up and the world is turned to their up (a warning). Athletes whose up
    varies by more than ``max_up_spread_deg`` are not upright: the world is kept.
    """
    if cfg.mode != "auto":
        return Levelling(reason=f"levelling is off (floor.mode={cfg.mode!r})")
    if pix.n_persons == 0:
        return Levelling(reason="world kept as it is: no athletes")
    soles, _ = pix.feet()
    high = tuple(n for n in HIGH_JOINTS if n in pix.joint_names)
    if not (soles and all(n in pix.joint_names for n in LOW_JOINTS) and high):
        return Levelling(reason="world kept as it is: the keypoints have no ankles and shoulders")
    feet = tuple(n for n in soles if n not in LOW_JOINTS)
    X = pix.triangulate(rig, LOW_JOINTS + high + feet, cfg.max_view_err_px)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN means: not seen
        v = (np.nanmean(X[:, :, 2 : 2 + len(high)], axis=2) - np.nanmean(X[:, :, :2], axis=2)).reshape(-1, 3)
    v = v[np.isfinite(v).all(axis=1)]
    v = v[np.linalg.norm(v, axis=1) > 0.3]  # a standing person's ankles-to-shoulders is 1.1-1.5 m
    if len(v) < cfg.min_frames:
        return Levelling(reason=f"world kept as it is: fewer than {cfg.min_frames} athlete-frames with an ankle and a shoulder seen in two views")
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    up = np.median(v, axis=0)
    up /= np.linalg.norm(up)
    body_tilt = angle_deg(up, np.array([0.0, 0.0, 1.0]))
    spread = float(np.degrees(np.median(np.arccos(np.clip(v @ up, -1.0, 1.0)))))
    if spread > cfg.max_up_spread_deg:  # athletes on the ground, or the ankles and shoulders mixed up
        return Levelling(reason=f"world kept as it is: the athletes are not upright (their up varies by {spread:.0f} deg, median; more than {cfg.max_up_spread_deg:g})")
    S = X[:, :, :2] if not feet else X[:, :, 2 + len(high) :]
    h = np.where(np.isfinite(S).all(axis=3), S @ up, np.inf)
    low = np.take_along_axis(S, h.argmin(axis=2)[:, :, None, None], axis=2)[:, :, 0].reshape(-1, 3)
    low = low[np.isfinite(low).all(axis=1)]
    n, se, why = _plane_normal(low, up, cfg) if len(low) >= cfg.min_frames else (None, float("nan"), f"fewer than {cfg.min_frames} frames with a foot seen")
    gap = angle_deg(n, up) if n is not None else float("nan")
    if n is not None and gap <= cfg.max_up_gap_deg:
        tilt = angle_deg(n, np.array([0.0, 0.0, 1.0]))
        if tilt < max(cfg.min_tilt_deg, SIGNIFICANT_SE * se):
            under = f"under {cfg.min_tilt_deg:g} deg" if tilt < cfg.min_tilt_deg else f"under {SIGNIFICANT_SE:g} standard errors"
            return Levelling(np.eye(3), tilt, body_tilt, f"world kept level: the floor's normal is {tilt:.2f} ± {se:.2f} deg from +z, {under}")
        if body_tilt > cfg.max_body_tilt_deg:
            log.warning("the calibration's world is not z-up: the athletes stand %.0f deg off +z; the world is turned to level the floor", body_tilt)
        return Levelling(rotation_to_z(n), tilt, body_tilt, f"world turned {tilt:.1f} deg to level the floor (its normal was {tilt:.1f} ± {se:.2f} deg from +z, the athletes' up {body_tilt:.1f} deg)")
    if n is not None:
        why = f"the feet's plane is {gap:.0f} deg from the athletes' up, more than {cfg.max_up_gap_deg:g}"
    if body_tilt > cfg.max_body_tilt_deg:
        log.warning("the calibration's world is not z-up: the athletes stand %.0f deg off +z; the world is turned to their up (%s)", body_tilt, why)
        return Levelling(rotation_to_z(up), float("nan"), body_tilt, f"world turned {body_tilt:.0f} deg to the athletes' up: the calibration is not z-up ({why})")
    return Levelling(np.eye(3), float("nan"), body_tilt, f"world kept as it is: {why}")
