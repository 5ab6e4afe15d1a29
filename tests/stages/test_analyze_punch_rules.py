"""The punch rules a coach checks (``punches.RULES``) on hand-made glove and body tracks: an arm
swinging up from the hip or bending on the way out is no punch, a jab at the head is."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.stages.analyze import AnalyzeConfig, AnalyzeInputs, PunchConfig, run
from pipeline.stages.analyze.body import bodies, facing_frames
from pipeline.stages.analyze.punches import (
    Candidate,
    candidates,
    elbow_angle_deg,
    hand_track,
    overlaps,
    rule_failed,
)
from tests.stages.analyze_fixtures import FPS, J, keypoints, minjerk, profile, straight, throw, two_boxers

GUARD_L = np.array([0.3, 0.12, 1.45])
HEAD_OF_1 = np.array([1.0, 0.0, 1.62])  # athlete 1's head, 1 m away


def _rules(xyz: np.ndarray, cfg: PunchConfig = PunchConfig()) -> list[str | None]:
    """The first failed rule of every candidate of athlete 0's left fist (None = a punch)."""
    bs = bodies(keypoints(xyz), cfg.max_gap_frames)
    R, ok = facing_frames(bs[0], bs[1])
    h = hand_track(bs[0], R, ok, "left", cfg)
    return [rule_failed(c, cfg, bs[0].fps) for c in candidates(bs[0], h, cfg)]


def _punches(xyz: np.ndarray, cfg: PunchConfig = PunchConfig()) -> int:
    return run(AnalyzeInputs(keypoints(xyz)), AnalyzeConfig(punch=cfg)).events.n_punches


def test_a_jab_at_the_head_passes_every_rule() -> None:
    xyz = two_boxers(100, distance_m=1.0)
    throw(xyz, 0, "left", profile(100, 0.6, 0.1), straight(GUARD_L, HEAD_OF_1 - np.array([0.3, 0.0, 0.0])))
    assert _rules(xyz) == [None]
    assert _punches(xyz) == 1


def test_a_fast_arm_swing_up_from_the_hip_is_not_thrown_from_the_guard() -> None:
    # The hanging arm (wrist 0.45 m below the shoulders) swings forward and up at the
    # opponent at ~5 m/s: fast, forward and extended, but it starts from no guard.
    xyz = two_boxers(100, distance_m=1.0)
    hip_side = np.array([0.05, 0.2, 1.0])
    throw(xyz, 0, "left", profile(100, 0.6, 0.12), straight(hip_side, np.array([0.45, 0.15, 1.3])))
    assert _rules(xyz) == ["guard_start"]
    assert _punches(xyz) == 0
    # Let a fist start that low and the next rule rejects it: the swing bends the elbow too
    # (as the Pose2Sim performer's did); with both rules loosened it counts.
    loose = dataclasses.replace(PunchConfig(), max_start_drop=2.0)
    assert _rules(xyz, loose) == ["elbow_extends"]
    looser = dataclasses.replace(loose, min_elbow_open_deg=-180.0)
    assert _rules(xyz, looser) == [None] and _punches(xyz, looser) == 1


def test_a_fast_arm_raise_away_from_the_opponent_is_not_a_punch() -> None:
    xyz = two_boxers(100, distance_m=1.0)
    throw(xyz, 0, "left", profile(100, 0.6, 0.1), straight(GUARD_L, GUARD_L + np.array([-0.15, 0.1, 0.35])))
    assert _rules(xyz) == ["forward"] and _punches(xyz) == 0


def test_a_fist_driven_out_while_the_elbow_bends_is_not_a_punch() -> None:
    # The fist goes at the head as fast as a jab, but the elbow closes (drops 0.3 m below the
    # shoulder-wrist line): a push of the bent arm, not a punch extending it.
    xyz = two_boxers(100, distance_m=1.0)
    prof = profile(100, 0.6, 0.1)
    throw(xyz, 0, "left", prof, straight(GUARD_L, HEAD_OF_1 - np.array([0.3, 0.0, 0.0])))
    xyz[:, 0, J["left_elbow"], 2] -= 0.3 * prof
    assert _rules(xyz) == ["elbow_extends"] and _punches(xyz) == 0
    loose = dataclasses.replace(PunchConfig(), min_elbow_open_deg=-180.0)
    assert _rules(xyz, loose) == [None]


def test_rule_thresholds_and_elbow_angle() -> None:
    c = Candidate("left", 10, 15, 25, 12, 15, 0.3, 5.0, 6.0, 0.9, 0.3, -0.05, 40.0, False)
    cfg = PunchConfig()
    assert rule_failed(c, cfg, 50.0) is None
    assert rule_failed(dataclasses.replace(c, start_drop=cfg.max_start_drop + 0.01), cfg, 50.0) == "guard_start"
    assert rule_failed(dataclasses.replace(c, elbow_open_deg=cfg.min_elbow_open_deg - 1.0), cfg, 50.0) == "elbow_extends"
    assert rule_failed(dataclasses.replace(c, elbow_open_deg=float("nan")), cfg, 50.0) is None  # no elbow: others decide
    assert rule_failed(dataclasses.replace(c, start_drop=float("nan")), cfg, 50.0) == "guard_start"
    s, e = np.zeros((3, 3)), np.array([[0.0, 0.0, -0.3]] * 3)
    w = np.array([[0.0, 0.0, -0.6], [0.3, 0.0, -0.3], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(elbow_angle_deg(s, e, w), [180.0, 90.0, 0.0], atol=1e-9)
    with pytest.raises(ValueError, match="max_start_drop"):
        PunchConfig(max_start_drop=0.0)
    with pytest.raises(ValueError, match="min_elbow_open_deg"):
        PunchConfig(min_elbow_open_deg=200.0)


def _double(t0_s: float = 0.6, out_s: float = 0.1, back_frac: float = 0.5) -> np.ndarray:
    """(100,) a double jab's extension: out, back ``back_frac`` of the way, out again, home."""
    t = np.arange(100) / FPS
    t1 = t0_s + out_s + 0.04
    t2 = t1 + 0.1
    return (minjerk((t - t0_s) / out_s) - back_frac * minjerk((t - t1) / 0.08)
            + back_frac * minjerk((t - t2) / 0.08) - minjerk((t - t2 - 0.12) / 0.16))  # fmt: skip


def test_a_double_jab_without_a_return_to_the_guard_is_two_punches() -> None:
    # The fist comes back half way and goes out again: one excursion with two peaks. Split at
    # the valley each way out is judged on its own and both are punches; without the split the
    # excursion is one punch (the larger bump).
    xyz = two_boxers(100, distance_m=1.0)
    throw(xyz, 0, "left", _double(), straight(GUARD_L, HEAD_OF_1 - np.array([0.3, 0.0, 0.0])))
    assert _rules(xyz) == [None, None]
    ev = run(AnalyzeInputs(keypoints(xyz)), AnalyzeConfig()).events
    assert ev.n_punches == 2 and ev.punch_start_frame[1] >= ev.punch_end_frame[0]
    assert ev.punch_peak_frame[0] < ev.punch_start_frame[1] < ev.punch_peak_frame[1]
    whole = dataclasses.replace(PunchConfig(), split_at_valleys=False)
    assert _punches(xyz, whole) == 1


def test_a_shallow_dip_while_the_fist_is_out_is_no_second_punch() -> None:
    # The fist comes back 2 cm on the way (a tremor, not a new punch): no second peak, one punch.
    xyz = two_boxers(100, distance_m=1.0)
    throw(xyz, 0, "left", _double(back_frac=0.05), straight(GUARD_L, HEAD_OF_1 - np.array([0.3, 0.0, 0.0])))
    assert _rules(xyz) == [None] and _punches(xyz) == 1


def test_overlaps_shares_more_than_the_valley_frame() -> None:
    assert overlaps(10, 20, 15, 30) and overlaps(15, 30, 10, 20) and overlaps(10, 30, 12, 14)
    assert not overlaps(10, 20, 20, 30) and not overlaps(20, 30, 10, 20) and not overlaps(10, 20, 25, 30)


@pytest.mark.parametrize(("advance_m", "rule"), [(0.07, None), (0.01, "forward")])
def test_a_flattened_punch_that_still_advances_keeps_the_forward_rule(advance_m: float, rule: str | None) -> None:
    # A fist that leaves the guard by 0.25 m mostly across and up (the way a two-view fit
    # flattens a body shot) counts when it ends a few cm nearer the opponent; a glove raised
    # onto the guard without advancing (a block) does not.
    xyz = two_boxers(100, distance_m=1.0)
    end = GUARD_L + np.array([advance_m, -0.12, -0.2])
    throw(xyz, 0, "left", profile(100, 0.6, 0.08), straight(GUARD_L, end))
    loose = dataclasses.replace(PunchConfig(), min_elbow_open_deg=-180.0, min_extension=0.0)
    assert _rules(xyz, loose) == [rule]
    strict = dataclasses.replace(loose, min_forward_m=0.12)  # the former threshold took neither
    assert _rules(xyz, strict) == ["forward"]


def test_min_forward_must_not_be_negative() -> None:
    with pytest.raises(ValueError, match="min_forward_m"):
        PunchConfig(min_forward_m=-0.01)
