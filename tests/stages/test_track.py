from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.schema import COCO17
from pipeline.schema.detections import Detections2D
from pipeline.stages.track import TrackConfig, iou_matrix, limb_embedding, run
from tests.conftest import make_rig

# A standing COCO-17 skeleton in box-height units (x right, y down, feet at y = 1).
_TEMPLATE = np.array(
    [
        [0.0, 0.06], [-0.02, 0.04], [0.02, 0.04], [-0.05, 0.05], [0.05, 0.05],  # head
        [-0.12, 0.18], [0.12, 0.18], [-0.15, 0.36], [0.15, 0.36], [-0.16, 0.52], [0.16, 0.52],  # arms
        [-0.08, 0.52], [0.08, 0.52], [-0.09, 0.75], [0.09, 0.75], [-0.09, 0.98], [0.09, 0.98],  # legs
    ]
)  # fmt: skip


def _person(cx: float, height: float, arm: float, leg: float) -> np.ndarray:
    s = _TEMPLATE.copy()
    s[7:11, 1] = 0.18 + (s[7:11, 1] - 0.18) * arm  # longer/shorter arms
    s[7:11, 0] *= arm
    s[13:17, 1] = 0.52 + (s[13:17, 1] - 0.52) * leg
    return s * height + np.array([cx, 100.0])


def _dets(people: list[list[np.ndarray | None]], n_views: int = 1) -> Detections2D:
    """people[frame] = list of (17, 2) keypoint arrays (None = not detected)."""
    view, frame, kps = [], [], []
    for f, plist in enumerate(people):
        for kp in plist:
            if kp is not None:
                view.append(0)
                frame.append(f)
                kps.append(kp)
    kp = np.stack(kps)
    box = np.concatenate([kp.min(axis=1) - 10, kp.max(axis=1) + 10], axis=1)
    n = len(kps)
    return Detections2D(
        joint_names=COCO17,
        n_views=n_views,
        n_frames=len(people),
        view=np.array(view),
        frame=np.array(frame),
        bbox_xyxy_px=box,
        bbox_score=np.full(n, 0.9),
        keypoints_px=kp,
        keypoint_conf=np.full((n, 17), 0.9),
        keypoint_valid=np.ones((n, 17), bool),
    )


def test_crossing_with_occlusion_keeps_ids() -> None:
    """Two athletes walk through each other; the one behind is hidden for 0.6 s."""
    rng = np.random.default_rng(0)
    fps, F = 50.0, 120
    rig = dataclasses.replace(make_rig(1), fps=fps)
    people: list[list[np.ndarray | None]] = []
    truth: list[list[int]] = []
    for f in range(F):
        xa = 200 + 6.0 * f  # A: left → right
        xb = 900 - 6.0 * f  # B: right → left (crosses A around f = 58)
        a = _person(xa, 400, arm=1.25, leg=0.8) + rng.normal(0, 1.5, (17, 2))
        b = _person(xb, 400, arm=0.8, leg=1.2) + rng.normal(0, 1.5, (17, 2))
        hidden = 45 <= f < 75  # B is behind A
        people.append([a] if hidden else [b, a])
        truth.append([0] if hidden else [1, 0])
    dets = _dets(people)
    tracks = run(dets, rig, TrackConfig())
    who = np.concatenate([np.array(t) for t in truth])
    ids_a = np.unique(tracks.track_id[who == 0])
    ids_b = np.unique(tracks.track_id[who == 1])
    assert ids_a.size == 1 and ids_b.size == 1, (ids_a, ids_b)
    assert ids_a[0] != ids_b[0] and ids_a[0] >= 0 and ids_b[0] >= 0


def test_bystander_and_spurious_detection() -> None:
    """A still bystander keeps its own id; a 2-frame false positive is not a track."""
    rig = make_rig(1)
    people = []
    for f in range(30):
        plist: list[np.ndarray | None] = [_person(300 + 2 * f, 400, 1, 1), _person(1100, 200, 1, 1)]
        if f in (10, 11):
            plist.append(_person(700, 150, 1.3, 0.7))
        people.append(plist)
    tracks = run(_dets(people), rig, TrackConfig(min_track_len=5))
    spurious = tracks.track_id[tracks.keypoints_px[:, 0, 0] > 650]
    spurious = spurious[np.abs(tracks.keypoints_px[tracks.keypoints_px[:, 0, 0] > 650][:, 0, 0] - 700) < 1]
    assert np.all(spurious == -1)
    tid = tracks.track_id[tracks.track_id >= 0]
    assert set(np.unique(tid).tolist()) == {0, 1}


def test_embedding_is_scale_invariant_and_discriminative() -> None:
    limbs = [
        (5, 6),
        (11, 12),
        (5, 11),
        (6, 12),
        (5, 7),
        (6, 8),
        (7, 9),
        (8, 10),
        (11, 13),
        (12, 14),
        (13, 15),
        (14, 16),
    ]
    ok = np.ones(17, bool)
    a1, _ = limb_embedding(_person(0, 300, 1.25, 0.8), ok, limbs)
    a2, _ = limb_embedding(_person(500, 600, 1.25, 0.8), ok, limbs)
    b, _ = limb_embedding(_person(0, 300, 0.8, 1.2), ok, limbs)
    assert np.abs(a1 - a2).mean() < 1e-9
    assert np.abs(a1 - b).mean() > 0.05


def test_iou_and_view_mismatch() -> None:
    a = np.array([[0, 0, 10, 10.0]])
    assert iou_matrix(a, np.array([[5, 0, 15, 10.0]]))[0, 0] == pytest.approx(1 / 3)
    dets = _dets([[_person(100, 300, 1, 1)]], n_views=2)
    with pytest.raises(ValueError, match="views"):
        run(dets, make_rig(3))
