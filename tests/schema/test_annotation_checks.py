"""Every edit kind is checked against the session: frames, cameras, tracks and detections at
that frame, joints, pixels, persons; bad cases name the reason. Also: the bounds a session folder
gives (tracks from the track stage with pending track edits applied on top)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.runner import run
from pipeline.runner.annotation_bounds import annotation_bounds
from pipeline.schema.annotation_checks import AnnotationBounds, check_annotation
from pipeline.schema.annotations import (
    Annotation,
    AssignIdentity,
    FixKeypoint,
    LabelContact,
    MarkInvalid,
    MergeTracks,
    SplitTrack,
    SwapIdentities,
    annotation_from_dict,
    annotation_to_dict,
)
from pipeline.schema.detections import Tracks2D
from tests.conftest import make_rig, make_tracks, write_tiny_session


def _tracks() -> Tracks2D:
    """Two tracks (0, 1) per view over frames 0..19, then track 1 of view 0 is dropped after frame 9."""
    t, _ = make_tracks(make_rig(), n_frames=20)
    keep = ~((t.view == 0) & (t.track_id == 1) & (t.frame >= 10))
    return Tracks2D.from_detections(t.detections().select(np.flatnonzero(keep)), t.track_id[keep])


TRACKS = _tracks()
BOUNDS = AnnotationBounds(n_frames=20, person_ids=(0, 1), cameras=("cam0", "cam1", "cam2"), tracks=TRACKS,
                          image_size_wh=np.array([[640, 480]] * 3))


def test_fixture_tracks_are_what_the_cases_assume() -> None:
    assert set(np.unique(TRACKS.track_id).tolist()) == {0, 1}
    assert TRACKS.frame[(TRACKS.view == 0) & (TRACKS.track_id == 1)].max() == 9
    assert "left_wrist" in TRACKS.joint_names


GOOD = [
    AssignIdentity(view="cam0", track=1, frame_start=5, frame_end=15, person=0),
    AssignIdentity(view="cam1", track=0, frame_start=0, frame_end=19, person=-1),
    SwapIdentities(frame=3, person_a=0, person_b=1),
    SwapIdentities(frame=3, person_a=0, person_b=1, view="cam2", frame_end=20),
    SplitTrack(view="cam0", track=1, frame=9),
    MergeTracks(view="cam1", track_a=0, track_b=1),
    MarkInvalid(view="cam2", frame=19, track=1),
    FixKeypoint(view="cam0", frame=0, track=0, joint="left_wrist", x_px=10.5, y_px=479.0),
    LabelContact(frame_start=4, frame_end=4, person_a=0, part_a="left_hand", person_b=1, part_b="head"),
]


@pytest.mark.parametrize("edit", GOOD, ids=lambda e: e.kind)
def test_good_edits_pass(edit: object) -> None:
    check_annotation(edit, BOUNDS)  # type: ignore[arg-type]


BAD: list[tuple[Annotation, str]] = [
    # assign_identity
    (AssignIdentity("cam9", 0, 0, 5, 0), "view 'cam9' is not a camera"),
    (AssignIdentity("cam0", 7, 0, 5, 0), "track 7 is not a track of view 'cam0'"),
    (AssignIdentity("cam0", 1, 12, 18, 0), r"track 1 of view 'cam0' has no detection in frames 12..18 \(its frames: 0..9\)"),
    (AssignIdentity("cam0", 0, 0, 20, 0), "frame_end 20 is outside the bout"),
    (AssignIdentity("cam0", 0, 6, 5, 0), "frame_start 6 is after frame_end 5"),
    (AssignIdentity("cam0", 0, 0, 5, 7), r"person 7 is not a person of this session \(known persons \[0, 1\]"),
    (AssignIdentity("cam0", 0, 0, 5, -2), "person -2 is not a person"),
    (AssignIdentity("", 0, 0, 5, 0), "view must name a camera"),
    # swap_identities
    (SwapIdentities(frame=-5, person_a=0, person_b=1), "frame -5 is outside the bout"),
    (SwapIdentities(frame=99999, person_a=0, person_b=7), "frame 99999 is outside the bout"),
    (SwapIdentities(frame=5, person_a=0, person_b=7), "person_b 7 is not a person"),
    (SwapIdentities(frame=5, person_a=1, person_b=1), "a swap needs two persons"),
    (SwapIdentities(frame=5, person_a=0, person_b=1, frame_end=5), "frame_end 5 must be after frame 5 and at most 20"),
    (SwapIdentities(frame=5, person_a=0, person_b=1, frame_end=21), "frame_end 21 must be after frame 5 and at most 20"),
    (SwapIdentities(frame=5, person_a=0, person_b=1, view="cam3"), "view 'cam3' is not a camera"),
    # split_track
    (SplitTrack("cam0", 1, 10), r"track 1 of view 'cam0' has no detection at or after frame 10"),
    (SplitTrack("cam0", 4, 3), "track 4 is not a track of view 'cam0'"),
    (SplitTrack("camX", 0, 3), "view 'camX' is not a camera"),
    (SplitTrack("cam0", 0, 20), "frame 20 is outside the bout"),
    # merge_tracks
    (MergeTracks("cam0", 0, 0), "a merge needs two tracks"),
    (MergeTracks("cam0", 0, 5), "track_b 5 is not a track of view 'cam0'"),
    (MergeTracks("cam0", 5, 0), "track_a 5 is not a track of view 'cam0'"),
    (MergeTracks("nope", 0, 1), "view 'nope' is not a camera"),
    # mark_invalid
    (MarkInvalid("cam0", 15, 1), "track 1 of view 'cam0' has no detection at frame 15"),
    (MarkInvalid("cam0", 5, 3), "track 3 is not a track of view 'cam0'"),
    (MarkInvalid("cam0", -1, 0), "frame -1 is outside the bout"),
    # fix_keypoint
    (FixKeypoint("cam0", 12, 1, "left_wrist", 5.0, 5.0), "track 1 of view 'cam0' has no detection at frame 12"),
    (FixKeypoint("cam0", 2, 0, "tail", 5.0, 5.0), "joint 'tail' is not one of the keypoints"),
    (FixKeypoint("cam0", 2, 0, "left_wrist", 640.0, 5.0), r"pixel \(640.0, 5.0\) is outside the 640x480 image"),
    (FixKeypoint("cam0", 2, 0, "left_wrist", 5.0, -0.5), "is outside the 640x480 image"),
    (FixKeypoint("cam0", 2, 0, "left_wrist", float("nan"), 5.0), "x_px must be a finite number"),
    # label_contact
    (LabelContact(10, 5, 0, "left_hand", 1, "head"), "frame_start 10 is after frame_end 5"),
    (LabelContact(1, 5, 0, "left_hand", 3, "head"), "person_b 3 is not a person"),
    (LabelContact(1, 5, 0, " ", 1, "head"), "part_a must name a body part"),
    (LabelContact(1, 25, 0, "left_hand", 1, "head"), "frame_end 25 is outside the bout"),
]


@pytest.mark.parametrize(("edit", "reason"), BAD, ids=[f"{e.kind}-{i}" for i, (e, _) in enumerate(BAD)])
def test_bad_edits_name_the_reason(edit: object, reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        check_annotation(edit, BOUNDS)  # type: ignore[arg-type]


def test_types_are_checked() -> None:
    with pytest.raises(ValueError, match="frame must be an integer"):
        check_annotation(annotation_from_dict({"kind": "mark_invalid", "view": "cam0", "frame": 2.0, "track": 0}), BOUNDS)
    with pytest.raises(ValueError, match="track must be an integer"):
        check_annotation(annotation_from_dict({"kind": "mark_invalid", "view": "cam0", "frame": 2, "track": True}), BOUNDS)
    with pytest.raises(ValueError, match="view must be a string"):
        check_annotation(annotation_from_dict({"kind": "split_track", "view": 0, "frame": 2, "track": 0}), BOUNDS)


def test_unknown_parts_are_not_checked() -> None:
    unknown = AnnotationBounds()
    check_annotation(MarkInvalid("cam7", 500, 9), unknown)
    check_annotation(SwapIdentities(frame=10_000, person_a=0, person_b=5, frame_end=20_000), unknown)
    with pytest.raises(ValueError, match="frame -3 is outside the bout"):
        check_annotation(SwapIdentities(frame=-3, person_a=0, person_b=1), unknown)
    no_tracks = AnnotationBounds(n_frames=20, person_ids=(0, 1), cameras=("cam0", "cam1", "cam2"))
    check_annotation(MarkInvalid("cam0", 15, 1), no_tracks)
    with pytest.raises(ValueError, match="view 'cam7' is not a camera"):
        check_annotation(MarkInvalid("cam7", 15, 1), no_tracks)


def test_swap_without_frame_end_keeps_its_old_json() -> None:
    old = {"kind": "swap_identities", "frame": 3, "person_a": 0, "person_b": 1, "view": ""}
    assert annotation_to_dict(annotation_from_dict(old)) == old
    ranged = annotation_to_dict(SwapIdentities(frame=3, person_a=0, person_b=1, frame_end=9))
    assert ranged == {**old, "frame_end": 9}
    assert annotation_from_dict(ranged) == SwapIdentities(frame=3, person_a=0, person_b=1, frame_end=9)


@pytest.fixture(scope="module")
def tracked(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = write_tiny_session(tmp_path_factory.mktemp("bounds") / "s", stages=("detect2d", "track"), n_frames=20)
    run(folder)
    return folder


def test_session_bounds_before_and_after_track_edits(tracked: Path) -> None:
    b = annotation_bounds(tracked)
    assert b.n_frames == 20 and b.person_ids == (0, 1) and b.cameras is not None and b.tracks is not None
    assert b.image_size_wh is not None and b.image_size_wh.shape == (len(b.cameras), 2)
    view = b.cameras[0]
    ids = sorted(set(b.tracks.track_id[b.tracks.view == 0].tolist()) - {-1})
    new_id = max(ids) + 1
    with pytest.raises(ValueError, match=f"track {new_id} is not a track"):
        check_annotation(MarkInvalid(view, 15, new_id), b)
    assert annotation_bounds(tracked, extra_person_ids=[4]).person_ids == (0, 1, 4)
    # a pending split (not run yet) creates track new_id: an edit may name it at once
    split = SplitTrack(view=view, track=ids[0], frame=10)
    (tracked / "annotations.json").write_text(json.dumps([annotation_to_dict(split)]))
    b2 = annotation_bounds(tracked)
    assert b2.tracks is not None
    check_annotation(MarkInvalid(view, 15, new_id), b2)
    with pytest.raises(ValueError, match=f"track {ids[0]} of view '{view}' has no detection at frame 15"):
        check_annotation(MarkInvalid(view, 15, ids[0]), b2)
    # after the stage ran with the split, undoing it leaves the tracks unknown until a re-run
    run(tracked)
    assert annotation_bounds(tracked).tracks is not None
    (tracked / "annotations.json").write_text("[]")
    assert annotation_bounds(tracked).tracks is None
    run(tracked)
    b3 = annotation_bounds(tracked)
    assert b3.tracks is not None
    check_annotation(MarkInvalid(view, 15, ids[0]), b3)
