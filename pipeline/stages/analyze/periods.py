"""Periods of a bout (rounds, or fixed spans when the rounds are not known) and the slicing of
the analyze stage's events and series to one of them."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.schema.analytics import AthleteSeries, BoutEvents

DEFAULT_PERIOD_S = 60.0
"""Length of a period when the session gives no round times (s): per minute."""


@dataclass(frozen=True)
class Period:
    """A span of the bout: ``label`` and its seconds from the first analysed frame [start_s, end_s)."""

    label: str
    start_s: float
    end_s: float

    @property
    def mid_min(self) -> float:
        """Its middle, in minutes from the first analysed frame."""
        return 0.5 * (self.start_s + self.end_s) / 60.0


def _mmss(t_s: float) -> str:
    t = int(round(t_s))
    return f"{t // 60}:{t % 60:02d}"


def bout_periods(
    duration_s: float, rounds_s: tuple[tuple[float, float], ...] = (), period_s: float = DEFAULT_PERIOD_S
) -> tuple[list[Period], str]:
    """The rounds that start within ``duration_s`` (clipped to it; labels ``round k``), else
    consecutive ``period_s`` spans covering the bout (labels ``m:ss–m:ss``); and ``"rounds"``
    or ``"periods"`` saying which. ``ValueError`` when ``period_s`` is not > 0."""
    if not (np.isfinite(period_s) and period_s > 0):
        raise ValueError(f"period_s must be finite and > 0, got {period_s}")
    if rounds_s:
        return [
            Period(f"round {k + 1}", a, min(b, duration_s))
            for k, (a, b) in enumerate(rounds_s)
            if a < duration_s
        ], "rounds"
    n = max(1, int(np.ceil(duration_s / period_s - 1e-9)))
    return [
        Period(f"{_mmss(k * period_s)}–{_mmss(min(duration_s, (k + 1) * period_s))}", k * period_s,
               min(duration_s, (k + 1) * period_s))
        for k in range(n)
    ], "periods"  # fmt: skip


def slice_bout(
    events: BoutEvents, series: AthleteSeries, start_s: float, end_s: float
) -> tuple[BoutEvents, AthleteSeries]:
    """The events and series of [start_s, end_s) seconds from the first analysed frame.

    A punch belongs to the span of its peak frame, a defence event (slip, duck, block, parry)
    to the span of the punch it answers, and a clinch is clipped to the span; so the spans of
    a bout add up to it. Raises ``ValueError`` when the span holds no analysed frame."""
    fr = series.frame_indices
    f0 = (fr[0] if fr.size else 0) + start_s * series.fps
    f1 = (fr[0] if fr.size else 0) + end_s * series.fps
    rows = (fr >= f0 - 1e-6) & (fr < f1 - 1e-6)
    if not rows.any():
        raise ValueError(f"slice_bout: no analysed frame in [{start_s}, {end_s}) s")
    lo, hi = int(fr[rows][0]), int(fr[rows][-1])
    sub = replace(
        series, frame_indices=fr[rows], valid=series.valid[rows], distance_m=series.distance_m[rows],
        distance_valid=series.distance_valid[rows], stance=series.stance[rows], stance_width_m=series.stance_width_m[rows],
        guard_height_m=series.guard_height_m[rows], punches_per_min=series.punches_per_min[rows],
        position_xy_m=series.position_xy_m[rows], position_valid=series.position_valid[rows],
    )  # fmt: skip
    keep = (events.punch_peak_frame >= lo) & (events.punch_peak_frame <= hi)
    new_index = np.cumsum(keep) - 1
    ev_keep = keep[events.evade_punch] if events.n_evades else np.zeros(0, bool)
    c_start = np.maximum(events.clinch_start_frame, lo)
    c_end = np.minimum(events.clinch_end_frame, hi)
    c_keep = c_start <= c_end
    ev = replace(
        events,
        punch_person=events.punch_person[keep], punch_hand=events.punch_hand[keep], punch_type=events.punch_type[keep],
        punch_start_frame=events.punch_start_frame[keep], punch_peak_frame=events.punch_peak_frame[keep],
        punch_end_frame=events.punch_end_frame[keep], punch_peak_speed_mps=events.punch_peak_speed_mps[keep],
        punch_extension=events.punch_extension[keep], punch_target=events.punch_target[keep],
        punch_outcome=events.punch_outcome[keep], punch_confidence=events.punch_confidence[keep],
        punch_source=events.punch_source[keep], evade_source=events.evade_source[ev_keep],
        clinch_source=events.clinch_source[c_keep],
        evade_person=events.evade_person[ev_keep], evade_kind=events.evade_kind[ev_keep],
        evade_start_frame=events.evade_start_frame[ev_keep], evade_peak_frame=events.evade_peak_frame[ev_keep],
        evade_end_frame=events.evade_end_frame[ev_keep], evade_displacement_m=events.evade_displacement_m[ev_keep],
        evade_punch=new_index[events.evade_punch[ev_keep]].astype(np.int64) if events.n_evades else events.evade_punch,
        clinch_start_frame=c_start[c_keep], clinch_end_frame=c_end[c_keep],
    )  # fmt: skip
    return ev, sub
