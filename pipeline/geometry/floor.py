"""Where the floor is: its height in the calibration's world, from the athletes' feet.

Every later stage puts the floor at the world's ``z = 0``: the filter keeps points above it,
the fit's ground term, the physics floor plane, the ground and skating metrics and the glTF
floor. A calibration whose origin is not on the floor (Shelf's is about 9 cm above it) would
have every planted foot pushed up by that much. ``estimate_floor`` measures the floor from
the triangulated sole keypoints (heels and toes; ankles when the keypoints have no feet) and
``pipeline.geometry.world.lower_world`` moves the rig's world so that the floor is at ``z = 0``
(docs/design/floor.md).
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from typing import Literal

import numpy as np

from pipeline.geometry.bundle import triangulate_px
from pipeline.schema.camera import CameraRig

SOLE_JOINTS = ("left_heel", "left_big_toe", "left_small_toe", "right_heel", "right_big_toe", "right_small_toe")
"""Keypoints on the sole's outline; the lowest of them per frame is on or near the floor."""
ANKLE_JOINTS = ("left_ankle", "right_ankle")
"""Used instead when the keypoints have no feet (COCO-17)."""

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FloorConfig:
    """How the floor's height is found (``calibrate.floor`` in ``session.json``)."""

    mode: Literal["auto", "height", "off"] = "auto"
    """``auto``: turn the world so the floor is level (``pipeline.geometry.level``), then move
    it so the floor is at ``z = 0`` when it is off by more than ``min_shift_m``; ``height``: the
    move only (the calibration is taken to be z-up and level); ``off``: the calibration's
    ``z = 0`` is the floor."""
    sole_height_m: float = 0.009
    """Median height (m, >= 0) above the floor of a person's lowest heel or toe keypoint per
    frame (docs/design/floor.md)."""
    ankle_height_m: float = 0.065
    """The same for the lower ankle (m, >= 0), used when the keypoints have no feet."""
    min_shift_m: float = 0.03
    """Smallest floor offset (m, >= 0) that moves the world; smaller ones are within the
    estimate's spread, and the calibration is kept as it is."""
    max_shift_m: float = 0.5
    """Largest floor offset (m, > ``min_shift_m``) applied when the athletes' up was not measured
    (``mode="height"``, or no shoulders seen); one further off (athletes not standing, a
    calibration not z-up) is reported, not applied."""
    hold_m: float = 0.01
    """On a re-run after an edit, the previous floor is kept when the new one is within this
    (m, >= 0) of it and ``hold_deg`` of its tilt."""
    hold_deg: float = 0.2
    """The same for the floor's direction (deg, >= 0)."""
    min_tilt_deg: float = 1.0
    """Smallest tilt (deg, >= 0) of the floor's normal from +z that turns the world (it must also
    be 3 standard errors); level floors measure 0.05-0.64 deg (docs/design/floor.md)."""
    max_up_gap_deg: float = 10.0
    """The floor's normal is used only when it is within this (deg, > 0) of the athletes' median
    up (ankles to shoulders; boxers lean 1-4 deg from the vertical)."""
    max_body_tilt_deg: float = 30.0
    """Athletes standing more than this (deg, > 0) off +z mean the calibration is not z-up: the
    world is turned to their up even when the feet give no plane (a warning)."""
    max_up_spread_deg: float = 20.0
    """The athletes' up is used only when their per-frame ankles-to-shoulders directions lie
    within this (deg, median angle from their median; > 0): upright athletes give 5-7 deg."""
    cell_m: float = 0.5
    """Side (m, > 0) of the floor squares whose median sole height the floor's plane is fitted to."""
    max_slope_se_deg: float = 0.5
    """The floor's plane is used only when its slope's standard error is at most this (deg, > 0);
    a short clip whose feet cover little floor gives none (docs/design/floor.md)."""
    min_frames: int = 20
    """Frames (>= 1) with a triangulated foot a person needs to count."""
    max_view_err_px: float = 15.0
    """A view whose reprojection error exceeds this (px, > 0) is dropped from a point."""

    def __post_init__(self) -> None:
        if self.mode not in ("auto", "height", "off"):
            raise ValueError(f"FloorConfig.mode must be auto/height/off, got {self.mode!r}")
        for name in ("sole_height_m", "ankle_height_m", "min_shift_m", "hold_m", "hold_deg", "min_tilt_deg"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"FloorConfig.{name} must be >= 0 m, got {v}")
        if not (np.isfinite(self.max_shift_m) and self.max_shift_m > self.min_shift_m):
            raise ValueError(f"FloorConfig.max_shift_m must be > min_shift_m ({self.min_shift_m} m), got {self.max_shift_m}")
        for name in ("max_up_gap_deg", "max_body_tilt_deg", "max_up_spread_deg", "cell_m", "max_slope_se_deg"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"FloorConfig.{name} must be > 0, got {v}")
        if self.min_frames < 1:
            raise ValueError(f"FloorConfig.min_frames must be >= 1, got {self.min_frames}")
        if not (np.isfinite(self.max_view_err_px) and self.max_view_err_px > 0):
            raise ValueError(f"FloorConfig.max_view_err_px must be > 0 px, got {self.max_view_err_px}")


@dataclass(frozen=True)
class FloorEstimate:
    """The floor found in a rig's world.

    Fields:
        floor_z_m: the floor's height (m) in the rig's world; NaN when not measured.
        shift_m: how far (m) the world was lowered: the floor's height when it was moved to
            ``z = 0``, else 0. A point at ``z`` in the input world is at ``z - shift_m`` after.
        person_floor_z_m: per person, the floor under them (m; NaN: too few frames).
        joints: ``"soles"``, ``"ankles"`` or ``""`` (none measured).
        reason: one sentence on the decision.
    """

    floor_z_m: float
    shift_m: float
    person_floor_z_m: tuple[float, ...]
    joints: str
    reason: str


@dataclass(frozen=True)
class AthletePixels:
    """The athletes' 2D keypoints, one row per (frame, person, joint) in that order
    (``calibrate.gather_pixels``), for measuring the floor and which way is up.

    Fields:
        uv_px: (rows, views, 2) distorted pixels.
        conf: (rows, views) confidence (0 = unseen).
        n_persons: persons per frame (>= 0).
        joint_names: the keypoints' names, one per joint.
        min_conf: keypoints under this confidence (0..1; the calibrate stage passes
            ``bundle.min_conf``) are not used.
    """

    uv_px: np.ndarray
    conf: np.ndarray
    n_persons: int
    joint_names: tuple[str, ...]
    min_conf: float

    def __post_init__(self) -> None:
        rows, J = self.uv_px.shape[0], len(self.joint_names)
        if self.conf.shape[0] != rows or rows % max(J * self.n_persons, 1):
            raise ValueError(f"AthletePixels: {rows} rows are not frames x {self.n_persons} persons x {J} joints")

    @property
    def n_frames(self) -> int:
        """Frames (rows / persons / joints; 0 without persons)."""
        return self.uv_px.shape[0] // max(self.n_persons * len(self.joint_names), 1)

    def feet(self) -> tuple[tuple[str, ...], str]:
        """The keypoints whose lowest per frame is on or near the floor and their kind:
        ``SOLE_JOINTS`` and ``"soles"``, else ``ANKLE_JOINTS`` and ``"ankles"``, else ``((), "")``."""
        if all(n in self.joint_names for n in SOLE_JOINTS):
            return SOLE_JOINTS, "soles"
        if all(n in self.joint_names for n in ANKLE_JOINTS):
            return ANKLE_JOINTS, "ankles"
        return (), ""

    def triangulate(self, rig: CameraRig, want: tuple[str, ...], max_view_err_px: float) -> np.ndarray:
        """The ``want`` joints triangulated in ``rig``'s world, (frames, persons, len(want), 3) m;
        NaN where not seen in two views (after dropping views off by ``max_view_err_px``)."""
        J, P = len(self.joint_names), self.n_persons
        idx = np.array([self.joint_names.index(n) for n in want], dtype=np.int64)
        out = np.full((self.n_frames, P, len(want), 3), np.nan)
        rows = np.flatnonzero(np.isin(np.arange(self.uv_px.shape[0]) % max(J, 1), idx))
        w = np.where(self.conf[rows] >= self.min_conf, self.conf[rows], 0.0)
        seen = (w > 0).sum(axis=1) >= 2
        rows, w = rows[seen], w[seen]
        if rows.size:
            X, used, _ = triangulate_px(rig, self.uv_px[rows], w, max_view_err_px)
            ok = used.sum(axis=1) >= 2
            r = rows[ok]
            slot = np.full(J, -1)
            slot[idx] = np.arange(len(want))
            out[r // (P * J), (r // J) % P, slot[r % J]] = X[ok]
        return out


def estimate_floor(rig: CameraRig, pix: AthletePixels, cfg: FloorConfig, up_measured: bool = False) -> FloorEstimate:
    """Measure the floor in ``rig``'s world from the athletes' keypoints ``pix``.

    Per person: the lowest triangulated foot keypoint of each frame, its median over frames,
    less ``sole_height_m`` (``ankle_height_m``). The floor is the lowest person's (a person on
    a platform or a treadmill stands higher; none stands lower than the floor). ``up_measured``
    (the world was levelled on the athletes' up, ``Levelling.up_measured``) applies a floor
    further off than ``max_shift_m``.
    """
    if cfg.mode == "off":
        return FloorEstimate(float("nan"), 0.0, (), "", "floor levelling is off (floor.mode='off')")
    names, kind = pix.feet()
    if not names:
        return FloorEstimate(float("nan"), 0.0, (), "", "floor kept at z = 0: the keypoints have no ankles or feet")
    height = cfg.sole_height_m if kind == "soles" else cfg.ankle_height_m
    z = pix.triangulate(rig, names, cfg.max_view_err_px)[..., 2]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN: no foot seen that frame
        lowest = np.nanmin(z, axis=2) if z.size else np.full(z.shape[:2], np.nan)  # (frames, persons)
    per = [float("nan")] * pix.n_persons
    for p in range(pix.n_persons):
        mine = lowest[:, p][np.isfinite(lowest[:, p])]
        if mine.size >= cfg.min_frames:
            per[p] = float(np.median(mine) - height)
    if not np.isfinite(per).any():
        why = f"no athlete has {cfg.min_frames} frames with a foot seen in two views"
        return FloorEstimate(float("nan"), 0.0, tuple(per), kind, f"floor kept at z = 0: {why}")
    floor = float(np.nanmin(per))
    at = f"the {kind} put the floor at z = {1000 * floor:+.0f} mm"
    if abs(floor) < cfg.min_shift_m:
        return FloorEstimate(floor, 0.0, tuple(per), kind, f"floor kept at z = 0: {at}, within {1000 * cfg.min_shift_m:.0f} mm")
    if abs(floor) > cfg.max_shift_m and not up_measured:
        why = f"{at}, more than {1000 * cfg.max_shift_m:.0f} mm off: check that the calibration is z-up and the athletes stand"
        log.warning("floor kept at z = 0: %s", why)
        return FloorEstimate(floor, 0.0, tuple(per), kind, f"floor kept at z = 0: {why}")
    return FloorEstimate(floor, floor, tuple(per), kind, f"world moved so the floor is at z = 0: {at}")
