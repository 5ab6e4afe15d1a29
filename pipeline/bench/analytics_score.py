"""Scores of the analytics against a synthetic bout's ground truth (``pipeline.synthetic.truth``).

Punches are matched one-to-one, per athlete and hand, by their strike (peak) frames at
most ``tol_frames`` apart, closest pairs first. Over the matched pairs: type accuracy,
outcome accuracy and the peak-speed error relative to the ground truth's. Clinches are
scored per frame (F1 of the clinch frames). Feints are the ground truth's feints that a
detected punch matches (false punches the choreography made on purpose).

Blocks: the choreography scripts blocks (a punch aimed at the guard, the defender's glove
moved onto its contact point; ``pipeline.synthetic.motion``) and the ground truth labels every
punch whose glove stops on the other athlete's arms ``blocked`` (``truth.contact_outcome`` on
the ground-truth bodies). Each such punch is a ground-truth block by the other athlete. A
detected ``block`` event matches one when it is the same defender's and the punch it answers
strikes within ``tol_frames`` of the ground-truth punch's strike, one-to-one, closest first.
A parried punch (``SyntheticConfig.parry_prob``) is not a ground-truth block even when its
glove ends on the other guard: parries are scored on their own (``analytics_parry``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.bench.analytics_parry import parry_counts, parry_rates
from pipeline.bench.matching import one_to_one
from pipeline.schema.analytics import BoutEvents
from pipeline.synthetic.truth import BoutTruth


def match_punches(truth: BoutTruth, events: BoutEvents, tol_frames: int = 3) -> list[tuple[int, int]]:
    """(truth row, event row) pairs: same athlete and hand, strikes within ``tol_frames``."""
    cands = []
    for i in range(truth.n_punches):
        for j in range(events.n_punches):
            if truth.punch_person[i] != events.punch_person[j] or truth.punch_hand[i] != events.punch_hand[j]:
                continue
            d = abs(int(truth.punch_peak_frame[i]) - int(events.punch_peak_frame[j]))
            if d <= tol_frames:
                cands.append((d, i, j))
    return one_to_one(cands)


def match_blocks(truth: BoutTruth, events: BoutEvents, tol_frames: int = 3) -> list[tuple[int, int]]:
    """(truth punch row, event defence row) pairs: the truth punch was blocked, the event is a
    ``block`` by the other athlete against a punch whose strike is within ``tol_frames``
    (parried punches excluded)."""
    gt = _truth_blocks(truth)
    det = np.flatnonzero(events.evade_kind == "block")
    cands = []
    for i in gt.tolist():
        for j in det.tolist():
            if events.evade_person[j] == truth.punch_person[i]:
                continue
            d = abs(int(truth.punch_peak_frame[i]) - int(events.punch_peak_frame[events.evade_punch[j]]))
            if d <= tol_frames:
                cands.append((d, i, j))
    return one_to_one(cands)


def _truth_blocks(truth: BoutTruth) -> np.ndarray:
    """Rows of the ground truth's blocked punches that were not parried."""
    blocked = truth.punch_outcome == "blocked"
    blocked[np.asarray(truth.parry_punch, dtype=np.int64)] = False
    return np.flatnonzero(blocked)


def clinch_mask(events: BoutEvents, n_frames: int) -> np.ndarray:
    """(n_frames,) bool from the events' clinch intervals (frames = bout frame indices)."""
    m = np.zeros(n_frames, dtype=bool)
    for s, e in zip(events.clinch_start_frame, events.clinch_end_frame, strict=True):
        m[int(s) : int(e) + 1] = True
    return m


def f1(truth: np.ndarray, pred: np.ndarray) -> float:
    tp = float(np.sum(truth & pred))
    denom = float(truth.sum() + pred.sum())
    return 2 * tp / denom if denom else 1.0


def score(truth: BoutTruth, events: BoutEvents, tol_frames: int = 3) -> dict[str, Any]:
    """Counts and rates of one bout (see the module docstring); the benches sum the counts."""
    pairs = match_punches(truth, events, tol_frames)
    ti = np.array([i for i, _ in pairs], dtype=np.int64)
    ej = np.array([j for _, j in pairs], dtype=np.int64)
    matched_e = set(ej.tolist())
    feint_hits = 0
    for j in range(events.n_punches):
        if j in matched_e:
            continue
        same = (truth.feint_person == events.punch_person[j]) & (truth.feint_hand == events.punch_hand[j])
        if np.any(same & (np.abs(truth.feint_peak_frame - events.punch_peak_frame[j]) <= tol_frames)):
            feint_hits += 1
    err = np.abs(events.punch_peak_speed_mps[ej] - truth.punch_peak_speed_mps[ti]) / truth.punch_peak_speed_mps[ti]
    n_f = truth.clinch.shape[0]
    pred = clinch_mask(events, n_f)
    return {
        "gt_punches": truth.n_punches,
        "detected": events.n_punches,
        "matched": len(pairs),
        "type_correct": int(np.sum(truth.punch_type[ti] == events.punch_type[ej])),
        "outcome_correct": int(np.sum(truth.punch_outcome[ti] == events.punch_outcome[ej])),
        "speed_err_sum": float(err.sum()),
        "speed_err_max": float(err.max()) if err.size else 0.0,
        "feints": int(truth.feint_person.size),
        "feint_hits": feint_hits,
        "clinch_tp": int(np.sum(truth.clinch & pred)),
        "clinch_gt": int(truth.clinch.sum()),
        "clinch_pred": int(pred.sum()),
        "frames": int(n_f),
        "gt_blocks": int(_truth_blocks(truth).size),
        "blocks_detected": int(np.sum(events.evade_kind == "block")),
        "blocks_matched": len(match_blocks(truth, events, tol_frames)),
        **parry_counts(truth, events, tol_frames),
        "confusion_type": [(str(truth.punch_type[i]), str(events.punch_type[j])) for i, j in pairs],
        "confusion_outcome": [(str(truth.punch_outcome[i]), str(events.punch_outcome[j])) for i, j in pairs],
    }


def rates(counts: dict[str, Any]) -> dict[str, float]:
    """Precision, recall, accuracies (%), mean speed error (%), clinch F1, and block and parry
    precision / recall of summed counts."""
    m = counts["matched"]
    nan = float("nan")
    cp, cg, ct = counts["clinch_pred"], counts["clinch_gt"], counts["clinch_tp"]
    return {
        "precision": m / counts["detected"] if counts["detected"] else nan,
        "recall": m / counts["gt_punches"] if counts["gt_punches"] else nan,
        "type_acc_pct": 100.0 * counts["type_correct"] / m if m else nan,
        "outcome_acc_pct": 100.0 * counts["outcome_correct"] / m if m else nan,
        "speed_err_pct": 100.0 * counts["speed_err_sum"] / m if m else nan,
        "speed_err_max_pct": 100.0 * counts["speed_err_max"],
        "clinch_f1": 2 * ct / (cp + cg) if cp + cg else 1.0,
        "block_precision": counts["blocks_matched"] / counts["blocks_detected"] if counts.get("blocks_detected") else nan,
        "block_recall": counts["blocks_matched"] / counts["gt_blocks"] if counts.get("gt_blocks") else nan,
        **(parry_rates(counts) if "gt_parries" in counts else {}),
    }
