"""analyze: boxing analytics on a 3D result (pure: data in, data out).

A readable chain: the athletes' joint tracks (``body``) -> per fist, the punches
(``punches``; and those the fit flattened, from the filtered triangulation: ``motion``, or
confirmed by the 2D tracks of each view: ``evidence2d``) ->
their type (``classify``) and outcome (``outcome``) -> the defender's slips and ducks and the clinches (``defence``), blocks and parries (``blocks``) -> the
per-frame series (``ring``, ``workrate``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline.evaluate.glove_contact import glove_gaps
from pipeline.schema.analytics import AthleteSeries, BoutEvents
from pipeline.schema.annotations import Annotation
from pipeline.schema.association import Association
from pipeline.schema.detections import Tracks2D
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import PhysicsResult
from pipeline.stages.analyze import blocks, classify, defence, evidence2d, outcome, ring
from pipeline.stages.analyze.body import Body, bodies, facing_frames, fill_gaps, opponent_of
from pipeline.stages.analyze.config import AnalyzeConfig
from pipeline.stages.analyze.corrections import Athlete, apply_corrections
from pipeline.stages.analyze.motion import flattened_punches
from pipeline.stages.analyze.punches import detect, hand_track, raw_peak_speed
from pipeline.stages.analyze.workrate import punches_per_min

REQUIRED_JOINTS: tuple[str, ...] = (
    "left_ear", "right_ear", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist", "left_hip", "right_hip", "left_ankle", "right_ankle",
)  # fmt: skip


@dataclass(frozen=True)
class AnalyzeInputs:
    """keypoints: the 3D result analysed; physics: the physics stage's result when the
    keypoints are its own (its contacts then decide outcomes where they exist); raw: the
    unfiltered triangulation, where the peak glove speeds are measured
    (``PunchConfig.speed_source``) and punches the fit flattened are confirmed; filtered: the
    filtered triangulation, where punches the fit flattened are looked for
    (``PunchConfig.flattened``, ``motion``; unused when it is the analysed result itself);
    corrections: annotators' event edits, applied in order after detection
    (``corrections.apply_corrections``; other edit kinds are ignored); tracks and association:
    the 2D tracks of every view and their athletes, where punches the fit flattened are
    confirmed (``AnalyzeConfig.views``, ``evidence2d``; both or neither, one association row
    per track row, else ``ValueError``)."""

    keypoints: Keypoints3D
    physics: PhysicsResult | None = None
    raw: Keypoints3D | None = None
    filtered: Keypoints3D | None = None
    corrections: tuple[Annotation, ...] = ()
    tracks: Tracks2D | None = None
    association: Association | None = None

    def __post_init__(self) -> None:
        if (self.tracks is None) != (self.association is None):
            raise ValueError("AnalyzeInputs: tracks and association go together (got only one of them)")
        if self.tracks is not None and self.association is not None:
            if self.association.person_of_det.shape[0] != self.tracks.n_dets:
                raise ValueError(
                    f"AnalyzeInputs: the association has {self.association.person_of_det.shape[0]} rows for "
                    f"{self.tracks.n_dets} track rows (it must come from the same tracks)"
                )


@dataclass(frozen=True)
class AnalyzeOutput:
    events: BoutEvents
    series: AthleteSeries
    stats: dict[str, Any] = field(default_factory=dict)


@dataclass
class _Punch:
    person: int
    hand: str
    type: str
    start: int
    peak: int
    end: int
    speed: float
    extension: float
    target: str
    outcome: str
    confidence: float


def _rows_on(src: Keypoints3D, kp: Keypoints3D) -> tuple[np.ndarray, np.ndarray]:
    """(frames,) rows of ``src`` at ``kp``'s frames (clipped) and whether ``src`` has that frame."""
    rows = np.searchsorted(src.frame_indices, kp.frame_indices)
    rows_c = np.minimum(rows, max(src.n_frames - 1, 0))
    same = (rows < src.n_frames) & (src.frame_indices[rows_c] == kp.frame_indices)
    return rows_c, same


def _motion_body(filtered: Keypoints3D | None, kp: Keypoints3D, pid: int, max_gap: int) -> Body | None:
    """Athlete ``pid`` of another 3D result (the filtered or the raw triangulation) on ``kp``'s
    frames and joints (matched by name; a joint it lacks is invalid), short gaps filled; None
    without one, or when ``kp`` is that result already (nothing to compare)."""
    if filtered is None or filtered is kp or pid not in filtered.person_ids.tolist() or filtered.n_frames == 0:
        return None
    p = filtered.person_index(pid)
    rows, same = _rows_on(filtered, kp)
    have = [n in filtered.joint_names for n in kp.joint_names]
    cols = [filtered.joint_names.index(n) if h else 0 for n, h in zip(kp.joint_names, have, strict=True)]
    ok = filtered.valid[rows][:, p][:, cols] & same[:, None] & np.array(have)[None, :]
    xyz = np.where(ok[..., None], filtered.xyz_m[rows][:, p][:, cols], 0.0)
    for j in range(len(kp.joint_names)):
        xyz[:, j], ok[:, j] = fill_gaps(xyz[:, j], ok[:, j], max_gap)
    conf = np.where(ok, np.clip(filtered.confidence[rows][:, p][:, cols], 0.0, 1.0), 0.0)
    return Body(pid, kp.joint_names, xyz, ok, conf, float(kp.fps))


def _raw_wrists(raw: Keypoints3D | None, kp: Keypoints3D, pid: int) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Hand -> (frames, 3) raw wrist positions on ``kp``'s frames, their validity and their
    view counts (empty without a raw result holding that athlete)."""
    if raw is None or pid not in raw.person_ids.tolist() or raw.n_frames == 0:
        return {}
    p = raw.person_index(pid)
    rows_c, same = _rows_on(raw, kp)
    out = {}
    for hand in ("left", "right"):
        if f"{hand}_wrist" in raw.joint_names:
            j = raw.joint_names.index(f"{hand}_wrist")
            out[hand] = (raw.xyz_m[rows_c, p, j], same & raw.valid[rows_c, p, j], raw.n_views[rows_c, p, j])
    return out


def _view_signals(inp: AnalyzeInputs, kp: Keypoints3D, me: Body, cfg: AnalyzeConfig) -> dict[str, evidence2d.ViewSignals]:
    """Hand -> the athlete's wrist motion in every view (``evidence2d``); empty when neither
    use of the views is on, the stage has no 2D tracks, or the 3D torso is never estimated."""
    if not (cfg.views.enabled or cfg.views.lift_speed) or inp.tracks is None or inp.association is None:
        return {}
    sh, sok = me.point("mid:left_shoulder+right_shoulder")
    hip, hok = me.point("mid:left_hip+right_hip")
    if not (sok & hok).any():
        return {}
    torso_m = float(np.median(np.linalg.norm(sh - hip, axis=1)[sok & hok]))
    pv = evidence2d.person_views(inp.tracks, inp.association, me.person_id, kp.frame_indices, cfg.views.min_conf)
    m_per_px = evidence2d.image_scale_m_per_px(pv, torso_m, me.fps, cfg.views.scale_window_s)
    p = cfg.punch
    return {
        hand: evidence2d.view_signals(pv, hand, m_per_px, me.fps, p.guard_window_s, p.rest_speed_mps, p.max_gap_frames)
        for hand in ("left", "right")
    }


def _with_filtered_reach(gaps: dict[str, np.ndarray], me: Body, opp: Body, motion: Body, hand: str, rows: np.ndarray,
                         views: np.ndarray, cfg: AnalyzeConfig) -> dict[str, np.ndarray]:  # fmt: skip
    """``gaps`` (region -> (rows,) gaps of the analysed glove, m), or, when the raw wrist was seen by
    fewer than ``OutcomeConfig.filtered_reach_views`` views (median over the punch), the smaller of
    them and the gaps of the glove placed by the filtered triangulation's elbow and wrist (``motion``,
    where estimated): a fit from two views shortens the punch, so its gaps err on the large side."""
    if views.size == 0 or float(np.median(views)) >= cfg.outcome.filtered_reach_views:
        return gaps
    cols = [me.names.index(f"{hand}_{j}") for j in ("elbow", "wrist")]
    xyz = me.xyz[rows].copy()
    have = motion.ok[rows][:, cols].all(axis=1)
    xyz[:, cols] = np.where(have[:, None, None], motion.xyz[rows][:, cols], xyz[:, cols])
    other = glove_gaps(xyz, hand, opp.xyz[rows], me.names)
    return {k: np.minimum(v, other[k]) for k, v in gaps.items()}


def _punches_of(me: Body, opp: Body | None, R: np.ndarray, r_ok: np.ndarray, stance_codes: np.ndarray,
                cfg: AnalyzeConfig, physics: PhysicsResult | None, frames: np.ndarray, clinch: np.ndarray,
                raw: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], motion: Body | None,
                views: dict[str, evidence2d.ViewSignals]) -> list[_Punch]:  # fmt: skip
    """The punches of ``me`` at ``opp`` (facing frames ``R``, valid ``r_ok``); ``raw``: hand ->
    raw wrist track for the speeds; ``motion``: the same athlete on the filtered triangulation,
    where punches the fit flattened are looked for (``motion``), or None; ``views``: hand -> the
    wrist's motion per view, where such punches are confirmed (``evidence2d``), or empty."""
    need = [me.names.index(j) for j in REQUIRED_JOINTS]
    out: list[_Punch] = []
    Rm, rm_ok = facing_frames(motion, opp) if motion is not None else (R, r_ok)
    for hand in ("left", "right"):
        h = hand_track(me, R, r_ok, hand, cfg.punch)
        found = detect(me, h, cfg.punch, clinch, raw.get(hand))
        if motion is not None and cfg.punch.flattened:
            hm = hand_track(motion, Rm, rm_ok, hand, cfg.punch)
            found = sorted(found + flattened_punches(motion, hm, me, h, raw.get(hand), cfg.punch, clinch),
                           key=lambda d: d.peak)  # fmt: skip
        if hand in views and cfg.views.enabled:
            seen = evidence2d.view_punches(me, h, views[hand], found, cfg.punch, cfg.views, clinch, raw.get(hand))
            found = sorted(found + seen, key=lambda d: d.peak)
        for d in found:
            speed = d.peak_speed_mps
            if cfg.punch.speed_source == "raw":
                path = h.wrist if cfg.punch.speed_along_path else None
                measured = raw_peak_speed(*raw[hand], d.start, d.peak, me.fps, path) if hand in raw else None
                if measured is None and hand in views and cfg.views.lift_speed:
                    measured = evidence2d.view_peak_speed(views[hand], d.start, d.peak)
                if measured is not None:
                    speed = float(np.clip(measured, speed, cfg.punch.raw_speed_max_ratio * speed))
            target, result = "none", "missed"
            level = (float("nan"), float("nan"))
            if opp is not None:
                hip, hok = opp.point("mid:left_hip+right_hip")
                sh, sok = opp.point("mid:left_shoulder+right_shoulder")
                if hok[d.peak] and sok[d.peak]:
                    level = (float(hip[d.peak, 2]), float(sh[d.peak, 2]))
                rows = np.arange(max(0, d.peak - cfg.outcome.window_frames), min(me.n_frames, d.peak + cfg.outcome.window_frames + 1))
                ok = me.ok[rows][:, need].all(axis=1) & opp.ok[rows][:, need].all(axis=1)
                if ok.any():
                    gaps = glove_gaps(me.xyz[rows[ok]], hand, opp.xyz[rows[ok]], me.names)
                    if motion is not None and cfg.outcome.filtered_reach and hand in raw:
                        gaps = _with_filtered_reach(gaps, me, opp, motion, hand, rows[ok], raw[hand][2][d.start : d.end + 1], cfg)
                    target, result = outcome.from_gaps({k: float(v.min()) for k, v in gaps.items()}, cfg.outcome)
                if physics is not None and cfg.outcome.use_contacts:
                    hit = outcome.from_contacts(outcome.contact_regions(physics, me.person_id, hand, opp.person_id, frames[rows]))
                    if hit is not None:
                        target, result = hit
            f = classify.path_features(h.r, d.start, d.fastest, d.peak, hand, float(h.wrist[d.peak, 2]), *level)
            kind = classify.punch_type(f, classify.is_lead(hand, stance_codes, d.peak), cfg.types)
            out.append(_Punch(me.person_id, hand, kind, d.start, d.peak, d.end, speed,
                              d.extension if np.isfinite(d.extension) else 0.0, target, result, d.confidence))  # fmt: skip
    return out


def _check(kp: Keypoints3D) -> None:
    missing = [j for j in REQUIRED_JOINTS if j not in kp.joint_names]
    if missing:
        raise ValueError(f"analyze: the keypoints lack joints {missing} (have {list(kp.joint_names)})")


def run(inp: AnalyzeInputs, cfg: AnalyzeConfig = AnalyzeConfig()) -> AnalyzeOutput:
    """Punches, evasions, clinches and series of every athlete in ``inp.keypoints``.

    Raises ``ValueError`` when the keypoints lack a joint the analytics needs
    (``REQUIRED_JOINTS``). Persons are analysed against their nearest other person.
    """
    kp = inp.keypoints
    _check(kp)
    frames = kp.frame_indices
    bs = bodies(kp, cfg.punch.max_gap_frames)
    opps = [opponent_of(bs, i) for i in range(len(bs))]
    n_f, n_p = kp.n_frames, kp.n_persons
    stance = np.zeros((n_f, n_p), dtype=np.int64)
    width = np.zeros((n_f, n_p))
    guard = np.zeros((n_f, n_p, 2))
    valid = np.zeros((n_f, n_p), dtype=bool)
    position = np.zeros((n_f, n_p, 2))
    position_ok = np.zeros((n_f, n_p), dtype=bool)
    punches: list[_Punch] = []
    clinch = np.zeros(n_f, dtype=bool)
    grip = clinch
    dist, dist_ok = np.zeros(n_f), np.zeros(n_f, dtype=bool)
    if len(bs) >= 2:
        clinch = defence.clinch_frames(bs[0], bs[1], cfg.defence)
        # Punches are not looked for where the hands take, hold or leave a grip: the clinch
        # test without its arms-around condition, which the clinch itself needs.
        grip = clinch | defence.clinch_frames(bs[0], bs[1], cfg.defence, arms_around=False)
        dist, dist_ok = ring.distance(bs[0], bs[1])
    for i, me in enumerate(bs):
        R, r_ok = facing_frames(me, opps[i])
        stance[:, i], width[:, i] = ring.stance(me, R, r_ok, cfg.ring)
        guard[:, i] = ring.guard_height(me, cfg.ring)
        valid[:, i] = me.ok[:, [kp.joint_names.index(j) for j in REQUIRED_JOINTS]].all(axis=1)
        hip, position_ok[:, i] = me.point("mid:left_hip+right_hip")
        position[:, i] = np.where(position_ok[:, i, None], hip[:, :2], 0.0)
        raw = _raw_wrists(inp.raw, kp, me.person_id)
        motion = _motion_body(inp.filtered, kp, me.person_id, cfg.punch.max_gap_frames)
        views = _view_signals(inp, kp, me, cfg)
        punches += _punches_of(me, opps[i], R, r_ok, stance[:, i], cfg, inp.physics, frames, grip, raw, motion, views)
    punches.sort(key=lambda p: (p.peak, p.person))
    by_id = {b.person_id: b for b in bs}
    measured = {b.person_id: _motion_body(inp.raw, kp, b.person_id, cfg.punch.max_gap_frames) for b in bs}
    evades: list[tuple[int, defence.Evade, int]] = []
    for k, p in enumerate(punches):
        opp = opps[[b.person_id for b in bs].index(p.person)]
        if opp is None or p.outcome == "landed" or p.type == "body_shot":
            continue
        ev = defence.evade(opp, by_id[p.person], p.hand, p.start, p.peak, cfg.defence)
        if ev is not None:
            evades.append((opp.person_id, ev, k))
    for k, p in enumerate(punches):
        opp = opps[[b.person_id for b in bs].index(p.person)]
        if opp is None or p.outcome == "landed":
            continue
        m_att, m_def = measured[p.person], measured[opp.person_id]
        guard_ev = blocks.defend(by_id[p.person], opp, p.hand, p.start, p.peak, p.end, inp.physics, frames, cfg,
                                 (m_att, m_def) if m_att is not None and m_def is not None else None)  # fmt: skip
        if guard_ev is not None:
            evades.append((opp.person_id, guard_ev, k))
    evades.sort(key=lambda e: (e[1].peak, e[0]))
    events = _events(kp, punches, evades, defence.runs(clinch))
    athletes = {b.person_id: Athlete(b, opps[i]) for i, b in enumerate(bs)}
    events, fixes = apply_corrections(events, inp.corrections, athletes, frames, cfg)
    rate = np.zeros((n_f, n_p))
    for i, b in enumerate(bs):
        strikes = events.punch_peak_frame[events.punch_person == b.person_id]
        rate[:, i] = punches_per_min(frames, kp.fps, strikes, cfg.work_rate) if n_f else 0.0
    series = AthleteSeries(
        frame_indices=frames.astype(np.int64), fps=float(kp.fps), person_ids=kp.person_ids.astype(np.int64),
        valid=valid, distance_m=dist, distance_valid=dist_ok, stance=stance, stance_width_m=width,
        guard_height_m=guard, punches_per_min=rate, position_xy_m=position, position_valid=position_ok,
    )  # fmt: skip
    stats: dict[str, Any] = {
        "punches": events.n_punches,
        "landed": int(np.sum(events.punch_outcome == "landed")),
        "blocked": int(np.sum(events.punch_outcome == "blocked")),
        "missed": int(np.sum(events.punch_outcome == "missed")),
        "slips": int(np.sum(events.evade_kind == "slip")),
        "ducks": int(np.sum(events.evade_kind == "duck")),
        "blocks": int(np.sum(events.evade_kind == "block")),
        "parries": int(np.sum(events.evade_kind == "parry")),
        "clinches": events.n_clinches,
        "clinch_frames": int(np.sum(events.clinch_end_frame - events.clinch_start_frame + 1)) if fixes.applied else int(clinch.sum()),
        "corrections_applied": fixes.applied,
        "corrections_unmatched": len(fixes.unmatched),
    }
    if fixes.unmatched:
        stats["corrections_unmatched_edits"] = list(fixes.unmatched)
    return AnalyzeOutput(events, series, stats)


def _events(kp: Keypoints3D, punches: list[_Punch], evades: list[tuple[int, defence.Evade, int]],
            clinches: list[tuple[int, int]]) -> BoutEvents:  # fmt: skip
    fr = kp.frame_indices.astype(np.int64)
    ev = BoutEvents.empty(kp.fps, kp.person_ids)

    def ints(v: list[int]) -> np.ndarray:
        return np.array(v, dtype=np.int64) if v else np.zeros(0, np.int64)

    def strs(v: list[str]) -> np.ndarray:
        return np.array(v, dtype=np.str_) if v else np.zeros(0, dtype="<U1")

    def flts(v: list[float]) -> np.ndarray:
        return np.array(v, dtype=np.float64) if v else np.zeros(0)

    return BoutEvents(
        fps=ev.fps, person_ids=ev.person_ids,
        punch_person=ints([p.person for p in punches]), punch_hand=strs([p.hand for p in punches]),
        punch_type=strs([p.type for p in punches]),
        punch_start_frame=fr[ints([p.start for p in punches])], punch_peak_frame=fr[ints([p.peak for p in punches])],
        punch_end_frame=fr[ints([p.end for p in punches])], punch_peak_speed_mps=flts([p.speed for p in punches]),
        punch_extension=flts([p.extension for p in punches]), punch_target=strs([p.target for p in punches]),
        punch_outcome=strs([p.outcome for p in punches]), punch_confidence=flts([p.confidence for p in punches]),
        evade_person=ints([e[0] for e in evades]), evade_kind=strs([e[1].kind for e in evades]),
        evade_start_frame=fr[ints([e[1].start for e in evades])], evade_peak_frame=fr[ints([e[1].peak for e in evades])],
        evade_end_frame=fr[ints([e[1].end for e in evades])],
        evade_displacement_m=flts([e[1].displacement_m for e in evades]), evade_punch=ints([e[2] for e in evades]),
        clinch_start_frame=fr[ints([s for s, _ in clinches])], clinch_end_frame=fr[ints([e for _, e in clinches])],
    )  # fmt: skip
