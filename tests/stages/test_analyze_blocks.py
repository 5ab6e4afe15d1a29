"""Blocks and parries (``pipeline.stages.analyze.blocks``) on hand-made glove and forearm tracks:
athlete 0 jabs with his left hand at athlete 1, whose guard is down except the left glove we
move; then the physics contacts' variant, the annotators' block/parry edits and the exports."""

from __future__ import annotations

import numpy as np

from pipeline.io.events_export import events_to_csv, events_to_json
from pipeline.schema.annotations import AddEvent, DeleteEvent
from pipeline.schema.results import PhysicsResult
from pipeline.stages.analyze import AnalyzeConfig, AnalyzeInputs, DefenceConfig, run
from tests.stages.analyze_fixtures import FPS, J, keypoints, profile, straight, throw, two_boxers

N = 100
A = np.array([0.3, 0.12, 1.45])  # the jab's start (the left guard) and its end, world metres
B = np.array([0.62, 0.0, 1.55])
C = 33  # the frame the defender's glove reaches the punch (the jab runs over frames 30-35)
DEFLECT_M = 0.12


def _bout(deflect_m: float, guard_speed_mps: float, distance_m: float = 1.0) -> np.ndarray:
    """(frames, 2, 23, 3): the jab, bent sideways (+y) by ``deflect_m`` over the 3 frames after
    frame ``C``; the defender's left glove centre arrives 0.11 m beside (-y) the jab's glove at
    ``C`` moving +y at ``guard_speed_mps``, then goes along with the deflection."""
    xyz = two_boxers(N, distance_m=distance_m)
    for hand, side in (("left", -1.0), ("right", 1.0)):  # the defender's guard drops
        for joint, drop in (("wrist", 0.35), ("elbow", 0.15)):
            xyz[:, 1, J[f"{hand}_{joint}"]] += np.array([0.1, 0.1 * side, -drop])
    prof = profile(N, 0.6, 0.1)
    f = np.arange(N)
    off = deflect_m * np.clip((f - C) / 3, 0, 1) * prof
    throw(xyz, 0, "left", prof, lambda p: straight(A, B)(p) + off[:, None] * np.array([0.0, 1.0, 0.0]))
    w, e = xyz[:, 0, J["left_wrist"]], xyz[:, 0, J["left_elbow"]]
    glove = e + 1.25 * (w - e)  # CapsuleProxy's glove sphere centre
    target = glove[C] + np.array([0.0, -0.11, 0.0])  # 0.11 m centre to centre: touching (radii 2 x 0.065)
    step = guard_speed_mps / FPS
    g = np.array([target - [0.0, step * (C - k), 0.0] if k <= C else target + [0.0, off[k], 0.0] for k in f])
    # His forearm points back towards him (+x); the glove centre is 1/4 of it past the wrist.
    xyz[:, 1, J["left_wrist"]] = g + np.array([0.05, 0.0, -0.025])
    xyz[:, 1, J["left_elbow"]] = g + np.array([0.25, 0.0, -0.125])
    return xyz


def _defence(xyz: np.ndarray, **kw: object) -> list[tuple[str, int, int, int]]:
    ev = run(AnalyzeInputs(keypoints(xyz), **kw)).events  # type: ignore[arg-type]
    assert ev.n_punches == 1 and ev.punch_person.tolist() == [0]
    return list(zip(ev.evade_kind.tolist(), ev.evade_person.tolist(), ev.evade_peak_frame.tolist(),
                    ev.evade_punch.tolist(), strict=True))  # fmt: skip


def test_a_glove_moving_across_that_deflects_the_jab_is_a_parry() -> None:
    ev = run(AnalyzeInputs(keypoints(_bout(DEFLECT_M, 3.0)))).events
    assert (
        ev.evade_kind.tolist() == ["parry"]
        and ev.evade_person.tolist() == [1]
        and ev.evade_punch.tolist() == [0]
    )
    assert ev.evade_peak_frame.tolist() == [C]  # the first contact
    # start: the deflection window (0.06 s = 3 frames) before the contact, not before the jab's
    # start; end: 3 frames after
    start = max(C - 3, int(ev.punch_start_frame[0]))
    assert (int(ev.evade_start_frame[0]), int(ev.evade_end_frame[0])) == (start, C + 3)
    # ~0.12 m sideways beyond the jab's own sideways drift, along the across-the-line axis
    assert 0.09 < ev.evade_displacement_m[0] < 0.2
    out = run(AnalyzeInputs(keypoints(_bout(DEFLECT_M, 3.0))))
    assert out.stats["parries"] == 1 and out.stats["blocks"] == 0


def test_without_the_deflection_or_the_glove_moving_it_is_a_block() -> None:
    assert _defence(_bout(0.0, 3.0)) == [("block", 1, C, 0)]  # moving across, jab not deflected
    kinds = _defence(_bout(DEFLECT_M, 0.0))  # deflected, but the glove waited for it
    assert [k[0] for k in kinds] == ["block"]
    # moving across against the deflection's direction: not a parry either
    xyz = _bout(-DEFLECT_M, 3.0)
    assert [k[0] for k in _defence(xyz)] != ["parry"]
    # stricter thresholds turn the parry into a block
    strict = AnalyzeConfig(defence=DefenceConfig(parry_min_deflection_m=0.3))
    assert run(AnalyzeInputs(keypoints(_bout(DEFLECT_M, 3.0))), strict).events.evade_kind.tolist() == [
        "block"
    ]


def test_a_parry_the_analysed_3d_smoothed_away_is_found_in_the_raw_triangulation() -> None:
    """The fit pulls the gloves apart and undoes the deflection; the raw triangulation keeps them."""
    smoothed = _bout(0.0, 3.0)
    for joint in ("left_wrist", "left_elbow"):
        smoothed[:, 1, J[joint], 1] -= 0.1  # 10 cm short of the jab: no contact in the analysed 3D
    raw = keypoints(_bout(DEFLECT_M, 3.0))
    assert "parry" not in [k[0] for k in _defence(smoothed)]  # the analysed 3D alone
    assert "parry" not in [k[0] for k in _defence(smoothed, raw=raw)]  # the default: opt-in
    on = AnalyzeConfig(defence=DefenceConfig(parry_measured=True))
    ev = run(AnalyzeInputs(keypoints(smoothed), raw=raw), on).events
    assert list(zip(ev.evade_kind.tolist(), ev.evade_person.tolist(), ev.evade_peak_frame.tolist(), strict=True)) == [
        ("parry", 1, C)
    ]


def test_no_block_when_the_glove_touches_nothing_or_lands() -> None:
    far = _bout(0.0, 3.0)
    far[:, 1, J["left_wrist"], 1] -= 0.5  # the defender's glove stays 0.5 m off the jab's line
    far[:, 1, J["left_elbow"], 1] -= 0.5
    ev = run(AnalyzeInputs(keypoints(far))).events
    assert ev.punch_outcome.tolist() == ["missed"] and ev.n_evades == 0
    landed = two_boxers(N, distance_m=1.0)  # guard down, the jab ends on the chin
    for hand, side in (("left", -1.0), ("right", 1.0)):
        for joint, drop in (("wrist", 0.35), ("elbow", 0.15)):
            landed[:, 1, J[f"{hand}_{joint}"]] += np.array([0.1, 0.1 * side, -drop])
    throw(landed, 0, "left", profile(N, 0.6, 0.1), straight(A, np.array([1.0 - 0.215, 0.0, 1.62])))
    ev = run(AnalyzeInputs(keypoints(landed))).events
    assert ev.punch_outcome.tolist() == ["landed"] and ev.n_evades == 0


def _physics(frames: list[int], pairs: list[tuple[str, str]]) -> PhysicsResult:
    names = (
        "world",
        "p0_left_hand",
        "p0_left_forearm",
        "p1_left_hand",
        "p1_right_forearm",
        "p1_right_upper_arm",
    )
    return PhysicsResult(
        person_ids=np.array([0, 1]), frame_indices=np.arange(N), fps=FPS, qpos=np.zeros((N, 1)), qvel=np.zeros((N, 1)),
        ctrl=np.zeros((N, 0)), joint_torque_nm=np.zeros((N, 0)), residual_root_force=np.zeros((N, 2, 6)),
        actuation="pd", contact_frame=np.array(frames), contact_person=np.array([[0, 1]] * len(frames)),
        contact_body=np.array([[names.index(a), names.index(b)] for a, b in pairs]),
        contact_depth_m=np.full(len(frames), 0.01), body_names=names,
    )  # fmt: skip


def _glove_back(xyz: np.ndarray) -> np.ndarray:
    """The defender's left glove and forearm 0.6 m farther from the jab (+x): no 3D contact."""
    for j in ("left_wrist", "left_elbow"):
        xyz[:, 1, J[j], 0] += 0.6
    return xyz


def test_physics_contacts_decide_when_physics_ran() -> None:
    # 1.6 m apart: in 3D nothing touches; the physics stage says the glove hit a forearm.
    xyz = _glove_back(_bout(0.0, 0.0, distance_m=1.6))
    kp = keypoints(xyz, source="physics")
    assert run(AnalyzeInputs(kp)).events.n_evades == 0
    hit = _physics([35], [("p0_left_hand", "p1_right_forearm")])
    assert [k[0] for k in _defence(xyz, physics=hit)] == ["block"]
    # on the upper arm: blocked as an outcome, but not with the glove or forearm
    upper = _physics([35], [("p0_left_hand", "p1_right_upper_arm")])
    ev = run(AnalyzeInputs(kp, physics=upper)).events
    assert ev.punch_outcome.tolist() == ["blocked"] and ev.n_evades == 0
    # the defender's glove on the punching forearm at C, moving across and deflecting: a parry
    xyz = _glove_back(_bout(DEFLECT_M, 3.0, distance_m=1.6))  # his glove moves as before, farther
    assert run(AnalyzeInputs(keypoints(xyz, source="physics"))).events.n_evades == 0
    parry = _physics([C], [("p1_left_hand", "p0_left_forearm")])
    assert _defence(xyz, physics=parry) == [("parry", 1, C, 0)]


def test_annotators_add_and_delete_blocks_and_parries_and_exports_carry_them() -> None:
    xyz = _bout(0.0, 3.0)
    before = run(AnalyzeInputs(keypoints(xyz))).events
    assert before.evade_kind.tolist() == ["block"]
    edits = (
        DeleteEvent(person=1, event="block", frame=C),
        AddEvent(person=1, event="parry", frame_start=30, frame_end=36),
    )
    out = run(AnalyzeInputs(keypoints(_bout(DEFLECT_M, 0.0)), corrections=edits))
    ev = out.events
    assert out.stats["corrections_applied"] == 2 and out.stats["corrections_unmatched"] == 0
    assert ev.evade_kind.tolist() == ["parry"] and ev.evade_source.tolist() == ["annotator"]
    # tied to the jab; its peak is the jab's strike; its displacement the jab's measured deflection
    assert ev.evade_punch.tolist() == [0] and ev.evade_peak_frame[0] == ev.punch_peak_frame[0]
    assert ev.evade_displacement_m[0] > 0.0
    doc = events_to_json(ev, {0: "Red", 1: "Blue"})
    assert [(e["kind"], e["athlete"], e["source"]) for e in doc["evades"]] == [("parry", "Blue", "annotator")]
    rows = events_to_csv(ev).splitlines()
    assert sorted(r.split(",")[0] for r in rows[1:]) == ["parry", "punch"]
    no_punch = run(
        AnalyzeInputs(
            keypoints(xyz), corrections=(AddEvent(person=1, event="block", frame_start=80, frame_end=90),)
        )
    )
    assert (
        no_punch.stats["corrections_unmatched"] == 1
        and "no punch of the opponent" in no_punch.stats["corrections_unmatched_edits"][0]
    )
