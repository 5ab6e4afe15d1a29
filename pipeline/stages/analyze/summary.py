"""Per-athlete summary of a bout's analytics (for ``cornerman analyze``, the API and the viewer).

Plain numbers from ``BoutEvents`` and ``AthleteSeries``, JSON-ready.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.schema.analytics import OUTCOMES, PUNCH_TYPES, STANCE_CODES, AthleteSeries, BoutEvents


def _r(x: float, nd: int = 2) -> float | None:
    return round(float(x), nd) if np.isfinite(x) else None


def athlete_summary(events: BoutEvents, series: AthleteSeries, person_id: int) -> dict[str, Any]:
    """Counts, speeds, work rate, defence, stance and guard of one athlete."""
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
    out: dict[str, Any] = {
        "person_id": int(person_id),
        "punches": n,
        **{f"punches_{k}": v for k, v in outcomes.items()},
        "landed_pct": _r(100.0 * outcomes["landed"] / n, 1) if n else None,
        "types": types,
        "peak_speed_mean_mps": _r(speeds.mean()) if n else None,
        "peak_speed_max_mps": _r(speeds.max()) if n else None,
        "punches_per_min": _r(n / (duration_s / 60.0), 1) if duration_s > 0 else None,
        "punches_per_min_first_half": _r(first / half_min, 1) if half_min > 0 else None,
        "punches_per_min_second_half": _r((n - first) / half_min, 1) if half_min > 0 else None,
        "slips": int(np.sum((events.evade_person == person_id) & (events.evade_kind == "slip"))),
        "ducks": int(np.sum((events.evade_person == person_id) & (events.evade_kind == "duck"))),
        "clinch_s": _r(float(np.sum(events.clinch_end_frame - events.clinch_start_frame + 1)) / events.fps),
    }
    if p >= 0:
        ok = series.valid[:, p]
        st = series.stance[ok, p]
        decided = st[st != 0]
        out["stance"] = STANCE_CODES[int(np.sign(np.sum(decided)))] if decided.size else "unknown"
        out["orthodox_pct"] = _r(100.0 * np.mean(decided > 0), 1) if decided.size else None
        out["stance_width_mean_m"] = _r(series.stance_width_m[ok, p].mean()) if ok.any() else None
        out["guard_height_mean_m"] = _r(series.guard_height_m[ok, p].mean()) if ok.any() else None
    if series.distance_valid.any():
        out["distance_mean_m"] = _r(series.distance_m[series.distance_valid].mean())
    return out


def summarize(events: BoutEvents, series: AthleteSeries, names: dict[int, str] | None = None) -> dict[str, Any]:
    """``{"duration_s", "fps", "clinches", "athletes": [per-athlete summary with "name"]}``."""
    names = names or {}
    athletes = []
    for pid in series.person_ids.tolist():
        s = athlete_summary(events, series, int(pid))
        athletes.append({"name": names.get(int(pid), f"athlete {pid}"), **s})
    return {
        "duration_s": _r(series.n_frames / series.fps),
        "fps": float(series.fps),
        "clinches": events.n_clinches,
        "athletes": athletes,
    }
