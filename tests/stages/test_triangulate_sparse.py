"""An athlete the cameras hardly ever saw together is named in a warning, with the frame count."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.artifacts import ArtifactStore
from pipeline.runner import run
from pipeline.schema.joints import COCO17_FEET
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.stages.triangulate import FEW_FRAMES_PCT, person_frames_pct, sparse_persons
from tests.conftest import write_tiny_session


def _kp(frames_seen: list[int], n_frames: int = 20) -> Keypoints3D:
    p, j = len(frames_seen), len(COCO17_FEET)
    valid = np.zeros((n_frames, p, j), bool)
    for i, k in enumerate(frames_seen):
        valid[:k, i, :5] = True  # a few joints are enough for the frame to count
    return Keypoints3D(
        joint_names=COCO17_FEET, person_ids=np.arange(p), frame_indices=np.arange(n_frames), fps=50.0,
        xyz_m=np.zeros((n_frames, p, j, 3)), valid=valid, confidence=valid.astype(float),
        n_views=valid.astype(int) * 2, reproj_err_px=np.zeros((n_frames, p, j)), source="filtered",
    )  # fmt: skip


def test_person_frames_pct_counts_frames_with_any_joint() -> None:
    assert person_frames_pct(_kp([20, 5, 0])).tolist() == [100.0, 25.0, 0.0]


def test_only_athletes_under_the_threshold_are_named() -> None:
    assert FEW_FRAMES_PCT == 25.0
    msgs = sparse_persons(_kp([20, 5, 4, 0]), {0: "Red", 1: "Blue", 2: "Green"})
    assert len(msgs) == 2  # 25 % is not under the threshold; 20 % and 0 % are
    assert msgs[0].startswith("Green (person 2) has 3D in 4 of 20 frames: fewer than two cameras")
    assert msgs[1].startswith("person 3 has 3D in 0 of 20 frames")  # no name: an extra identity
    assert sparse_persons(_kp([20, 20]), {0: "Red", 1: "Blue"}) == []


def test_the_manifest_reports_the_least_seen_athlete(tmp_path: Path) -> None:
    s = write_tiny_session(tmp_path / "s", stages=("detect2d", "track", "associate", "triangulate"))
    run(s)
    store = ArtifactStore(s)
    m = store.manifest("triangulate")
    kp = store.load("triangulate", "keypoints3d", Keypoints3D)
    assert m is not None and m.metrics["person_frames_min_pct"] == round(float(person_frames_pct(kp).min()), 1)
    assert 0.0 < m.metrics["person_frames_min_pct"] <= 100.0
