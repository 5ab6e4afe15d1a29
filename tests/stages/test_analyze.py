"""The analyze stage on hand-made boxers: punch detection, types, outcomes, evasions,
clinches, series, and its schema."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.schema import save_npz
from pipeline.schema.analytics import AthleteSeries, BoutEvents
from pipeline.schema.base import load_npz
from pipeline.stages.analyze import AnalyzeConfig, AnalyzeInputs, PunchConfig, TypeConfig, run
from pipeline.stages.analyze.classify import PathFeatures, is_lead, punch_type
from pipeline.stages.analyze.config import OutcomeConfig, WorkRateConfig
from pipeline.stages.analyze.defence import clean_runs
from pipeline.stages.analyze.outcome import body_region, contact_regions, from_contacts, from_gaps
from pipeline.stages.analyze.punches import raw_peak_speed
from pipeline.stages.analyze.workrate import punches_per_min
from tests.stages.analyze_fixtures import FPS, J, bezier, keypoints, profile, straight, throw, two_boxers

GUARD_L = np.array([0.3, 0.12, 1.45])


def _jab(xyz: np.ndarray, t0_s: float, end: np.ndarray, out_s: float = 0.1) -> None:
    throw(xyz, 0, "left", profile(xyz.shape[0], t0_s, out_s), straight(GUARD_L, end))


def test_a_jab_is_found_with_its_frames_speed_and_type() -> None:
    xyz = two_boxers(100, distance_m=1.6)
    _jab(xyz, 0.6, GUARD_L + np.array([0.3, 0.0, 0.0]))  # 0.3 m in 0.1 s: peak 5.6 m/s
    out = run(AnalyzeInputs(keypoints(xyz)))
    ev = out.events
    assert ev.n_punches == 1, ev.punch_peak_frame
    assert ev.punch_person[0] == 0 and ev.punch_hand[0] == "left" and ev.punch_type[0] == "jab"
    assert 30 <= ev.punch_start_frame[0] <= 31 and abs(int(ev.punch_peak_frame[0]) - 35) <= 1
    assert ev.punch_end_frame[0] > ev.punch_peak_frame[0]
    assert ev.punch_peak_speed_mps[0] == pytest.approx(1.875 * 0.3 / 0.1, rel=0.05)
    assert ev.punch_outcome[0] == "missed" and ev.punch_target[0] == "none"  # 1.6 m away
    assert out.stats["punches"] == 1 and out.series.punches_per_min[-1, 0] > 0


def test_feints_slow_reaches_and_blocks_are_not_punches() -> None:
    xyz = two_boxers(120, distance_m=1.6)
    _jab(xyz, 0.3, GUARD_L + np.array([0.08, 0.0, 0.0]), out_s=0.08)  # a feint: 8 cm
    _jab(xyz, 1.2, GUARD_L + np.array([0.3, 0.0, 0.0]), out_s=0.5)  # a slow reach: 1.1 m/s
    # The other athlete's glove goes to his own face quickly (a catch): not forward.
    throw(xyz, 1, "right", profile(120, 0.8, 0.08), straight(xyz[0, 1, J["right_wrist"]], xyz[0, 1, J["left_ear"]] + [-0.1, 0, 0]))
    assert run(AnalyzeInputs(keypoints(xyz))).events.n_punches == 0


def test_punch_types_from_the_path() -> None:
    n = 100
    cases = {
        "lead_hook": bezier(GUARD_L, np.array([0.42, 0.42, 1.5]), np.array([0.6, 0.35, 1.55]), np.array([0.6, -0.05, 1.55])),
        "lead_uppercut": bezier(GUARD_L, np.array([0.3, 0.12, 1.2]), np.array([0.42, 0.08, 1.25]), np.array([0.5, 0.05, 1.62])),
        "body_shot": straight(GUARD_L, np.array([0.62, 0.05, 1.1])),
        "jab": straight(GUARD_L, np.array([0.62, 0.0, 1.55])),
    }
    for want, path in cases.items():
        xyz = two_boxers(n, distance_m=1.6)
        throw(xyz, 0, "left", profile(n, 0.6, 0.12), path)
        ev = run(AnalyzeInputs(keypoints(xyz))).events
        assert ev.n_punches == 1 and ev.punch_type[0] == want, (want, ev.punch_type)
    # The rear hand of an orthodox boxer throws crosses; of a southpaw, jabs.
    for southpaw, want in ((False, "cross"), (True, "jab")):
        xyz = two_boxers(n, distance_m=1.6, southpaw=(southpaw, False))
        start = xyz[0, 0, J["right_wrist"]]
        throw(xyz, 0, "right", profile(n, 0.6, 0.12), straight(start, start + np.array([0.35, 0.0, 0.05])))
        out = run(AnalyzeInputs(keypoints(xyz)))
        assert out.events.punch_type.tolist() == [want]
        assert out.series.stance[50, 0] == (-1 if southpaw else 1)


def test_type_rules() -> None:
    cfg = TypeConfig()
    def f(rise: float = 0.1, bulge: float = 0.0, sag: float = 0.0, climb: float = 0.0, level: float = 1.2) -> PathFeatures:
        return PathFeatures(rise=rise, across=0.0, bulge=bulge, sag=sag, climb=climb, level=level)

    assert punch_type(f(rise=0.9, sag=0.15), True, cfg) == "lead_uppercut"
    assert punch_type(f(rise=0.9, bulge=0.4), False, cfg) == "rear_hook"
    assert punch_type(f(level=0.4), False, cfg) == "body_shot"
    assert punch_type(f(level=float("nan")), False, cfg) == "cross"
    stance = np.array([0, 0, 1, 1, 0, -1, -1])
    assert is_lead("left", stance, 0) and is_lead("right", stance, 6) and not is_lead("left", stance, 5)
    assert is_lead("left", np.zeros(3, dtype=int), 1)  # unknown: orthodox


def test_outcome_rules() -> None:
    cfg = OutcomeConfig()
    assert from_gaps({"head": 0.01, "body": 0.2, "arms": 0.08}, cfg) == ("head", "landed")
    assert from_gaps({"head": 0.3, "body": 0.02, "arms": 0.1}, cfg) == ("body", "landed")
    assert from_gaps({"head": 0.12, "body": 0.2, "arms": 0.0}, cfg) == ("guard", "blocked")
    assert from_gaps({"head": 0.03, "body": 0.2, "arms": 0.0}, cfg) == ("guard", "blocked")  # the glove got there first
    assert from_gaps({"head": 0.15, "body": 0.3, "arms": 0.25}, cfg) == ("head", "missed")
    assert from_gaps({"head": 0.5, "body": 0.5, "arms": 0.5}, cfg) == ("none", "missed")
    assert from_contacts({"arms", "head"}) == ("head", "landed")
    assert from_contacts({"arms"}) == ("guard", "blocked") and from_contacts(set()) is None
    assert body_region("p1_left_forearm") == (1, "left", "arms") and body_region("p0_torso") == (0, "", "body")
    assert body_region("world") is None and body_region("p0_left_shin") is None


def test_a_jab_on_the_chin_is_blocked_lands_or_is_slipped() -> None:
    d = 1.0
    head = np.array([d, 0.0, 1.62])
    end = head - np.array([0.1 + 0.065 + 0.05, 0.0, 0.0])  # glove centre ~0.06 m past the wrist
    xyz = two_boxers(100, distance_m=d)
    _jab(xyz, 0.6, end)
    ev = run(AnalyzeInputs(keypoints(xyz))).events
    assert ev.punch_outcome.tolist() == ["blocked"] and ev.punch_target.tolist() == ["guard"]  # his guard is up
    for hand, side in (("left", -1.0), ("right", 1.0)):  # the defender drops his hands
        for joint, drop in (("wrist", 0.35), ("elbow", 0.15)):
            xyz[:, 1, J[f"{hand}_{joint}"]] += np.array([0.1, 0.1 * side, -drop])
    ev = run(AnalyzeInputs(keypoints(xyz))).events
    assert ev.punch_outcome.tolist() == ["landed"] and ev.punch_target.tolist() == ["head"]
    assert ev.n_evades == 0
    # The defender slips: his head (and the face points) goes 0.22 m sideways around the strike.
    slip = np.sin(np.pi * np.clip((np.arange(100) / FPS - 0.45) / 0.45, 0, 1)) ** 2
    for name in ("nose", "left_eye", "right_eye", "left_ear", "right_ear"):
        xyz[:, 1, J[name], 1] += 0.22 * slip
    ev = run(AnalyzeInputs(keypoints(xyz))).events
    assert ev.punch_outcome.tolist() == ["missed"]
    assert ev.evade_kind.tolist() == ["slip"] and ev.evade_person.tolist() == [1] and ev.evade_punch.tolist() == [0]
    assert ev.evade_displacement_m[0] > 0.15


def test_physics_contacts_decide_the_outcome() -> None:
    from pipeline.schema.results import PhysicsResult

    xyz = two_boxers(100, distance_m=1.6)
    _jab(xyz, 0.6, GUARD_L + np.array([0.3, 0.0, 0.0]))
    names = ("world", "p0_left_hand", "p1_head", "p1_right_forearm")
    res = PhysicsResult(
        person_ids=np.array([0, 1]), frame_indices=np.arange(100), fps=FPS, qpos=np.zeros((100, 1)), qvel=np.zeros((100, 1)),
        ctrl=np.zeros((100, 0)), joint_torque_nm=np.zeros((100, 0)), residual_root_force=np.zeros((100, 2, 6)),
        actuation="pd", contact_frame=np.array([35, 36]), contact_person=np.array([[0, 1], [0, 1]]),
        contact_body=np.array([[1, 2], [1, 3]]), contact_depth_m=np.array([0.01, 0.01]), body_names=names,
    )  # fmt: skip
    assert contact_regions(res, 0, "left", 1, np.arange(33, 38)) == {"head", "arms"}
    ev = run(AnalyzeInputs(keypoints(xyz, source="physics"), physics=res)).events
    assert ev.punch_outcome.tolist() == ["landed"] and ev.punch_target.tolist() == ["head"]
    off = AnalyzeConfig(outcome=OutcomeConfig(use_contacts=False))
    assert run(AnalyzeInputs(keypoints(xyz, source="physics"), physics=res), off).events.punch_outcome.tolist() == ["missed"]


def test_clinch_frames() -> None:
    n = 100
    xyz = two_boxers(n, distance_m=1.5)
    inside = slice(20, 71)
    xyz[inside, 1, :, 0] -= 1.1  # 0.4 m apart
    for p, other in ((0, 1), (1, 0)):
        centre = xyz[inside, other][:, [J["left_shoulder"], J["right_shoulder"], J["left_hip"], J["right_hip"]]].mean(axis=1)
        xyz[inside, p, J["left_wrist"]] = centre + np.array([0.0, 0.15, 0.1])
        xyz[inside, p, J["right_wrist"]] = centre + np.array([0.0, -0.15, 0.1])
    ev = run(AnalyzeInputs(keypoints(xyz))).events
    assert ev.n_clinches == 1
    assert (int(ev.clinch_start_frame[0]), int(ev.clinch_end_frame[0])) == (20, 70)
    assert ev.n_punches == 0  # hands going into and out of the grip are not punches
    m = np.array([0, 1, 1, 0, 1, 1, 1, 1, 0, 0, 1, 0], dtype=bool)
    assert clean_runs(m, 2).astype(int).tolist() == [0, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0]


def test_series_distance_guard_and_work_rate() -> None:
    xyz = two_boxers(60, distance_m=1.3)
    s = run(AnalyzeInputs(keypoints(xyz))).series
    assert s.distance_valid.all() and np.allclose(s.distance_m, 1.3)
    assert (s.stance == 1).all() and np.allclose(s.stance_width_m, np.hypot(0.44, 0.28))
    assert np.allclose(s.guard_height_m[:, 0], [1.45 - 1.52, 1.48 - 1.52])
    rate = punches_per_min(np.arange(600), 50.0, np.array([100, 200, 550]), WorkRateConfig(window_s=4.0, min_window_s=2.0))
    assert rate[0] == 0 and rate[100] == pytest.approx(30.0) and rate[250] == pytest.approx(2 * 60 / 4)
    assert rate[450] == pytest.approx(0.0) and rate[599] == pytest.approx(15.0)


def test_raw_speed_stencils() -> None:
    t = np.arange(40) / FPS
    x = np.stack([3.0 * t, np.zeros_like(t), np.zeros_like(t)], axis=1)  # 3 m/s exactly
    ok = np.ones(40, dtype=bool)
    assert raw_peak_speed(x, ok, np.full(40, 4), 10, 20, FPS) == pytest.approx(3.0)
    assert raw_peak_speed(x, ok, np.full(40, 2), 10, 20, FPS) == pytest.approx(3.0)
    ok[5:25] = False
    assert raw_peak_speed(x, ok, np.full(40, 4), 10, 20, FPS) is None


def test_events_schema_validates_and_round_trips(tmp_path) -> None:  # noqa: ANN001
    xyz = two_boxers(100, distance_m=1.6)
    _jab(xyz, 0.6, GUARD_L + np.array([0.3, 0.0, 0.0]))
    out = run(AnalyzeInputs(keypoints(xyz)))
    save_npz(tmp_path / "events.npz", out.events)
    save_npz(tmp_path / "series.npz", out.series)
    ev = load_npz(tmp_path / "events.npz", BoutEvents)
    s = load_npz(tmp_path / "series.npz", AthleteSeries)
    assert ev.punch_type.tolist() == out.events.punch_type.tolist() and ev.fps == FPS
    np.testing.assert_array_equal(s.guard_height_m, out.series.guard_height_m)
    empty = BoutEvents.empty(50.0, np.array([0, 1]))
    with pytest.raises(ValueError, match="unknown values"):
        BoutEvents(**{**empty.__dict__, "punch_person": np.array([0]), "punch_hand": np.array(["left"]),
                      "punch_type": np.array(["haymaker"]), "punch_start_frame": np.array([1]),
                      "punch_peak_frame": np.array([2]), "punch_end_frame": np.array([3]),
                      "punch_peak_speed_mps": np.array([5.0]), "punch_extension": np.array([0.9]),
                      "punch_target": np.array(["head"]), "punch_outcome": np.array(["landed"]),
                      "punch_confidence": np.array([0.5])})  # fmt: skip
    with pytest.raises(ValueError, match="start 1 <= end 0"):
        BoutEvents(**{**empty.__dict__, "clinch_start_frame": np.array([1]), "clinch_end_frame": np.array([0])})
    with pytest.raises(ValueError, match="start 5 <= peak 2"):
        BoutEvents(**{**empty.__dict__, "punch_person": np.array([0]), "punch_hand": np.array(["left"]),
                      "punch_type": np.array(["jab"]), "punch_start_frame": np.array([5]),
                      "punch_peak_frame": np.array([2]), "punch_end_frame": np.array([3]),
                      "punch_peak_speed_mps": np.array([5.0]), "punch_extension": np.array([0.9]),
                      "punch_target": np.array(["head"]), "punch_outcome": np.array(["landed"]),
                      "punch_confidence": np.array([0.5])})  # fmt: skip


def test_config_and_input_errors() -> None:
    with pytest.raises(ValueError, match="edge_frac"):
        PunchConfig(edge_frac=1.5)
    with pytest.raises(ValueError, match="min_peak_speed_mps"):
        PunchConfig(min_peak_speed_mps=0.0)
    kp = keypoints(two_boxers(10))
    with pytest.raises(ValueError, match="lack joints"):
        run(AnalyzeInputs(kp.replace(joint_names=tuple(f"j{i}" for i in range(23)))))
