"""Per-athlete summary of a bout's analytics (for ``cornerman analyze``, the API, the report
and the viewer).

Plain numbers from ``BoutEvents`` and ``AthleteSeries``, JSON-ready. The ring zones need the
ring (``session.json``'s ``ring_xy_m``; ``zones``), the periods the round times (``rounds_s``,
else minutes; ``periods``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from pipeline.schema.analytics import OUTCOMES, PUNCH_TYPES, STANCE_CODES, AthleteSeries, BoutEvents
from pipeline.stages.analyze import zones
from pipeline.stages.analyze.fatigue import trends
from pipeline.stages.analyze.periods import DEFAULT_PERIOD_S, bout_periods, slice_bout

PERIOD_KEYS: tuple[str, ...] = (
    "punches", "punches_landed", "punches_per_min", "peak_speed_median_mps", "guard_height_median_m",
    "blocks", "parries", *(f"ring_{z}_pct" for z in zones.RING_ZONES),
)  # fmt: skip
"""Keys of ``athlete_summary`` repeated per period (``by_period``)."""


def _r(x: float, nd: int = 2) -> float | None:
    return round(float(x), nd) if np.isfinite(x) else None


def _ring_shares(series: AthleteSeries, p: int, ring_xy_m: np.ndarray | None) -> dict[str, float | None]:
    """``ring_<zone>_pct`` for every zone (None when the ring or every position is unknown)."""
    shares = None
    if ring_xy_m is not None and p >= 0:
        ok = series.position_valid[:, p]
        shares = zones.zone_shares(zones.ring_zones(series.position_xy_m[:, p], ring_xy_m), ok)
    return {f"ring_{z}_pct": (_r(shares[z], 1) if shares is not None else None) for z in zones.RING_ZONES}


def athlete_summary(
    events: BoutEvents, series: AthleteSeries, person_id: int, ring_xy_m: np.ndarray | None = None
) -> dict[str, Any]:
    """Counts, speeds, work rate, defence, stance, guard and (when ``ring_xy_m`` (corners, 2)
    is given) ring zones of one athlete."""
    p = int(np.flatnonzero(series.person_ids == person_id)[0]) if person_id in series.person_ids else -1
    mine = events.punch_person == person_id
    n = int(mine.sum())
    duration_s = series.n_frames / series.fps if series.n_frames else 0.0
    speeds = events.punch_peak_speed_mps[mine]
    outcomes = {o: int(np.sum(events.punch_outcome[mine] == o)) for o in OUTCOMES}
    types = {t: int(np.sum(events.punch_type[mine] == t)) for t in PUNCH_TYPES}
    half = series.frame_indices[0] + series.n_frames / 2 if series.n_frames else 0
    first = int(np.sum(events.punch_peak_frame[mine] < half))
    half_min = duration_s / 2 / 60.0
    defended = events.evade_person == person_id
    out: dict[str, Any] = {
        "person_id": int(person_id),
        "punches": n,
        **{f"punches_{k}": v for k, v in outcomes.items()},
        "landed_pct": _r(100.0 * outcomes["landed"] / n, 1) if n else None,
        "types": types,
        "peak_speed_mean_mps": _r(speeds.mean()) if n else None,
        "peak_speed_median_mps": _r(float(np.median(speeds))) if n else None,
        "peak_speed_max_mps": _r(speeds.max()) if n else None,
        "punches_per_min": _r(n / (duration_s / 60.0), 1) if duration_s > 0 else None,
        "punches_per_min_first_half": _r(first / half_min, 1) if half_min > 0 else None,
        "punches_per_min_second_half": _r((n - first) / half_min, 1) if half_min > 0 else None,
        "slips": int(np.sum(defended & (events.evade_kind == "slip"))),
        "ducks": int(np.sum(defended & (events.evade_kind == "duck"))),
        "blocks": int(np.sum(defended & (events.evade_kind == "block"))),
        "parries": int(np.sum(defended & (events.evade_kind == "parry"))),
        "clinch_s": _r(float(np.sum(events.clinch_end_frame - events.clinch_start_frame + 1)) / events.fps),
    }
    if p >= 0:
        ok = series.valid[:, p]
        st = series.stance[ok, p]
        decided = st[st != 0]
        guard = series.guard_height_m[ok, p].mean(axis=1)
        out["stance"] = STANCE_CODES[int(np.sign(np.sum(decided)))] if decided.size else "unknown"
        out["orthodox_pct"] = _r(100.0 * np.mean(decided > 0), 1) if decided.size else None
        out["stance_width_mean_m"] = _r(series.stance_width_m[ok, p].mean()) if ok.any() else None
        out["guard_height_mean_m"] = _r(guard.mean()) if ok.any() else None
        out["guard_height_median_m"] = _r(float(np.median(guard))) if ok.any() else None
    out.update(_ring_shares(series, p, ring_xy_m))
    if series.distance_valid.any():
        out["distance_mean_m"] = _r(series.distance_m[series.distance_valid].mean())
    return out


def summarize(
    events: BoutEvents, series: AthleteSeries, names: dict[int, str] | None = None,
    ring_xy_m: np.ndarray | Sequence[Sequence[float]] | None = None, rounds_s: tuple[tuple[float, float], ...] = (),
    period_s: float = DEFAULT_PERIOD_S,
) -> dict[str, Any]:  # fmt: skip
    """``{"duration_s", "fps", "clinches", "ring_known", "ring_zones", "period_kind", "periods",
    "athletes"}``: per athlete the bout's summary with ``"name"``, ``"by_period"`` (``PERIOD_KEYS``
    per period: rounds from ``rounds_s``, else ``period_s`` spans) and ``"fatigue"`` (trends,
    ``fatigue.trends``). ``ring_xy_m`` (corners, 2), metres: the ring for the zones (None: unknown)."""
    names = names or {}
    ring = None if ring_xy_m is None or len(ring_xy_m) == 0 else np.asarray(ring_xy_m, dtype=np.float64)
    duration = series.n_frames / series.fps
    spans, kind = bout_periods(duration, tuple(rounds_s), period_s) if series.n_frames else ([], "periods")
    sliced = []
    for span in spans:
        try:
            sliced.append((span, *slice_bout(events, series, span.start_s, span.end_s)))
        except ValueError:  # a round with no analysed frame (a gap in the 3D)
            continue
    athletes = []
    for pid in series.person_ids.tolist():
        s = athlete_summary(events, series, int(pid), ring)
        per = []
        for span, ev, se in sliced:
            a = athlete_summary(ev, se, int(pid), ring)
            per.append({"label": span.label, "start_s": _r(span.start_s), "end_s": _r(span.end_s),
                        **{k: a.get(k) for k in PERIOD_KEYS}})  # fmt: skip
        fatigue = trends([span.mid_min for span, _, _ in sliced], per)
        athletes.append(
            {"name": names.get(int(pid), f"athlete {pid}"), **s, "by_period": per, "fatigue": fatigue}
        )
    return {
        "duration_s": _r(duration),
        "fps": float(series.fps),
        "clinches": events.n_clinches,
        "ring_known": ring is not None,
        "ring_zones": {
            "centre_scale": zones.CENTRE_SCALE,
            "ropes_band_m": zones.ROPES_BAND_M,
            "corner_radius_m": zones.CORNER_RADIUS_M,
        },  # fmt: skip
        "period_kind": kind,
        "periods": [
            {"label": sp.label, "start_s": _r(sp.start_s), "end_s": _r(sp.end_s)} for sp, _, _ in sliced
        ],
        "athletes": athletes,
    }
