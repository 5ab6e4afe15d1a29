"""Validation at construction and npz round trips of the typed data model."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from pipeline.schema import (
    COCO17,
    Association,
    CameraRig,
    Keypoints3D,
    SessionConfig,
    SwapIdentities,
    Tracks2D,
    annotation_from_dict,
    annotation_to_dict,
    annotations_hash,
    load_annotations,
    load_npz,
    save_npz,
)
from tests.conftest import make_rig, make_tracks


def test_rig_round_trip_and_projection_matrix(tmp_path: Path) -> None:
    rig = make_rig(4)
    save_npz(tmp_path / "rig.npz", rig)
    back = load_npz(tmp_path / "rig.npz", CameraRig)
    assert back.names == rig.names
    np.testing.assert_allclose(back.T_world_cam, rig.T_world_cam)
    # P maps each camera centre to the null space.
    C = np.concatenate([rig.centers_world_m, np.ones((4, 1))], axis=1)
    assert np.abs(np.einsum("vij,vj->vi", rig.P, C)).max() < 1e-9


def test_a_truncated_or_corrupt_npz_is_a_clear_error_naming_the_file(tmp_path: Path) -> None:
    from pipeline.schema.base import load_npz_scalar

    save_npz(tmp_path / "rig.npz", make_rig(2))
    data = (tmp_path / "rig.npz").read_bytes()
    for name, content in (("cut.npz", data[: len(data) // 3]), ("junk.npz", b"not an npz"), ("empty.npz", b"")):
        (tmp_path / name).write_bytes(content)
        with pytest.raises(ValueError, match=f"{name}: cannot read npz"):
            load_npz(tmp_path / name, CameraRig)
        with pytest.raises(ValueError, match=f"{name}: cannot read npz"):
            load_npz_scalar(tmp_path / name, "fps")


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(K=np.zeros((2, 3, 3))), "expected shape"),
        (dict(fps=-1.0), "fps must be positive"),
        (dict(names=("a", "a", "b")), "unique"),
        (dict(dist=np.full((3, 5), np.nan)), "NaN"),
    ],
)
def test_rig_validation_errors(change: dict, message: str) -> None:
    rig = make_rig(3)
    kw = dict(rig.__dict__)
    kw.update(change)
    with pytest.raises(ValueError, match=message):
        CameraRig(**kw)


def test_rig_rejects_improper_rotation() -> None:
    rig = make_rig(3)
    T = rig.T_world_cam.copy()
    T[1, :3, 0] *= -1  # a reflection
    with pytest.raises(ValueError, match="cam2"):
        dataclasses.replace(rig, T_world_cam=T)


def test_tracks_validation_and_round_trip(tmp_path: Path) -> None:
    rig = make_rig(3)
    tracks, _ = make_tracks(rig, n_frames=5)
    save_npz(tmp_path / "t.npz", tracks)
    back = load_npz(tmp_path / "t.npz", Tracks2D)
    np.testing.assert_array_equal(back.track_id, tracks.track_id)
    assert back.joint_names == COCO17
    kw = dict(tracks.__dict__)
    kw["track_id"] = np.zeros_like(tracks.track_id)  # both persons share id 0 in a frame
    with pytest.raises(ValueError, match="appears twice"):
        Tracks2D(**kw)
    kw = dict(tracks.__dict__)
    kp = tracks.keypoints_px.copy()
    kp[0, 0] = np.nan  # NaN at a valid joint
    kw["keypoints_px"] = kp
    with pytest.raises(ValueError, match="NaN"):
        Tracks2D(**kw)
    kw["keypoint_valid"] = tracks.keypoint_valid.copy()
    kw["keypoint_valid"][0, 0] = False  # NaN at an invalid joint is fine
    Tracks2D(**kw)


def test_keypoints3d_empty_and_validation() -> None:
    kp = Keypoints3D.empty(COCO17, np.array([0, 1]), np.arange(4), 50.0, "filtered")
    assert kp.xyz_m.shape == (4, 2, 17, 3) and not kp.valid.any()
    with pytest.raises(ValueError, match="source"):
        kp.replace(source="magic")
    with pytest.raises(ValueError, match="strictly increasing"):
        kp.replace(frame_indices=np.array([0, 2, 1, 3]))
    # Artifacts written before the result names were unified call the raw result "triangulation".
    assert kp.replace(source="triangulation").source == "raw"


@pytest.mark.parametrize("bad", [np.nan, np.inf, -0.1, 1.5])
def test_keypoints3d_rejects_a_valid_joint_whose_confidence_is_not_in_0_1(tmp_path: Path, bad: float) -> None:
    kp = Keypoints3D.empty(COCO17, np.array([0, 1]), np.arange(4), 50.0, "filtered")
    valid = kp.valid.copy()
    valid[2, 1, 5] = True
    conf = np.zeros_like(kp.confidence)
    conf[0, 0, 0] = bad  # an invalid joint may hold anything
    ok = kp.replace(valid=valid, confidence=conf)
    conf[2, 1, 5] = bad
    with pytest.raises(ValueError, match=r"Keypoints3D.confidence: 1 entries .* index \(2, 1, 5\)"):
        kp.replace(valid=valid, confidence=conf)
    # A stored artifact with such a confidence is an error naming the file.
    path = tmp_path / "keypoints3d.npz"
    save_npz(path, ok)
    with np.load(path) as z:
        arrays = dict(z)
    arrays["confidence"] = conf
    np.savez(path, **arrays)
    with pytest.raises(ValueError, match=re.escape(f"{path}: invalid Keypoints3D: Keypoints3D.confidence")):
        load_npz(path, Keypoints3D)


def test_association_rejects_unknown_ids() -> None:
    with pytest.raises(ValueError, match="not in person_ids"):
        Association(np.array([0, 1]), ("A", "B"), np.array([0, 2, -1]), np.array([1.0, 1.0, 0.0]))
    a = Association(np.array([0, 1]), ("A", "B"), np.array([0, 1, 0, 1]), np.ones(4))
    spans = a.spans(np.array([0, 0, 0, 0]), np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1]))
    assert spans == [
        {"view": 0, "track": 0, "person": 0, "frame_start": 0, "frame_end": 1},
        {"view": 0, "track": 1, "person": 1, "frame_start": 0, "frame_end": 1},
    ]


def test_annotations_json_and_hash(tmp_path: Path) -> None:
    a = SwapIdentities(frame=10, person_a=0, person_b=1, view="cam2")
    d = annotation_to_dict(a)
    assert annotation_from_dict(d) == a
    assert annotations_hash([a]) != annotations_hash([])
    with pytest.raises(ValueError, match="unknown annotation kind"):
        annotation_from_dict({"kind": "teleport"})
    with pytest.raises(ValueError, match="missing fields"):
        annotation_from_dict({"kind": "swap_identities", "frame": 3})
    bad = tmp_path / "annotations.json"
    bad.write_text("[{")
    with pytest.raises(ValueError, match="annotations.json: malformed JSON"):
        load_annotations(bad)


def test_session_config_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no session.json"):
        SessionConfig.load(tmp_path)
    (tmp_path / "session.json").write_text('{"name": "x", "source": "video", "calibration": "c.toml"}')
    with pytest.raises(ValueError, match="non-empty 'videos'"):
        SessionConfig.load(tmp_path)
    (tmp_path / "session.json").write_text('{"name": "x", "source": "tracks", "calibration": "c", "tracks": "t", "oops": 1}')
    with pytest.raises(ValueError, match="unknown keys"):
        SessionConfig.load(tmp_path)
    (tmp_path / "session.json").write_text('{"name": "x", "source": "tracks", "calibration": "c", "tracks": "t", "stage_config": [1, 2]}')
    with pytest.raises(ValueError, match=r"session\.stage_config must be an object of per-stage settings .*got list"):
        SessionConfig.load(tmp_path)
