"""One southpaw against an orthodox boxer (``SyntheticConfig.mixed_stance``): boxer 1 throws
the script's punches with his other hand from a mirrored stance, boxer 0 stays orthodox, the
labels say so, and the analytics read one orthodox and one southpaw."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.bench.analytics_score import rates, score
from pipeline.schema.analytics import STANCE_CODES
from pipeline.schema.joints import COCO17_FEET, mirror_joints
from pipeline.stages.analyze import AnalyzeConfig, AnalyzeInputs
from pipeline.stages.analyze import run as analyze
from pipeline.synthetic import SyntheticBout, SyntheticConfig, make_bout
from pipeline.synthetic.choreo import Punch

SEED = 15
"""A varied bout where both boxers punch, lead and rear (held-out seed of bench analytics)."""
J = {n: i for i, n in enumerate(COCO17_FEET)}


def _bout(mixed: bool, southpaw: bool = False) -> SyntheticBout:
    cfg = SyntheticConfig(seed=SEED, n_frames=300, n_cameras=2, variety=True, bystander=False,
                          mixed_stance=mixed, southpaw=southpaw)  # fmt: skip
    return make_bout(cfg)


@pytest.fixture(scope="module")
def pair() -> tuple[SyntheticBout, SyntheticBout]:
    return _bout(False), _bout(True)


def test_lead_hand_of_a_punch() -> None:
    jab = Punch(0, "jab", 1.0, 0.2, 0.04, 0.3, 6.0)
    cross = Punch(0, "cross", 1.0, 0.2, 0.04, 0.3, 6.0, lead="right")
    assert jab.hand == "left" and Punch(0, "jab", 1.0, 0.2, 0.04, 0.3, 6.0, lead="right").hand == "right"
    assert cross.hand == "left"
    with pytest.raises(ValueError, match="lead must be 'left' or 'right'"):
        Punch(0, "jab", 1.0, 0.2, 0.04, 0.3, 6.0, lead="both")


def test_only_the_southpaw_changes_hands(pair: tuple[SyntheticBout, SyntheticBout]) -> None:
    orth, mixed = pair
    a, b = orth.truth, mixed.truth
    assert a.n_punches == b.n_punches > 0 and set(a.punch_person.tolist()) == {0, 1}
    np.testing.assert_array_equal(b.punch_person, a.punch_person)
    np.testing.assert_array_equal(b.punch_type, a.punch_type)
    one = a.punch_person == 1
    np.testing.assert_array_equal(b.punch_hand[~one], a.punch_hand[~one])
    np.testing.assert_array_equal(b.punch_hand[one], np.where(a.punch_hand[one] == "left", "right", "left"))
    # The speed calibration times each punch on the new bodies: strikes stay within a frame or two.
    assert np.max(np.abs(b.punch_peak_frame - a.punch_peak_frame)) <= 2
    leads = {(p, t): h for p, t, h in zip(b.punch_person, b.punch_type, b.punch_hand, strict=True)}
    assert leads.get((1, "jab"), "right") == "right" and leads.get((1, "cross"), "left") == "left"
    assert leads.get((0, "jab"), "left") == "left" and leads.get((0, "cross"), "right") == "right"


def _right_foot_ahead(bout: SyntheticBout, person: int) -> float:
    """Fraction of the frames out of the clinch in which ``person``'s right ankle is nearer the
    opponent than his left (along the line between their pelvises)."""
    xyz = bout.gt.xyz_m
    pelvis = 0.5 * (xyz[:, :, J["left_hip"]] + xyz[:, :, J["right_hip"]])
    to_opp = pelvis[:, 1 - person, :2] - pelvis[:, person, :2]
    to_opp /= np.linalg.norm(to_opp, axis=1, keepdims=True)
    ahead = np.einsum("fi,fi->f", xyz[:, person, J["right_ankle"], :2] - xyz[:, person, J["left_ankle"], :2], to_opp)
    return float(np.mean(ahead[~bout.truth.clinch] > 0.0))


def test_the_southpaw_stands_right_foot_forward(pair: tuple[SyntheticBout, SyntheticBout]) -> None:
    orth, mixed = pair
    assert _right_foot_ahead(orth, 0) < 0.2 and _right_foot_ahead(orth, 1) < 0.2
    assert _right_foot_ahead(mixed, 0) < 0.2 and _right_foot_ahead(mixed, 1) > 0.8


def test_analytics_read_one_orthodox_and_one_southpaw(pair: tuple[SyntheticBout, SyntheticBout]) -> None:
    """On the ground-truth joints: the stance of each boxer, and the punches with their hands
    and lead / rear types as labelled."""
    _, mixed = pair
    res = analyze(AnalyzeInputs(mixed.gt), AnalyzeConfig())
    code = {v: k for k, v in STANCE_CODES.items()}
    assert np.mean(res.series.stance[:, 0] == code["orthodox"]) > 0.7
    assert np.mean(res.series.stance[:, 1] == code["southpaw"]) > 0.7
    r = rates(score(mixed.truth, res.events))
    assert r["recall"] >= 0.85 and r["precision"] >= 0.85 and r["type_acc_pct"] >= 90.0


def test_the_mirror_of_a_mixed_bout_makes_boxer_0_the_southpaw(pair: tuple[SyntheticBout, SyntheticBout]) -> None:
    _, mixed = pair
    both = _bout(True, southpaw=True)
    np.testing.assert_array_equal(both.gt.xyz_m, mirror_joints(mixed.gt.xyz_m))
    assert _right_foot_ahead(both, 0) > 0.8 and _right_foot_ahead(both, 1) < 0.2
