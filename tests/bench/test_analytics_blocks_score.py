"""``bench analytics``' block scores: the defender's block events against the choreography's
blocked punches (ground-truth labels from contact on the ground-truth bodies)."""

from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.bench.analytics_score import match_blocks, rates, score
from pipeline.schema.analytics import BoutEvents
from pipeline.synthetic import SyntheticConfig, make_bout


def _events(tr, blocks: list[tuple[int, int]]) -> BoutEvents:  # noqa: ANN001
    """The truth's punches as detected, plus ``(defender, punch row)`` block events."""
    n, k = tr.n_punches, len(blocks)
    ev = BoutEvents.empty(tr.fps, np.array([0, 1]))
    peak = tr.punch_peak_frame[[r for _, r in blocks]] if k else np.zeros(0, np.int64)
    return BoutEvents(**{
        **ev.__dict__, "punch_person": tr.punch_person, "punch_hand": tr.punch_hand, "punch_type": tr.punch_type,
        "punch_start_frame": tr.punch_start_frame, "punch_peak_frame": tr.punch_peak_frame,
        "punch_end_frame": tr.punch_end_frame, "punch_peak_speed_mps": tr.punch_peak_speed_mps,
        "punch_extension": np.ones(n), "punch_target": np.full(n, "guard"), "punch_outcome": tr.punch_outcome,
        "punch_confidence": np.ones(n), "evade_person": np.array([p for p, _ in blocks], dtype=np.int64),
        "evade_kind": np.full(k, "block"), "evade_start_frame": peak, "evade_peak_frame": peak, "evade_end_frame": peak,
        "evade_displacement_m": np.zeros(k), "evade_punch": np.array([r for _, r in blocks], dtype=np.int64),
    })  # fmt: skip


def test_block_precision_and_recall() -> None:
    tr = make_bout(SyntheticConfig(seed=1, n_frames=300, variety=True, bystander=False)).truth
    blocked = np.flatnonzero(tr.punch_outcome == "blocked").tolist()
    assert len(blocked) >= 2, tr.punch_outcome  # the choreography scripts blocks
    right = [(1 - int(tr.punch_person[i]), i) for i in blocked]
    s = score(tr, _events(tr, right))
    r = rates(s)
    assert s["gt_blocks"] == s["blocks_detected"] == s["blocks_matched"] == len(blocked)
    assert r["block_precision"] == r["block_recall"] == 1.0
    # a block credited to the puncher, and one on a punch that was not blocked, match nothing
    other = next(i for i in range(tr.n_punches) if tr.punch_outcome[i] != "blocked")
    wrong = [
        (int(tr.punch_person[blocked[0]]), blocked[0]),
        *right[1:],
        (1 - int(tr.punch_person[other]), other),
    ]
    s = score(tr, _events(tr, wrong))
    r = rates(s)
    assert s["blocks_matched"] == len(blocked) - 1 and s["blocks_detected"] == len(blocked) + 1
    assert r["block_recall"] == (len(blocked) - 1) / len(blocked) and r["block_precision"] == (
        len(blocked) - 1
    ) / (len(blocked) + 1)
    assert match_blocks(tr, _events(tr, [])) == [] and np.isnan(
        rates(score(tr, _events(tr, [])))["block_precision"]
    )


def test_a_parried_punch_is_scored_as_a_parry_not_as_a_block() -> None:
    tr = make_bout(SyntheticConfig(seed=1, n_frames=300, variety=True, bystander=False)).truth
    blocked = np.flatnonzero(tr.punch_outcome == "blocked").tolist()
    i = blocked[0]
    d = 1 - int(tr.punch_person[i])
    parried = dataclasses.replace(
        tr, parry_person=np.array([d]), parry_hand=np.array(["left"]), parry_punch=np.array([i]),
        parry_frame=np.array([int(tr.punch_peak_frame[i]) - 2]),
    )  # fmt: skip
    right = [(1 - int(tr.punch_person[k]), k) for k in blocked]
    s = score(parried, _events(parried, right))
    assert s["gt_blocks"] == len(blocked) - 1 and s["blocks_matched"] == len(blocked) - 1  # the parried one left out
    assert s["gt_parries"] == 1 and s["parries_detected"] == 0 and np.isnan(rates(s)["parry_precision"])
    ev = _events(parried, [*right[1:], (d, i)])
    kinds = ev.evade_kind.copy()
    kinds[-1] = "parry"  # the defender's parry of punch i
    ev = BoutEvents(**{**ev.__dict__, "evade_kind": kinds})
    r = rates(score(parried, ev))
    assert r["parry_precision"] == r["parry_recall"] == 1.0 and r["block_recall"] == 1.0
