"""Ground truth recorded from the choreography: punches (type, frames, outcome), feints,
slips and ducks, clinch frames; the varied script and what it leaves unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.evaluate.glove_contact import glove_gaps
from pipeline.schema.analytics import OUTCOMES, PUNCH_TYPES
from pipeline.schema.base import load_npz
from pipeline.schema.joints import COCO17_FEET
from pipeline.synthetic import SyntheticBout, SyntheticConfig, make_bout
from pipeline.synthetic.truth import CONTACT_TOL_M, BoutTruth, contact_outcome

N_FRAMES = 200


@pytest.fixture(scope="module")
def varied() -> SyntheticBout:
    return make_bout(SyntheticConfig(seed=0, n_frames=300, variety=True, bystander=False))


def test_base_script_is_labelled_and_unchanged(default_bout: SyntheticBout) -> None:
    tr, ch = default_bout.truth, default_bout.choreography
    assert {p.aim for p in ch.punches} == {"legacy"} and not any(p.feint for p in ch.punches)
    assert tr.n_punches == len(ch.punches) and set(tr.punch_type.tolist()) <= {"jab", "cross", "lead_hook"}
    assert set(tr.punch_intent.tolist()) == {"legacy"}
    # The base script throws from out of range: nothing lands.
    assert set(tr.punch_outcome.tolist()) == {"missed"}
    np.testing.assert_allclose(tr.punch_peak_speed_mps, default_bout.punch_peak_speed_mps)
    assert tr.clinch.shape == (300,) and 40 <= tr.clinch.sum() <= 150


def test_varied_script_keeps_phases_and_clinches() -> None:
    base = make_bout(SyntheticConfig(seed=3, n_frames=N_FRAMES, bystander=False))
    var = make_bout(SyntheticConfig(seed=3, n_frames=N_FRAMES, variety=True, bystander=False))
    assert base.choreography.phases == var.choreography.phases
    np.testing.assert_array_equal(base.truth.clinch, var.truth.clinch)
    np.testing.assert_array_equal(base.rig.T_world_cam, var.rig.T_world_cam)
    assert base.limb_lengths_m == var.limb_lengths_m


def test_varied_truth_is_consistent(varied: SyntheticBout) -> None:
    tr = varied.truth
    assert tr.n_punches >= 4
    assert set(tr.punch_type.tolist()) <= set(PUNCH_TYPES) and set(tr.punch_outcome.tolist()) <= set(OUTCOMES)
    assert np.all(tr.punch_start_frame < tr.punch_peak_frame) and np.all(tr.punch_peak_frame < tr.punch_end_frame)
    assert np.all((tr.punch_peak_speed_mps > 5.5) & (tr.punch_peak_speed_mps < 11.0))
    hands = {"jab": "left", "cross": "right", "lead_hook": "left", "rear_hook": "right", "lead_uppercut": "left", "rear_uppercut": "right"}
    for t, h in zip(tr.punch_type.tolist(), tr.punch_hand.tolist(), strict=True):
        assert hands.get(t, h) == h
    # Labels agree with the bodies: a landed glove touches the head or trunk at the strike.
    xyz = varied.gt.xyz_m
    for i in range(tr.n_punches):
        f, p = int(tr.punch_peak_frame[i]), int(tr.punch_person[i])
        gaps = glove_gaps(xyz[f - 1 : f + 3, p], str(tr.punch_hand[i]), xyz[f - 1 : f + 3, 1 - p], COCO17_FEET)
        near = min(float(gaps["head"].min()), float(gaps["body"].min()))
        if tr.punch_outcome[i] == "landed":
            assert near <= CONTACT_TOL_M
        elif tr.punch_outcome[i] == "missed":
            assert near > CONTACT_TOL_M and float(gaps["arms"].min()) > CONTACT_TOL_M
    # Feints travel a fraction of a punch's path.
    for k in range(tr.feint_person.size):
        p, f0, f1 = int(tr.feint_person[k]), int(tr.feint_start_frame[k]), int(tr.feint_peak_frame[k])
        w = xyz[:, p, COCO17_FEET.index(f"{tr.feint_hand[k]}_wrist")]
        assert np.linalg.norm(w[f1] - w[f0]) < 0.25


def test_contact_outcome_on_hand_made_bodies() -> None:
    from tests.stages.analyze_fixtures import J, two_boxers

    xyz = two_boxers(3, distance_m=1.0)
    frames = np.arange(3)
    assert contact_outcome(xyz, 0, "left", frames) == ("missed", "none")
    head = xyz[:, 1, [J["left_ear"], J["right_ear"]]].mean(axis=1)
    xyz[:, 0, J["left_elbow"]] = head - np.array([0.45, 0.0, 0.0])
    xyz[:, 0, J["left_wrist"]] = head - np.array([0.45 - 0.24 / 1.25 * 1.0, 0.0, 0.0])
    # glove centre = elbow + 1.25 (wrist - elbow) = head - 0.21 m: 0.045 m short of the head sphere + glove
    assert contact_outcome(xyz, 0, "left", frames)[0] in ("missed", "blocked")
    xyz[:, 0, J["left_wrist"]] += np.array([0.05, 0.0, 0.0])
    xyz[:, 1, J["left_wrist"], 2] -= 0.4  # the defender's hands are down
    xyz[:, 1, J["right_wrist"], 2] -= 0.4
    assert contact_outcome(xyz, 0, "left", frames) == ("landed", "head")


def test_demo_session_saves_the_truth(tmp_path) -> None:  # noqa: ANN001
    from pipeline.synthetic.session import GT_EVENTS, make_demo_session

    s = make_demo_session(tmp_path / "demo", SyntheticConfig(n_frames=60, n_cameras=2, bystander=False))
    tr = load_npz(s / GT_EVENTS, BoutTruth)
    assert tr.clinch.shape == (60,) and tr.fps == 50.0
