from pathlib import Path

import numpy as np
import pytest

from pipeline.artifacts import ArtifactStore, Manifest
from pipeline.schema import Association
from tests.webui.fixtures import build_session
from webui.scene.session_data import artifacts_stamp, frame_row, load_session_data


def test_loads_what_exists(tmp_path: Path) -> None:
    d = load_session_data(build_session(tmp_path, n_frames=8))
    assert d.n_frames == 8
    assert d.person_ids == [0, 1]
    assert set(d.keypoints) == {"filtered"}
    assert d.bodyfit is None and d.physics is None and d.physics_xml is None
    rows = d.det_rows(1, 3)
    assert rows.size == 2
    assert set(d.tracks.view[rows].tolist()) == {1} and set(d.tracks.frame[rows].tolist()) == {3}
    assert sorted(d.person_of_rows(rows).tolist()) == [0, 1]
    assert d.track_person(1, 11, 3) == 1
    assert d.track_person(1, 99, 3) == -1


def test_missing_stages_are_absent_not_errors(tmp_path: Path) -> None:
    sdir = build_session(tmp_path, n_frames=6)
    store = ArtifactStore(sdir)
    store.invalidate("associate")
    store.invalidate("triangulate")
    d = load_session_data(sdir)
    assert d.association is None and d.keypoints == {}
    assert d.tracks is not None and d.n_frames == 6
    # without an association every detection is unassigned
    assert d.person_of_rows(d.det_rows(0, 0)).tolist() == [-1, -1]


def test_association_not_matching_tracks_is_ignored(tmp_path: Path) -> None:
    sdir = build_session(tmp_path, n_frames=6)
    bad = Association(np.array([0, 1]), ("a", "b"), np.zeros(5, dtype=np.int64), np.ones(5))
    ArtifactStore(sdir).write(Manifest("associate", "t", {}, "0", {}), {"association": bad})
    assert load_session_data(sdir).association is None


def test_stamp_changes_when_a_stage_is_rewritten(tmp_path: Path) -> None:
    sdir = build_session(tmp_path, n_frames=6)
    before = artifacts_stamp(sdir)
    d = load_session_data(sdir)
    ArtifactStore(sdir).write(Manifest("associate", "t", {}, "0", {}), {"association": d.association})
    assert artifacts_stamp(sdir) != before


def test_frame_row(tmp_path: Path) -> None:
    kp = load_session_data(build_session(tmp_path, n_frames=6)).keypoints["filtered"]
    kp2 = kp.replace(frame_indices=np.array([0, 2, 4, 6, 8, 10]))
    assert frame_row(kp2, 4) == 2
    assert frame_row(kp2, 5) is None
    assert frame_row(kp2, 11) is None


def test_unreadable_session_raises(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="session.json"):
        load_session_data(tmp_path)
