"""Stage ``calibrate``: refine the camera extrinsics (and optionally focal lengths) on the athletes.

``run(tracks, assoc, rig, cfg) -> CalibrationResult``, after ``associate``:

1. Gather, for every (frame, person, joint), the associated 2D keypoint of each view
   (distorted pixels and confidence): one candidate 3D point per row.
2. ``mode="on"``: bundle-adjust on all of them (``pipeline.geometry.bundle``) and use
   the refined rig.
3. ``mode="auto"`` (default) adopts nothing that held-out frames do not confirm: the
   frames are split into interleaved time blocks of ``block_s`` (neighbouring frames are
   nearly the same pose, so odd/even frames would not be independent); the rig is refined on the even
   blocks and scored on the odd ones: the median reprojection error over all views of
   the re-triangulated held-out points, input rig vs refined rig. The refined rig is
   adopted only when it lowers that error by ``min_improvement`` and no camera's
   held-out median gets worse by more than that; otherwise the input rig is returned
   with ``adopted=False`` and the reason. The adopted rig is the one fitted on the even
   blocks, i.e. exactly the rig that passed the held-out test (the subsample of
   ``bundle.max_points`` bounds the points either way, so a refit on all frames would
   add little and would itself be untested). Reprojection is only a proxy of 3D accuracy:
   on a rig that is already good, the adjustment also absorbs view-dependent keypoint
   biases, which ``min_improvement`` leaves out.
4. ``mode="off"``: the input rig, unchanged.
5. Whatever the mode, ``floor`` turns the chosen rig's world so that the floor is level
   (``pipeline.geometry.level``), measures the floor's height from the athletes' feet and
   lowers the world so the floor is at ``z = 0``, the floor every later stage assumes
   (``pipeline.geometry.floor``; ``floor.mode="off"`` keeps it).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any, Literal

import numpy as np

from pipeline.geometry.bundle import (
    BundleConfig,
    BundleResult,
    ReprojectionStats,
    bundle_adjust,
    reprojection_stats,
)
from pipeline.geometry.floor import AthletePixels, FloorConfig, FloorEstimate, estimate_floor
from pipeline.geometry.level import Levelling, level_world
from pipeline.geometry.world import lower_world, rigid, transform_world, turn_deg, turns_between_deg
from pipeline.schema.association import Association
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.stages.observations import athlete_rows

__all__ = ["BundleConfig", "CalibrateConfig", "FloorConfig", "CalibrationResult", "gather_pixels", "run", "summary"]


@dataclass(frozen=True)
class CalibrateConfig:
    """Calibration refinement from the athletes' keypoints (bundle adjustment)."""

    mode: Literal["auto", "on", "off"] = "auto"
    """``auto``: refine, adopt only if it helps on held-out frames; ``on``: always adopt
    the refined rig; ``off``: keep the input rig."""
    min_improvement: float = 0.10
    """``auto`` adopts when the held-out median reprojection error drops by at least this
    fraction (0..1) and no camera's held-out median rises by more than it. Keypoints are not
    exact correspondences (view-dependent detector biases), so an adjustment of a good rig
    still gains a few percent without improving the 3D result; hence a margin."""
    block_s: float = 0.5
    """Length (s, > 0) of the interleaved time blocks of the held-out split (shortened
    for short clips so that there are ``min_blocks`` blocks)."""
    min_blocks: int = 4
    """At least this many time blocks (>= 2; half of them held out)."""
    bundle: BundleConfig = field(default_factory=BundleConfig)
    """Bundle adjustment settings (``refine_focal``, thresholds, loss; a dict in
    ``session.json`` is accepted)."""
    floor: FloorConfig = field(default_factory=FloorConfig)
    """Where the floor is: measured from the feet, and the world lowered to put it at z = 0
    (a dict in ``session.json`` is accepted)."""
    incremental: bool = True
    """On a re-run (after an edit), keep the previous run's rig when the new one is within
    ``hold_center_mm`` / ``hold_rotation_deg`` / ``hold_focal_rel`` of it in every camera and
    the decision is the same, so that a local edit does not move every frame downstream."""
    hold_center_mm: float = 5.0
    """Largest camera centre change (mm, >= 0) that keeps the previous rig."""
    hold_rotation_deg: float = 0.05
    """Largest camera rotation change (degrees, >= 0) that keeps the previous rig."""
    hold_focal_rel: float = 0.002
    """Largest relative focal length change (>= 0) that keeps the previous rig."""

    def __post_init__(self) -> None:
        if isinstance(self.bundle, dict):
            known = {f.name for f in fields(BundleConfig)}
            extra = set(self.bundle) - known
            if extra:
                raise ValueError(
                    f"CalibrateConfig.bundle: unknown keys {sorted(extra)}; known: {sorted(known)}"
                )
            object.__setattr__(self, "bundle", BundleConfig(**self.bundle))
        if isinstance(self.floor, dict):
            known = {f.name for f in fields(FloorConfig)}
            extra = set(self.floor) - known
            if extra:
                raise ValueError(f"CalibrateConfig.floor: unknown keys {sorted(extra)}; known: {sorted(known)}")
            object.__setattr__(self, "floor", FloorConfig(**self.floor))
        if self.mode not in ("auto", "on", "off"):
            raise ValueError(f"CalibrateConfig.mode must be auto/on/off, got {self.mode!r}")
        if not 0.0 <= self.min_improvement < 1.0:
            raise ValueError(f"CalibrateConfig.min_improvement must be in [0, 1), got {self.min_improvement}")
        if not (np.isfinite(self.block_s) and self.block_s > 0):
            raise ValueError(f"CalibrateConfig.block_s must be > 0 s, got {self.block_s}")
        if self.min_blocks < 2:
            raise ValueError(f"CalibrateConfig.min_blocks must be >= 2, got {self.min_blocks}")
        for name in ("hold_center_mm", "hold_rotation_deg", "hold_focal_rel"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"CalibrateConfig.{name} must be >= 0, got {v}")


@dataclass(frozen=True)
class CalibrationResult:
    """The rig to use downstream and how it was decided.

    Fields:
        rig: the rig for the later stages (the input rig unless ``adopted``).
        adopted: the refined rig was adopted.
        reason: one human-readable sentence on the decision.
        before, after: per-camera reprojection statistics (undistorted px) over all frames,
            input rig vs the refined candidate (whether adopted or not); None when no
            candidate was computed (``mode="off"`` or the adjustment failed).
        heldout_before_px, heldout_after_px: held-out median error of the input and the
            candidate rig (``auto`` only, else NaN).
        center_shift_m, rotation_change_deg, focal_scale: (views,) change of the candidate
            against the input rig (zeros / ones without a candidate).
        converged: the candidate's adjustment converged.
        floor: the floor found in the levelled world and how far ``rig``'s world was
            lowered to put it at z = 0 (None: not looked for).
        level: how the chosen rig's world was turned to make the floor level (None: not
            looked for).
    """

    rig: CameraRig
    adopted: bool
    reason: str
    before: ReprojectionStats | None = None
    after: ReprojectionStats | None = None
    heldout_before_px: float = float("nan")
    heldout_after_px: float = float("nan")
    center_shift_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rotation_change_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    focal_scale: np.ndarray = field(default_factory=lambda: np.zeros(0))
    converged: bool = False
    floor: FloorEstimate | None = None
    level: Levelling | None = None

    @property
    def world_from_input(self) -> np.ndarray:
        """(4, 4) rigid transform from the input calibration's world to ``rig``'s: turned by
        ``level``, then lowered by ``floor.shift_m``."""
        R = self.level.rotation if self.level is not None else None
        return rigid(R, (0.0, 0.0, -self.floor.shift_m if self.floor is not None else 0.0))

    def __post_init__(self) -> None:
        V = self.rig.n_views
        for name, fill in (("center_shift_m", 0.0), ("rotation_change_deg", 0.0), ("focal_scale", 1.0)):
            a = getattr(self, name)
            if a.size == 0:
                object.__setattr__(self, name, np.full(V, fill))
            elif a.shape != (V,):
                raise ValueError(f"CalibrationResult.{name}: expected shape ({V},), got {a.shape}")
        if not self.reason:
            raise ValueError("CalibrationResult.reason must say why the rig was (not) adopted")


def gather_pixels(
    tracks: Tracks2D, assoc: Association, n_views: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense observations, one row per (frame, person, joint).

    Per (frame, person, view) the detection ``observations.athlete_rows`` picks. Returns
    ``uv_px`` (rows, views, 2) distorted pixels, ``conf`` (rows, views) confidence (0 = none
    or invalid) and ``frame`` (rows,) indices.
    """
    F, P, J, V = tracks.n_frames, assoc.n_persons, len(tracks.joint_names), n_views
    rows, f, p, v = athlete_rows(tracks, assoc, n_views)
    ok = tracks.keypoint_valid[rows]
    dense_uv = np.zeros((F, P, V, J, 2))
    dense_conf = np.zeros((F, P, V, J))
    dense_uv[f, p, v] = np.where(ok[..., None], tracks.keypoints_px[rows], 0.0)
    dense_conf[f, p, v] = np.where(ok, tracks.keypoint_conf[rows], 0.0)
    uv = np.moveaxis(dense_uv, 2, 3).reshape(F * P * J, V, 2)
    conf = np.moveaxis(dense_conf, 2, 3).reshape(F * P * J, V)
    return uv, conf, np.repeat(np.arange(F), P * J)


def run(
    tracks: Tracks2D, assoc: Association, rig: CameraRig, cfg: CalibrateConfig = CalibrateConfig()
) -> CalibrationResult:
    """Refine ``rig`` on the associated keypoints, then put the floor at z = 0 (see the module
    docstring).

    Raises:
        ValueError: tracks/association/rig mismatch; with ``mode="on"`` also the errors of
        ``bundle_adjust`` (one camera, too few correspondences, NaN keypoints). ``auto``
        turns those into ``adopted=False`` with the error as the reason.
    """
    uv, conf, frame = gather_pixels(tracks, assoc, rig.n_views)
    result = _refine(tracks.n_frames, rig, uv, conf, frame, cfg)
    pix = AthletePixels(uv, conf, assoc.n_persons, tuple(tracks.joint_names), cfg.bundle.min_conf)
    level = level_world(result.rig, pix, cfg.floor)
    turned = transform_world(result.rig, rigid(level.rotation))
    floor = estimate_floor(turned, pix, cfg.floor, up_measured=level.up_measured)
    return replace(result, rig=lower_world(turned, floor.shift_m), floor=floor, level=level)


def _refine(
    n_frames: int, rig: CameraRig, uv: np.ndarray, conf: np.ndarray, frame: np.ndarray, cfg: CalibrateConfig
) -> CalibrationResult:
    """Refine ``rig`` on the associated keypoints of ``n_frames`` frames, ``gather_pixels``'
    rows (steps 1-4 of the module docstring).

    Raises:
        ValueError: with ``mode="on"``, the errors of ``bundle_adjust``; ``auto`` turns those
        into ``adopted=False`` with the error as the reason.
    """
    if cfg.mode == "off":
        return CalibrationResult(rig=rig, adopted=False, reason="calibration refinement is off (mode='off')")
    if cfg.mode == "on":
        res = bundle_adjust(rig, uv, conf, cfg.bundle)
        # The adjustment's own before/after statistics cover the same observations.
        return _result(
            rig,
            res,
            True,
            "refined rig used as configured (mode='on')",
            uv,
            conf,
            cfg,
            full=(res.before, res.after),
        )

    if n_frames < 2 * cfg.min_blocks:
        reason = f"not refined: {n_frames} frames are too few for {cfg.min_blocks} held-out blocks"
        return CalibrationResult(rig=rig, adopted=False, reason=reason)
    block_frames = min(cfg.block_s * rig.fps, n_frames / cfg.min_blocks)
    fit = np.floor(frame / block_frames).astype(np.int64) % 2 == 0
    try:
        res = bundle_adjust(rig, uv[fit], conf[fit], cfg.bundle)
    except ValueError as e:
        return CalibrationResult(rig=rig, adopted=False, reason=f"not refined: {e}")
    hold_uv, hold_w = uv[~fit], np.where(conf[~fit] >= cfg.bundle.min_conf, conf[~fit], 0.0)
    seen = (hold_w > 0).sum(axis=1) >= 2
    hb, ha = reprojection_stats(rig, hold_uv[seen], hold_w[seen], res.rig, cfg.bundle.start_threshold_px)
    if not np.isfinite(hb.all_median_px) or not np.isfinite(ha.all_median_px):
        return _result(
            rig, res, False, "not adopted: no held-out points to validate on", uv, conf, cfg, hb, ha
        )
    gain = 1.0 - ha.all_median_px / max(hb.all_median_px, 1e-12)
    worse = ha.median_px > hb.median_px * (1.0 + cfg.min_improvement)
    change = f"{100 * gain:.1f} % better" if gain >= 0 else f"{-100 * gain:.1f} % worse"
    msg = f"held-out median {hb.all_median_px:.2f} -> {ha.all_median_px:.2f} px ({change})"
    if gain < cfg.min_improvement:
        reason = f"not adopted: {msg}, below the required {100 * cfg.min_improvement:.1f} %"
        return _result(rig, res, False, reason, uv, conf, cfg, hb, ha)
    if worse.any():
        names = [
            f"{rig.names[v]} {hb.median_px[v]:.2f} -> {ha.median_px[v]:.2f} px" for v in np.flatnonzero(worse)
        ]
        reason = f"not adopted: {msg}, but held-out error rises on {', '.join(names)}"
        return _result(rig, res, False, reason, uv, conf, cfg, hb, ha)
    return _result(rig, res, True, f"adopted: {msg}", uv, conf, cfg, hb, ha)


def _result(
    rig: CameraRig,
    res: BundleResult,
    adopted: bool,
    reason: str,
    uv: np.ndarray,
    conf: np.ndarray,
    cfg: CalibrateConfig,
    held_before: ReprojectionStats | None = None,
    held_after: ReprojectionStats | None = None,
    full: tuple[ReprojectionStats, ReprojectionStats] | None = None,
) -> CalibrationResult:
    if full is None:
        w = np.where(conf >= cfg.bundle.min_conf, conf, 0.0)
        seen = (w > 0).sum(axis=1) >= 2
        full = reprojection_stats(rig, uv[seen], w[seen], res.rig, cfg.bundle.start_threshold_px)
    before, after = full
    return CalibrationResult(
        rig=res.rig if adopted else rig,
        adopted=adopted,
        reason=reason,
        before=before,
        after=after,
        heldout_before_px=held_before.all_median_px if held_before else float("nan"),
        heldout_after_px=held_after.all_median_px if held_after else float("nan"),
        center_shift_m=np.linalg.norm(res.rig.centers_world_m - rig.centers_world_m, axis=1),
        rotation_change_deg=turns_between_deg(rig.T_world_cam[:, :3, :3], res.rig.T_world_cam[:, :3, :3]),
        focal_scale=res.rig.K[:, 0, 0] / rig.K[:, 0, 0],
        converged=res.converged,
    )


def rig_change(a: CameraRig, b: CameraRig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per camera of two rigs with the same cameras: centre shift (mm), rotation change
    (degrees) and relative focal change; ``ValueError`` when the cameras differ."""
    if a.names != b.names:
        raise ValueError(f"rig_change: different cameras {list(a.names)} vs {list(b.names)}")
    centre = 1000.0 * np.linalg.norm(a.centers_world_m - b.centers_world_m, axis=1)
    rot = turns_between_deg(a.T_world_cam[:, :3, :3], b.T_world_cam[:, :3, :3])
    return centre, rot, np.abs(b.K[:, 0, 0] / a.K[:, 0, 0] - 1.0)


def holds(previous: CameraRig, new: CameraRig, cfg: CalibrateConfig) -> bool:
    """True when ``new`` is within the config's hold thresholds of ``previous`` in every camera."""
    if previous.names != new.names:
        return False
    centre, rot, focal = rig_change(previous, new)
    return bool(
        np.all(centre <= cfg.hold_center_mm)
        and np.all(rot <= cfg.hold_rotation_deg)
        and np.all(focal <= cfg.hold_focal_rel)
    )


def summary(result: CalibrationResult) -> dict[str, Any]:
    """Small scalar metrics for the manifest / run table."""

    def r(x: float) -> float | None:
        return round(float(x), 2) if np.isfinite(x) else None

    out: dict[str, Any] = {"adopted": result.adopted, "reason": result.reason, "converged": result.converged}
    out["heldout_before_px"], out["heldout_after_px"] = (
        r(result.heldout_before_px),
        r(result.heldout_after_px),
    )
    if result.before is not None and result.after is not None:
        out["median_before_px"] = r(result.before.all_median_px)
        out["median_after_px"] = r(result.after.all_median_px)
    out["max_center_shift_mm"] = r(1000.0 * float(result.center_shift_m.max(initial=0.0)))
    out["max_rotation_change_deg"] = r(float(result.rotation_change_deg.max(initial=0.0)))
    if result.floor is not None:
        out["floor_z_mm"] = r(1000.0 * result.floor.floor_z_m)
        out["floor_shift_m"] = round(result.floor.shift_m, 6)
        out["floor"] = result.floor.reason
    if result.level is not None:
        out["floor_tilt_deg"] = r(result.level.tilt_deg)
        out["body_tilt_deg"] = r(result.level.body_tilt_deg)
        out["world_turn_deg"] = r(turn_deg(result.level.rotation))
        out["level"] = result.level.reason
    return out
