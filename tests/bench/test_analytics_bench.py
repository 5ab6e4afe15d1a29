"""``bench analytics``: matching and scores against the choreography's labels (fast: ground-truth joints)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.bench.analytics import run_bench
from pipeline.bench.analytics_score import match_punches, rates, score
from pipeline.schema.analytics import BoutEvents
from pipeline.synthetic import SyntheticConfig, make_bout


def _events_from_truth(tr, shift: int = 0) -> BoutEvents:  # noqa: ANN001
    n = tr.n_punches
    ev = BoutEvents.empty(tr.fps, np.array([0, 1]))
    return BoutEvents(**{
        **ev.__dict__, "punch_person": tr.punch_person, "punch_hand": tr.punch_hand, "punch_type": tr.punch_type,
        "punch_start_frame": tr.punch_start_frame + shift, "punch_peak_frame": tr.punch_peak_frame + shift,
        "punch_end_frame": tr.punch_end_frame + shift, "punch_peak_speed_mps": 1.1 * tr.punch_peak_speed_mps,
        "punch_extension": np.ones(n), "punch_target": np.full(n, "head"), "punch_outcome": tr.punch_outcome,
        "punch_confidence": np.ones(n),
    })  # fmt: skip


def test_scores_of_perfect_and_shifted_events() -> None:
    tr = make_bout(SyntheticConfig(seed=0, n_frames=300, variety=True, bystander=False)).truth
    s = score(tr, _events_from_truth(tr))
    r = rates(s)
    assert s["matched"] == tr.n_punches and r["precision"] == r["recall"] == 1.0
    assert r["type_acc_pct"] == r["outcome_acc_pct"] == 100.0 and abs(r["speed_err_pct"] - 10.0) < 1e-6
    assert r["clinch_f1"] == 0.0  # no clinch predicted
    assert match_punches(tr, _events_from_truth(tr, shift=4)) == []  # beyond +-3 frames


def test_run_bench_on_ground_truth_joints() -> None:
    rows = run_bench(seeds=[0], n_frames=300, cameras=4, sources="gt", pose2sim="")
    assert [r["data"] for r in rows] == [
        "synthetic (gt)", "synthetic, southpaw (gt)", "synthetic, orthodox vs southpaw (gt)"]  # fmt: skip
    assert rows[0]["recall"] >= 0.8 and rows[0]["clinch_f1"] >= 0.8
    assert rows[2]["recall"] >= 0.8 and rows[2]["type_acc_pct"] >= 90.0 and rows[2]["clinch_f1"] >= 0.8
    # The southpaw bout is the same bout in a mirror: on its ground-truth joints every score is the same.
    scores = ("gt_punches", "detected", "matched", "precision", "recall", "type_acc_pct", "outcome_acc_pct", "clinch_f1")
    assert {k: rows[1][k] for k in scores} == {k: rows[0][k] for k in scores}


def test_run_bench_refuses_an_unknown_stance() -> None:
    with pytest.raises(ValueError, match="stances must be among orthodox, southpaw, mixed; got 'lefty'"):
        run_bench(seeds=[0], cameras=4, sources="gt", pose2sim="", stances="lefty")


def test_run_bench_with_two_cameras_a_quarter_turn_apart() -> None:
    """The layout is named in the rows; on the ground-truth joints (no cameras involved) it
    scores what the default rig's bouts score: moving a camera changes no motion."""
    kw = {"seeds": [0], "cameras": 2, "sources": "gt", "pose2sim": "", "stances": "orthodox"}
    (quarter,) = run_bench(**kw, camera_step_deg=90)
    (default,) = run_bench(**kw)
    assert quarter["data"] == "synthetic (gt), cameras 90 deg apart" and quarter["camera_step_deg"] == 90.0
    assert default["data"] == "synthetic (gt)" and default["camera_step_deg"] is None
    scores = ("gt_punches", "detected", "matched", "recall", "type_acc_pct", "outcome_acc_pct", "clinch_f1")
    assert quarter["gt_punches"] > 0 and {k: quarter[k] for k in scores} == {k: default[k] for k in scores}


def test_run_bench_refuses_a_camera_step_out_of_range_before_any_bout() -> None:
    with pytest.raises(ValueError, match=r"camera_step_deg must be in \[15, 90\] deg for 4 cameras"):
        run_bench(seeds=[0], cameras=(4, 2), sources="gt", pose2sim="", camera_step_deg=200)
    with pytest.raises(ValueError, match="camera_step_deg must be a number of degrees, got 'abc'"):
        run_bench(seeds=[0], cameras=2, sources="gt", pose2sim="", camera_step_deg="abc")
