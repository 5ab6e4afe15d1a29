"""2D evidence of punches per camera view (``pipeline.stages.analyze.evidence2d``), on hand-made
boxers projected into two pinhole views: a fast wrist excursion in one view is found, a still
arm or the whole athlete walking is not; a jab the fit slowed down is confirmed by the views;
mismatched inputs fail with a clear error."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.schema import COCO17_FEET
from pipeline.schema.association import Association
from pipeline.schema.detections import Tracks2D
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.stages.analyze import AnalyzeConfig, AnalyzeInputs, run
from pipeline.stages.analyze import evidence2d as e2
from pipeline.stages.analyze.config import ViewEvidenceConfig
from tests.stages.analyze_fixtures import FPS, keypoints, profile, straight, throw, two_boxers

N = 100
GUARD_L = np.array([0.3, 0.12, 1.45])
AT_HEAD = np.array([0.7, 0.0, 1.62])
FOCAL_PX = 1000.0
# (centre, forward): view 0 looks across the punch line (+y), view 1 along it (+x).
CAMERAS = (
    (np.array([0.5, -4.0, 1.5]), np.array([0.0, 1.0, 0.0])),
    (np.array([-4.0, 0.0, 1.5]), np.array([1.0, 0.0, 0.0])),
)
ON = AnalyzeConfig(views=ViewEvidenceConfig(enabled=True))


def _jab(scale: float = 1.0, out_s: float = 0.1) -> np.ndarray:
    """Athlete 0 throws a left jab at 0.6 s, ``scale`` of its full path, out in ``out_s``."""
    xyz = two_boxers(N, distance_m=1.0)
    throw(xyz, 0, "left", profile(N, 0.6, out_s), straight(GUARD_L, GUARD_L + scale * (AT_HEAD - GUARD_L)))
    return xyz


def _project(xyz: np.ndarray, cameras: tuple = CAMERAS) -> Tracks2D:
    """Pinhole images (no noise) of every athlete of ``xyz`` (frames, persons, 23, 3) in
    ``cameras``; rows ordered by (view, frame, person), track id = person."""
    view: list[int] = []
    frame: list[int] = []
    points: list[np.ndarray] = []
    track: list[int] = []
    up = np.array([0.0, 0.0, 1.0])
    for v, (centre, fwd) in enumerate(cameras):
        right = np.cross(fwd, up)
        p = xyz - centre
        depth = p @ fwd
        uv = np.stack([640.0 + FOCAL_PX * (p @ right) / depth, 360.0 - FOCAL_PX * (p @ up) / depth], axis=-1)
        for f in range(xyz.shape[0]):
            for person in range(xyz.shape[1]):
                view.append(v)
                frame.append(f)
                points.append(uv[f, person])
                track.append(person)
    kp = np.array(points)
    n = kp.shape[0]
    box = np.concatenate([kp.min(axis=1), kp.max(axis=1)], axis=1)
    return Tracks2D(
        joint_names=COCO17_FEET, n_views=len(cameras), n_frames=xyz.shape[0], view=np.array(view),
        frame=np.array(frame), bbox_xyxy_px=box, bbox_score=np.ones(n), keypoints_px=kp,
        keypoint_conf=np.full(kp.shape[:2], 0.9), keypoint_valid=np.ones(kp.shape[:2], dtype=bool),
        track_id=np.array(track),
    )  # fmt: skip


def _association(tracks: Tracks2D) -> Association:
    return Association(
        person_ids=np.array([0, 1]), person_names=("", ""), person_of_det=tracks.track_id.copy(),
        confidence=np.ones(tracks.n_dets),
    )  # fmt: skip


def _signals(xyz: np.ndarray, cameras: tuple = CAMERAS) -> e2.ViewSignals:
    """Athlete 0's left wrist in every view, the 3D torso 0.5 m long (the fixtures' boxer)."""
    tracks = _project(xyz, cameras)
    pv = e2.person_views(tracks, _association(tracks), 0, np.arange(N))
    m_per_px = e2.image_scale_m_per_px(pv, 0.5, FPS, 1.5)
    return e2.view_signals(pv, "left", m_per_px, FPS, 1.5, 1.5, 4)


def test_a_fast_wrist_excursion_is_seen_in_the_view_across_it() -> None:
    sig = _signals(_jab())
    exc, speed = e2.window_evidence(sig, 28, 36, 45)
    # View 0 sees the 0.45 m path across its line of sight (0.4 m of it horizontal and
    # vertical); view 1 looks along the punch and sees only its 0.2 m sideways and up part.
    assert 0.38 < exc[0] < 0.5 and speed[0] > 5.0
    assert exc[1] < 0.25 and exc[1] < 0.6 * exc[0]
    before, fast_before = e2.window_evidence(sig, 0, 10, 20)
    assert before.max() < 0.01 and fast_before.max() < 0.1


def test_a_still_arm_and_a_walking_athlete_show_no_excursion() -> None:
    still = _signals(two_boxers(N, distance_m=1.0))
    exc, speed = e2.window_evidence(still, 1, 50, N - 2)
    assert exc.max() < 0.01 and speed.max() < 0.1
    # The whole athlete walks 2 m/s along x (0.8 m over 0.4 s) and back: the wrist moves
    # fast in the image, but with the neck.
    walk = two_boxers(N, distance_m=1.0)
    walk[:, 0] += (0.8 * profile(N, 0.6, 0.4, 0.0, 0.4))[:, None, None] * np.array([1.0, 0.0, 0.0])
    sig = _signals(walk)
    exc, speed = e2.window_evidence(sig, 1, 50, N - 2)
    assert sig.step_mps.max() > 2.0  # the wrist itself moves fast in the image ...
    # ... not away from the body (perspective leaves a few cm, a third of the threshold).
    assert exc.max() < ViewEvidenceConfig().view_min_excursion_m / 3 and speed.max() < 0.3


def test_the_projected_excursion_is_in_metres_whatever_the_distance() -> None:
    near = _signals(_jab())
    far_cameras = tuple((centre * np.array([1.0, 2.0, 1.0]), fwd) for centre, fwd in CAMERAS[:1])
    far = _signals(_jab(), far_cameras)
    e_near, _ = e2.window_evidence(near, 28, 36, 45)
    e_far, _ = e2.window_evidence(far, 28, 36, 45)
    assert abs(e_far[0] - e_near[0]) < 0.05 * e_near[0]


def test_a_jab_the_fit_slowed_down_is_confirmed_by_the_views() -> None:
    # The fit's fist travels 35 % of the path in 0.15 s (1.9 m/s: too slow, too short for the
    # punch rules); the cameras saw the whole jab, out in 0.1 s.
    fit, seen = _jab(0.35, 0.15), _jab()
    tracks = _project(seen)

    def left_jabs(inp: AnalyzeInputs, cfg: AnalyzeConfig) -> list[int]:
        ev = run(inp, cfg).events
        return ev.punch_peak_frame[(ev.punch_person == 0) & (ev.punch_hand == "left")].tolist()

    with_views = AnalyzeInputs(keypoints(fit), tracks=tracks, association=_association(tracks))
    strikes = left_jabs(with_views, ON)
    assert len(strikes) == 1 and 30 <= strikes[0] <= 40
    # No raw triangulation measures its speed: the fastest view's wrist lifts the fit's.
    speeds = {
        lift: run(
            with_views, dataclasses.replace(ON, views=ViewEvidenceConfig(enabled=True, lift_speed=lift))
        ).events.punch_peak_speed_mps.tolist()
        for lift in (False, True)
    }
    assert speeds[False][0] < 2.5 and speeds[True][0] > 1.5 * speeds[False][0]
    assert left_jabs(AnalyzeInputs(keypoints(fit)), ON) == []  # no 2D tracks: nothing to confirm it
    assert left_jabs(with_views, dataclasses.replace(ON, views=ViewEvidenceConfig(enabled=False))) == []
    # The views showing the same slow motion as the fit do not make a punch of it.
    slow = _project(fit)
    assert left_jabs(AnalyzeInputs(keypoints(fit), tracks=slow, association=_association(slow)), ON) == []


def test_the_views_add_a_punch_only_where_the_raw_triangulation_did_not_measure_it() -> None:
    # The fit's fist travels 35 % of the path in 0.15 s, the cameras saw the whole jab out in
    # 0.1 s. A raw triangulation that measured the way out (every frame triangulated) has judged
    # the motion with its own speed: the views add nothing. Where it lost the wrist on the way out
    # (a view did not see it), the views decide as without one.
    fit, tracks = _jab(0.35, 0.15), _project(_jab())
    raw = keypoints(fit, "raw")
    raw = dataclasses.replace(raw, n_views=np.full_like(raw.n_views, 2))
    hidden = raw.valid.copy()
    hidden[25:40, 0, COCO17_FEET.index("left_wrist")] = False
    lost = dataclasses.replace(raw, valid=hidden, n_views=np.where(hidden, 2, 1))

    def left_jabs(r: Keypoints3D, unmeasured_only: bool = True) -> list[int]:
        cfg = dataclasses.replace(ON, views=ViewEvidenceConfig(enabled=True, unmeasured_only=unmeasured_only))
        ev = run(
            AnalyzeInputs(keypoints(fit), raw=r, tracks=tracks, association=_association(tracks)), cfg
        ).events
        return ev.punch_peak_frame[(ev.punch_person == 0) & (ev.punch_hand == "left")].tolist()

    assert ViewEvidenceConfig().unmeasured_only
    assert left_jabs(raw) == []
    assert len(left_jabs(raw, unmeasured_only=False)) == 1  # the views alone would take it
    strikes = left_jabs(lost)
    assert len(strikes) == 1 and 30 <= strikes[0] <= 40


def test_the_default_lifts_the_speed_of_a_punch_the_rules_found_without_adding_punches() -> None:
    # The fit's jab is whole but slow (out in 0.2 s); the cameras saw it out in 0.1 s. The
    # default (``enabled`` off, ``lift_speed`` on) keeps the one punch and takes its speed from
    # the fastest view; without the lift the fit's speed stays.
    fit, tracks = _jab(1.0, 0.2), _project(_jab())
    inp = AnalyzeInputs(keypoints(fit), tracks=tracks, association=_association(tracks))
    lifted = run(inp, AnalyzeConfig()).events
    kept = run(inp, AnalyzeConfig(views=ViewEvidenceConfig(lift_speed=False))).events
    assert not AnalyzeConfig().views.enabled and AnalyzeConfig().views.lift_speed
    assert lifted.punch_hand.tolist() == kept.punch_hand.tolist() == ["left"]
    assert lifted.punch_peak_speed_mps[0] > 1.3 * kept.punch_peak_speed_mps[0]
    # A slow view does not lower the fit's speed (the lift only raises it).
    slow = _project(fit)
    same = run(
        AnalyzeInputs(keypoints(fit), tracks=slow, association=_association(slow)), AnalyzeConfig()
    ).events
    assert same.punch_peak_speed_mps[0] >= kept.punch_peak_speed_mps[0] - 1e-9


def test_mismatched_inputs_are_refused() -> None:
    tracks = _project(_jab())
    short = Association(np.array([0, 1]), ("", ""), tracks.track_id[:-3].copy(), np.ones(tracks.n_dets - 3))
    with pytest.raises(ValueError, match="association has .* rows for .* track rows"):
        AnalyzeInputs(keypoints(_jab()), tracks=tracks, association=short)
    with pytest.raises(ValueError, match="association has .* rows for .* track rows"):
        e2.person_views(tracks, short, 0, np.arange(N))
    with pytest.raises(ValueError, match="tracks and association go together"):
        AnalyzeInputs(keypoints(_jab()), tracks=tracks)
    no_hips = dataclasses.replace(
        tracks, joint_names=tuple("x" + n if "hip" in n else n for n in COCO17_FEET)
    )
    with pytest.raises(ValueError, match=r"lack joints \['left_hip', 'right_hip'\]"):
        e2.person_views(no_hips, _association(tracks), 0, np.arange(N))
    pv = e2.person_views(tracks, _association(tracks), 0, np.arange(N))
    with pytest.raises(ValueError, match="PersonViews: xy_px"):
        dataclasses.replace(pv, xy_px=pv.xy_px[:, :-1])
    sig = _signals(_jab())
    with pytest.raises(ValueError, match="view signals have 99 frames, the body 100"):
        from pipeline.stages.analyze.body import bodies, facing_frames
        from pipeline.stages.analyze.punches import hand_track

        b = bodies(keypoints(_jab()), 4)
        h = hand_track(b[0], *facing_frames(b[0], b[1]), "left", ON.punch)
        short_sig = dataclasses.replace(sig, excursion_m=sig.excursion_m[:, 1:], speed_mps=sig.speed_mps[:, 1:],
                                        ok=sig.ok[:, 1:], step_mps=sig.step_mps[:, 1:])  # fmt: skip
        e2.view_punches(b[0], h, short_sig, [], ON.punch, ON.views)
    with pytest.raises(ValueError, match="min_conf must be in"):
        ViewEvidenceConfig(min_conf=1.5)
    with pytest.raises(ValueError, match="view_min_speed_mps"):
        ViewEvidenceConfig(view_min_speed_mps=0.0)
