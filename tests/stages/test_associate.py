"""Association: identities across views under swaps, bystanders, missing views, re-entries, edits."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.evaluate.metrics import identity_accuracy
from pipeline.schema import AssignIdentity, MarkInvalid, SwapIdentities
from pipeline.stages.associate import AssociateConfig, run
from tests.stages.mv_fixtures import Scene, make_scene

TWO = AssociateConfig(n_persons=2)


def _subset(s: Scene, keep: np.ndarray) -> Scene:
    return dataclasses.replace(s, tracks=s.tracks.select(keep), gt_person_of_det=s.gt_person_of_det[keep])


def _mapped(pod: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Estimated ids renamed to the true ids (majority vote per estimated id)."""
    out = pod.copy()
    for e in np.unique(pod[pod >= 0]):
        vals = gt[(pod == e) & (gt >= 0)]
        out[pod == e] = np.bincount(vals).argmax() if vals.size else -1
    return out


def test_clean_two_boxers() -> None:
    s = make_scene(n_frames=40)
    a = run(s.tracks, s.rig, person_names=("Red", "Blue"))
    assert a.person_ids.tolist() == [0, 1] and a.person_names == ("Red", "Blue")
    assert identity_accuracy(a.person_of_det, s.gt_person_of_det) == 1.0
    assert (a.confidence >= 0).all() and (a.confidence <= 1).all() and a.confidence.mean() > 0.5


def test_the_athletes_list_sets_the_person_count() -> None:
    s = make_scene(n_frames=40, referee=True)
    two = run(s.tracks, s.rig, person_names=("Red", "Blue"))
    three = run(s.tracks, s.rig, person_names=("Red", "Blue", "Referee"))
    assert two.person_ids.tolist() == [0, 1] and three.person_ids.tolist() == [0, 1, 2]
    assert identity_accuracy(two.person_of_det, s.gt_person_of_det) == 1.0
    # The third person is the referee: every referee detection gets the one remaining id.
    ref = s.gt_person_of_det < 0
    assert np.unique(three.person_of_det[ref]).size == 1 and three.person_of_det[ref][0] >= 0
    assert three.person_names == ("Red", "Blue", "Referee")
    with pytest.raises(ValueError, match='"athletes".*n_persons'):
        run(s.tracks, s.rig, person_names=())


def test_auto_counts_persons_in_the_volume_and_not_bystanders_outside() -> None:
    inside = make_scene(n_frames=60, referee=True)
    a = run(inside.tracks, inside.rig, AssociateConfig(n_persons="auto"), person_names=("Red", "Blue"))
    assert a.person_ids.tolist() == [0, 1, 2]  # a referee inside the ring is a person to "auto"
    # A bystander walking outside the ring of cameras (radius 6 m) is seen by the cameras
    # on the far side (>= 2 views, the whole clip), yet is not a person.
    outside = make_scene(n_frames=60, referee=True, referee_radius_m=8.0)
    seen = np.unique(outside.tracks.view[outside.gt_person_of_det < 0])
    assert seen.size >= 2
    a = run(outside.tracks, outside.rig, AssociateConfig(n_persons="auto"), person_names=("Red", "Blue"))
    assert a.person_ids.tolist() == [0, 1]
    assert identity_accuracy(a.person_of_det, outside.gt_person_of_det) == 1.0
    # With a number, the bystander ranks after the persons inside the volume: the boxers
    # keep ids 0 and 1 and the third id goes to (part of) the bystander only.
    a = run(outside.tracks, outside.rig, AssociateConfig(n_persons=3))
    boxers = outside.gt_person_of_det >= 0
    assert identity_accuracy(a.person_of_det[boxers], outside.gt_person_of_det[boxers]) == 1.0
    assert (a.person_of_det[~boxers] == 2).any()


def test_one_camera_is_a_clear_error() -> None:
    s = make_scene(n_frames=5)
    one = s.rig.subset([0])
    keep = s.tracks.view == 0
    t = dataclasses.replace(s.tracks.select(keep), n_views=1)
    with pytest.raises(ValueError, match="1 camera.*at least 2"):
        run(t, one, TWO)


def test_referee_seen_by_every_camera_is_not_a_boxer() -> None:
    s = make_scene(n_frames=40, referee=True)
    a = run(s.tracks, s.rig, TWO)
    assert a.person_ids.tolist() == [0, 1]
    assert identity_accuracy(a.person_of_det, s.gt_person_of_det) == 1.0
    assert (a.person_of_det[s.gt_person_of_det < 0] == -1).all()


def test_bystander_in_some_views_only() -> None:
    s = make_scene(n_frames=40, referee=True)
    keep = (s.gt_person_of_det >= 0) | (s.tracks.view <= 1)
    s = _subset(s, keep)
    a = run(s.tracks, s.rig, TWO)
    assert identity_accuracy(a.person_of_det, s.gt_person_of_det) == 1.0


def test_per_view_id_swaps_are_overridden_by_geometry() -> None:
    swaps = ((1, 15), (2, 15), (3, 30))
    s = make_scene(n_frames=45, referee=True, swaps=swaps)
    a = run(s.tracks, s.rig, TWO)
    m = _mapped(a.person_of_det, s.gt_person_of_det)
    for v, f in swaps:
        sel = (s.tracks.view == v) & (s.tracks.frame >= f)
        assert (m[sel] == s.gt_person_of_det[sel]).all(), f"swap in view {v} at frame {f} not followed"
    assert identity_accuracy(a.person_of_det, s.gt_person_of_det) == 1.0


def test_camera_that_sees_nobody_and_missed_detections() -> None:
    s = make_scene(n_frames=50, referee=True, empty_views=(2,), miss_det=0.2, noise_px=3.0, seed=3)
    a = run(s.tracks, s.rig, TWO)
    assert identity_accuracy(a.person_of_det, s.gt_person_of_det) >= 0.99


def test_two_cameras() -> None:
    s = make_scene(n_views=2, n_frames=40)
    a = run(s.tracks, s.rig, TWO)
    assert identity_accuracy(a.person_of_det, s.gt_person_of_det) == 1.0


def test_leaving_and_reentering_one_view_with_a_new_track_id() -> None:
    s = make_scene(n_frames=60)
    gone = (s.tracks.view == 1) & (s.gt_person_of_det == 0) & (s.tracks.frame >= 15) & (s.tracks.frame < 35)
    s = _subset(s, ~gone)
    tid = s.tracks.track_id.copy()
    back = (s.tracks.view == 1) & (s.gt_person_of_det == 0) & (s.tracks.frame >= 35)
    tid[back] = 99  # the tracker gives the returning person a new id
    s = dataclasses.replace(s, tracks=dataclasses.replace(s.tracks, track_id=tid))
    a = run(s.tracks, s.rig, TWO)
    assert identity_accuracy(a.person_of_det, s.gt_person_of_det) == 1.0


def test_leaving_every_view_and_coming_back() -> None:
    s = make_scene(n_frames=100)
    gone = (s.gt_person_of_det == 1) & (s.tracks.frame >= 30) & (s.tracks.frame < 70)  # 0.8 s away
    s = _subset(s, ~gone)
    cfg = AssociateConfig(n_persons=2, max_missing_s=0.2)  # the 3D track ends, a new fragment starts
    a = run(s.tracks, s.rig, cfg)
    assert a.person_ids.tolist() == [0, 1]
    assert identity_accuracy(a.person_of_det, s.gt_person_of_det) == 1.0


def test_edits_override_the_automatic_result() -> None:
    s = make_scene(n_frames=30)
    auto = run(s.tracks, s.rig, TWO)
    t = s.tracks
    # Which automatic id does the first track of cam1 carry?
    tr = int(t.track_id[(t.view == 1)][0])
    pid = int(auto.person_of_det[(t.view == 1) & (t.track_id == tr)][0])
    other = 1 - pid
    # 1) Assign that track to the other athlete for frames 5..9: the other athlete's own
    #    detection in those frames of cam1 gives up the id.
    a = run(s.tracks, s.rig, TWO, edits=[AssignIdentity(view="cam1", track=tr, frame_start=5, frame_end=9, person=other)])
    seg = (t.view == 1) & (t.track_id == tr) & (t.frame >= 5) & (t.frame <= 9)
    assert (a.person_of_det[seg] == other).all() and (a.confidence[seg] == 1).all()
    clash = (t.view == 1) & (t.track_id != tr) & (t.frame >= 5) & (t.frame <= 9)
    assert (a.person_of_det[clash] == -1).all()
    rest = ~seg & ~clash
    assert (a.person_of_det[rest] == auto.person_of_det[rest]).all()
    # 2) Swap identities from frame 12 in cam2 only, then in every view.
    a = run(s.tracks, s.rig, TWO, edits=[SwapIdentities(frame=12, person_a=0, person_b=1, view="cam2")])
    late = (t.view == 2) & (t.frame >= 12)
    assert (a.person_of_det[late] == 1 - auto.person_of_det[late]).all()
    assert (a.person_of_det[~late] == auto.person_of_det[~late]).all()
    a = run(s.tracks, s.rig, TWO, edits=[SwapIdentities(frame=12, person_a=0, person_b=1)])
    late = t.frame >= 12
    assert (a.person_of_det[late] == 1 - auto.person_of_det[late]).all()
    # 3) A bystander assignment (-1) and a new person id 2.
    a = run(s.tracks, s.rig, TWO, edits=[AssignIdentity(view="cam0", track=int(t.track_id[t.view == 0][0]), frame_start=0, frame_end=100, person=2)])
    assert a.person_ids.tolist() == [0, 1, 2] and (a.person_of_det == 2).sum() == 30
    # Edits apply in order; other kinds are ignored.
    a = run(s.tracks, s.rig, TWO, edits=[MarkInvalid(view="cam0", frame=0, track=0)])
    assert (a.person_of_det == auto.person_of_det).all()
    with pytest.raises(ValueError, match="not in the rig"):
        run(s.tracks, s.rig, TWO, edits=[SwapIdentities(frame=0, person_a=0, person_b=1, view="nope")])


def test_rig_mismatch_raises() -> None:
    s = make_scene(n_frames=5)
    with pytest.raises(ValueError, match="views"):
        run(s.tracks, s.rig.subset([0, 1]), TWO)


def test_chunked_assignment_matches_per_frame() -> None:
    s = make_scene(n_frames=45, referee=True, swaps=((1, 15), (3, 30)), miss_det=0.1, seed=4)
    chunked = run(s.tracks, s.rig, AssociateConfig(n_persons=2, assign_chunk_s=0.1))
    per_frame = run(s.tracks, s.rig, AssociateConfig(n_persons=2, assign_chunk_s=0.0))
    assert identity_accuracy(chunked.person_of_det, s.gt_person_of_det) == 1.0
    assert identity_accuracy(per_frame.person_of_det, s.gt_person_of_det) == 1.0
