"""Scores of the analytics' parries against a synthetic bout's ground truth.

The choreography scripts parries (``SyntheticConfig.parry_prob``: a jab or cross met on its
way out by the defender's glove, which slaps it sideways; ``pipeline.synthetic.motion``), and
the ground truth records each one whose gloves touch on the bodies (``BoutTruth.parry_*``:
the defender, his glove, the punch parried and the frame of the contact). A detected
``parry`` event matches one when it is the same defender's and the punch it answers strikes
within ``tol_frames`` of the ground-truth punch's strike, one-to-one, closest first: the
conventions of ``analytics_score.match_blocks``.
"""

from __future__ import annotations

import numpy as np

from pipeline.bench.matching import one_to_one
from pipeline.schema.analytics import BoutEvents
from pipeline.synthetic.truth import BoutTruth


def match_parries(truth: BoutTruth, events: BoutEvents, tol_frames: int = 3) -> list[tuple[int, int]]:
    """(truth parry row, event defence row) pairs: the event is a ``parry`` by the ground-truth
    parry's defender against a punch whose strike is within ``tol_frames`` of the parried
    punch's strike; one-to-one, nearest first, sorted by truth row. ``ValueError`` when
    ``tol_frames`` < 0."""
    if tol_frames < 0:
        raise ValueError(f"match_parries: tol_frames must be >= 0, got {tol_frames}")
    det = np.flatnonzero(events.evade_kind == "parry")
    cands = []
    for i in range(truth.parry_person.size):
        strike = int(truth.punch_peak_frame[truth.parry_punch[i]])
        for j in det.tolist():
            if events.evade_person[j] != truth.parry_person[i]:
                continue
            d = abs(strike - int(events.punch_peak_frame[events.evade_punch[j]]))
            if d <= tol_frames:
                cands.append((d, i, j))
    return one_to_one(cands)


def parry_counts(truth: BoutTruth, events: BoutEvents, tol_frames: int = 3) -> dict[str, int]:
    """Counts of one bout: ``gt_parries`` (ground-truth parries), ``parries_detected`` (``parry``
    events) and ``parries_matched`` (``match_parries``); the benches sum them."""
    return {
        "gt_parries": int(truth.parry_person.size),
        "parries_detected": int(np.sum(events.evade_kind == "parry")),
        "parries_matched": len(match_parries(truth, events, tol_frames)),
    }


def parry_rates(counts: dict[str, int]) -> dict[str, float]:
    """Parry precision and recall of summed counts (NaN when there is nothing to divide by)."""
    nan = float("nan")
    m = counts["parries_matched"]
    return {
        "parry_precision": m / counts["parries_detected"] if counts["parries_detected"] else nan,
        "parry_recall": m / counts["gt_parries"] if counts["gt_parries"] else nan,
    }
