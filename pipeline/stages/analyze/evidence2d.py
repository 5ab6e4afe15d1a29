"""2D evidence of a punch, per camera view: the wrist moving fast in the image.

With two views the body fit can nearly erase a punch (``motion``), while each camera's 2D
track still shows the wrist leaving the guard. Per athlete, view and hand, the wrist is taken
relative to the neck (the shoulders' midpoint) in the image, so that the athlete walking or
turning moves both together and does not count, and scaled to metres by the athlete's image
size: the torso length in pixels (shoulders' midpoint to hips' midpoint, a running median)
against the 3D torso length. The result is a *projected* motion: the component of the fist's
motion across that camera's line of sight, never more than the 3D motion.

Per view the guard position is the running median of the scaled wrist over frames where it
is nearly still (as ``punches.hand_track`` in 3D) and the excursion is the distance from it;
the speed is the central difference of the scaled wrist. ``view_signals`` gives both on the
analysed frames; ``window_evidence`` the largest of them over one excursion, per view.

``view_punches`` turns this into punches: a 3D excursion of the fist of at least
``ViewEvidenceConfig.min_excursion_3d_m`` that passes every punch rule but those on speed, whose
way out the raw triangulation did not measure (``ViewEvidenceConfig.unmeasured_only``), and that
one view shows far and fast enough (``view_failed``). ``view_peak_speed`` bounds a punch's
peak speed from below where the raw triangulation could not measure it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.schema.association import Association
from pipeline.schema.detections import Tracks2D
from pipeline.stages.analyze.body import Body, fill_gaps
from pipeline.stages.analyze.config import PunchConfig, ViewEvidenceConfig
from pipeline.stages.analyze.punches import Candidate, Detection, HandTrack, candidates, overlaps, rule_failed

JOINTS: tuple[str, ...] = (
    "left_shoulder", "right_shoulder", "left_hip", "right_hip", "left_wrist", "right_wrist",
)  # fmt: skip
"""The 2D joints the evidence reads (``person_views``)."""


@dataclass(frozen=True)
class PersonViews:
    """One athlete's 2D joints in every view, on the analysed frames.

    Fields: person_id; joint_names (joints,) = ``JOINTS``; xy_px (views, frames, joints, 2)
    image coordinates, pixels (0 where not ok); ok (views, frames, joints) bool, the joint
    was detected in that view and frame and attributed to this athlete.
    """

    person_id: int
    joint_names: tuple[str, ...]
    xy_px: np.ndarray
    ok: np.ndarray

    def __post_init__(self) -> None:
        v, f, j = self.ok.shape if self.ok.ndim == 3 else (-1, -1, -1)
        if j != len(self.joint_names) or self.xy_px.shape != (v, f, j, 2):
            raise ValueError(
                f"PersonViews: xy_px {self.xy_px.shape} and ok {self.ok.shape} must be (views, frames, "
                f"{len(self.joint_names)}, 2) and (views, frames, {len(self.joint_names)})"
            )

    @property
    def n_views(self) -> int:
        return int(self.ok.shape[0])

    def joint(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(views, frames, 2) pixels and (views, frames) validity of joint ``name``."""
        j = self.joint_names.index(name)
        return self.xy_px[:, :, j], self.ok[:, :, j]


def person_views(
    tracks: Tracks2D,
    association: Association,
    person_id: int,
    frame_indices: np.ndarray,
    min_conf: float = 0.0,
) -> PersonViews:
    """The 2D joints of athlete ``person_id`` per view on ``frame_indices`` (the analysed video
    frames). Where two detections of one view and frame are attributed to the athlete, the one
    with the higher association confidence is used. Joints below ``min_conf`` are invalid.

    Raises ``ValueError`` when ``association`` does not have one row per ``tracks`` row, or
    ``tracks`` lacks a joint of ``JOINTS``."""
    if association.person_of_det.shape[0] != tracks.n_dets:
        raise ValueError(
            f"evidence2d: the association has {association.person_of_det.shape[0]} rows for "
            f"{tracks.n_dets} track rows (it must come from the same tracks)"
        )
    missing = [n for n in JOINTS if n not in tracks.joint_names]
    if missing:
        raise ValueError(f"evidence2d: the 2D tracks lack joints {missing} (have {list(tracks.joint_names)})")
    frames = np.asarray(frame_indices, dtype=np.int64)
    cols = [tracks.joint_names.index(n) for n in JOINTS]
    n_v, n_f = tracks.n_views, frames.shape[0]
    xy = np.zeros((n_v, n_f, len(JOINTS), 2))
    ok = np.zeros((n_v, n_f, len(JOINTS)), dtype=bool)
    rows = np.flatnonzero(association.person_of_det == person_id)
    if rows.size == 0 or n_f == 0:
        return PersonViews(int(person_id), JOINTS, xy, ok)
    # Lowest confidence first, so that the best detection of a (view, frame) is written last.
    rows = rows[np.argsort(association.confidence[rows], kind="stable")]
    at = np.searchsorted(frames, tracks.frame[rows])
    at_c = np.minimum(at, n_f - 1)
    keep = frames[at_c] == tracks.frame[rows]
    rows, at_c = rows[keep], at_c[keep]
    kp = tracks.keypoints_px[rows][:, cols]
    good = tracks.keypoint_valid[rows][:, cols] & (tracks.keypoint_conf[rows][:, cols] >= min_conf)
    view = tracks.view[rows]
    xy[view, at_c] = np.where(good[..., None], kp, 0.0)
    ok[view, at_c] = good
    return PersonViews(int(person_id), JOINTS, xy, ok)


@dataclass(frozen=True)
class ViewSignals:
    """One fist's projected motion per view (views, frames).

    Fields: excursion_m distance of the scaled wrist (relative to the neck) from its guard
    position, metres across the line of sight (0 where not ok); speed_mps its speed (central
    differences), m/s (0 where not ok); ok bool, the wrist, the neck and the image scale are
    known there; step_mps the wrist's own frame-to-frame displacement (not relative to the
    neck) times the frame rate, m/s, at the later frame of each pair (0 where either is unknown).
    """

    hand: str
    excursion_m: np.ndarray
    speed_mps: np.ndarray
    ok: np.ndarray
    step_mps: np.ndarray


def _running_median_1d(x: np.ndarray, use: np.ndarray, half: int) -> np.ndarray:
    """(frames,) median of ``x`` over a centred window of ``2 * half + 1`` frames, over the
    frames where ``use``; NaN where a window holds none."""
    out = np.full(x.shape[0], np.nan)
    for t in range(x.shape[0]):
        w = x[max(0, t - half) : t + half + 1][use[max(0, t - half) : t + half + 1]]
        if w.size:
            out[t] = np.median(w)
    return out


def image_scale_m_per_px(pv: PersonViews, torso_m: float, fps: float, window_s: float) -> np.ndarray:
    """(views, frames) metres per pixel of the athlete in each view: ``torso_m`` over the image
    torso length (shoulders' midpoint to hips' midpoint), a running median over ``window_s``
    seconds; NaN where no torso was seen within the window."""
    ls, lok = pv.joint("left_shoulder")
    rs, rok = pv.joint("right_shoulder")
    lh, hok = pv.joint("left_hip")
    rh, rhok = pv.joint("right_hip")
    torso_px = np.linalg.norm(0.5 * (ls + rs) - 0.5 * (lh + rh), axis=-1)
    use = lok & rok & hok & rhok & (torso_px > 1.0)
    half = max(1, int(round(0.5 * window_s * fps)))
    med = np.stack([_running_median_1d(torso_px[v], use[v], half) for v in range(pv.n_views)])
    return torso_m / med


def view_signals(
    pv: PersonViews,
    hand: str,
    m_per_px: np.ndarray,
    fps: float,
    guard_window_s: float,
    rest_speed_mps: float,
    max_gap: int,
) -> ViewSignals:
    """The projected excursion and speeds of ``hand``'s wrist in every view (module docstring);
    ``m_per_px`` (views, frames) from ``image_scale_m_per_px``; gaps of the wrist or the neck
    up to ``max_gap`` frames are interpolated first (a fast fist blurs and drops out)."""
    w, wok = pv.joint(f"{hand}_wrist")
    ls, lok = pv.joint("left_shoulder")
    rs, rok = pv.joint("right_shoulder")
    n_v, n_f = wok.shape
    scale = np.where(np.isfinite(m_per_px), m_per_px, 0.0)
    r = np.zeros((n_v, n_f, 2))
    x = np.zeros((n_v, n_f, 2))
    ok = np.zeros((n_v, n_f), dtype=bool)
    okx = np.zeros((n_v, n_f), dtype=bool)
    for v in range(n_v):
        neck, nok = fill_gaps(0.5 * (ls[v] + rs[v]), lok[v] & rok[v], max_gap)
        wv, wvok = fill_gaps(w[v], wok[v], max_gap)
        ok[v] = wvok & nok & (scale[v] > 0)
        okx[v] = wvok & (scale[v] > 0)
        r[v] = (wv - neck) * scale[v][:, None]
        x[v] = wv * scale[v][:, None]
    speed = np.zeros((n_v, n_f))
    step = np.zeros((n_v, n_f))
    if n_f >= 3:
        good = ok[:, 2:] & ok[:, :-2] & ok[:, 1:-1]
        speed[:, 1:-1] = np.where(good, np.linalg.norm(r[:, 2:] - r[:, :-2], axis=-1) * fps / 2.0, 0.0)
    if n_f >= 2:
        step[:, 1:] = np.where(
            okx[:, 1:] & okx[:, :-1], np.linalg.norm(x[:, 1:] - x[:, :-1], axis=-1) * fps, 0.0
        )
    half = max(1, int(round(0.5 * guard_window_s * fps)))
    exc = np.zeros((n_v, n_f))
    for v in range(n_v):
        still = ok[v] & (speed[v] < rest_speed_mps)
        guard = np.stack([_running_median_1d(r[v, :, k], still, half) for k in range(2)], axis=1)
        have = ok[v] & np.isfinite(guard).all(axis=1)
        exc[v] = np.where(have, np.linalg.norm(r[v] - np.where(have[:, None], guard, 0.0), axis=1), 0.0)
        ok[v] &= have
    return ViewSignals(hand, exc, np.where(ok, speed, 0.0), ok, step)


def window_evidence(sig: ViewSignals, start: int, peak: int, end: int) -> tuple[np.ndarray, np.ndarray]:
    """Per view (views,): the largest projected excursion (m) over rows ``start .. end`` and the
    largest projected speed relative to the neck (m/s) over the way out ``start .. peak``
    (inclusive); 0 in a view that did not see the wrist there."""
    n = sig.ok.shape[1]
    lo, hi, mid = max(0, start), min(n, end + 1), min(n, peak + 1)
    if hi <= lo:
        return np.zeros(sig.ok.shape[0]), np.zeros(sig.ok.shape[0])
    exc = np.where(sig.ok[:, lo:hi], sig.excursion_m[:, lo:hi], 0.0).max(axis=1)
    speed = (
        np.where(sig.ok[:, lo:mid], sig.speed_mps[:, lo:mid], 0.0).max(axis=1)
        if mid > lo
        else np.zeros(sig.ok.shape[0])
    )
    return exc, speed


def view_peak_speed(sig: ViewSignals, start: int, peak: int) -> float | None:
    """Largest projected frame-to-frame speed of the wrist (m/s, not relative to the neck) over
    rows ``start .. peak + 1`` in any view: a lower bound of the 3D peak speed where the wrist
    was seen, up to the 2D noise; None when no view saw two consecutive frames there."""
    lo, hi = max(1, start), min(sig.step_mps.shape[1], peak + 2)
    step = sig.step_mps[:, lo:hi]
    return float(step.max()) if step.size and step.max() > 0 else None


VIEW_RULES: tuple[str, ...] = ("new", "whole", "unmeasured", "form", "views")
"""The checks a weak 3D excursion passes to count as a punch seen in 2D (``view_failed``)."""
MOTION_ONLY: tuple[str, ...] = ("out_speed", "peak_speed")
"""Punch rules (``punches.RULES``) about the fist's speed, which the 2D evidence replaces."""


def view_failed(
    c: Candidate,
    sig: ViewSignals,
    found: list[Detection],
    cfg: PunchConfig,
    vcfg: ViewEvidenceConfig,
    fps: float,
) -> str | None:
    """The first check of ``VIEW_RULES`` the 3D candidate ``c`` fails, None for a punch:
    ``new``, no punch of ``found`` (the same fist's) overlaps it; ``whole``, it lies inside the
    clip (an excursion cut by the first or last frame has no way out or back to judge);
    ``unmeasured``, with ``vcfg.unmeasured_only``, the raw triangulation did not measure its way
    out (``c.measured_mps`` is NaN: under 60 % of those frames triangulated); ``form``, it passes every punch
    rule but those on speed (``MOTION_ONLY``); ``views``, one view shows the wrist at least
    ``vcfg.view_min_excursion_m`` from its guard and at least ``vcfg.view_min_speed_mps`` fast on the way out."""
    if any(overlaps(c.start, c.end, d.start, d.end) for d in found):
        return "new"
    if c.start <= 0 or c.end >= sig.ok.shape[1] - 1:
        return "whole"
    if vcfg.unmeasured_only and np.isfinite(c.measured_mps):
        return "unmeasured"
    # The speed rules are the views' to judge, the excursion was (``min_excursion_3d_m``).
    loose = replace(c, out_speed_mps=np.inf, peak_speed_mps=np.inf, measured_mps=np.inf, excursion_m=np.inf)
    if rule_failed(loose, cfg, fps) is not None:
        return "form"
    exc, speed = window_evidence(sig, c.start, c.peak, c.end)
    if not np.any((exc >= vcfg.view_min_excursion_m) & (speed >= vcfg.view_min_speed_mps)):
        return "views"
    return None


def view_punches(
    body: Body,
    h: HandTrack,
    sig: ViewSignals,
    found: list[Detection],
    cfg: PunchConfig,
    vcfg: ViewEvidenceConfig,
    clinch: np.ndarray | None = None,
    raw: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> list[Detection]:
    """The punches of one fist that the 3D shows too weak or too slow and a view shows fast
    (``view_failed``), in time order; ``found``: the punches already detected on that fist;
    ``raw``: the fist's raw wrist (``punches.candidates``), where a candidate's speed is measured.
    Rows index the analysed frames of ``body``, ``h`` and ``sig`` alike."""
    if sig.ok.shape[1] != body.n_frames:
        raise ValueError(
            f"evidence2d: the view signals have {sig.ok.shape[1]} frames, the body {body.n_frames}"
        )
    relaxed = replace(cfg, min_excursion_m=min(cfg.min_excursion_m, vcfg.min_excursion_3d_m))
    out: list[Detection] = []
    for c in candidates(body, h, relaxed, clinch, raw):
        if view_failed(c, sig, found + out, cfg, vcfg, body.fps) is not None:
            continue
        score = np.clip(c.excursion_m / cfg.min_excursion_m, 0.0, 1.0)
        # Lower confidence than a punch the 3D shows: one view's projection vouches for it.
        out.append(Detection(c.hand, c.start, c.peak, c.end, c.fastest, c.excursion_m, c.out_speed_mps,
                             c.peak_speed_mps, c.extension, float(0.5 * score)))  # fmt: skip
    return out
