"""Simulated 2D detections of the synthetic bout: projection, noise, occlusion, bystander,
track-id swaps, misses."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.geometry import project
from pipeline.synthetic import SyntheticBout, SyntheticConfig, make_bout
from pipeline.synthetic.render2d import SWAP_IOU


def _boxer_rows(bout: SyntheticBout) -> np.ndarray:
    return np.flatnonzero(bout.gt_person_of_det >= 0)


@pytest.mark.parametrize("distortion", [False, True])
def test_noise_free_detections_are_gt_projections(distortion: bool) -> None:
    bout = make_bout(SyntheticConfig(noise_px=0.0, n_frames=60, distortion=distortion, seed=2))
    if distortion:
        assert np.all((bout.rig.dist[:, 0] <= -0.1) & (bout.rig.dist[:, 0] >= -0.25))
    else:
        assert not np.any(bout.rig.dist)
    uv, _ = project(bout.rig, bout.gt.xyz_m)  # (V, F, P, J, 2)
    rows = _boxer_rows(bout)
    tr = bout.tracks
    pred = uv[tr.view[rows], tr.frame[rows], bout.gt_person_of_det[rows]]
    valid = tr.keypoint_valid[rows]
    assert valid.sum() > 1000
    np.testing.assert_allclose(tr.keypoints_px[rows][valid], pred[valid], atol=1e-6)
    np.testing.assert_allclose(bout.clean_keypoints_px[rows][valid], pred[valid], atol=1e-9)


def test_noise_level_and_confidence(default_bout: SyntheticBout) -> None:
    tr, b = default_bout.tracks, default_bout
    vis = tr.keypoint_valid & ~b.occluded
    err = (tr.keypoints_px - b.clean_keypoints_px)[vis]
    assert err.std() == pytest.approx(3.0, rel=0.1)
    assert np.abs(err.mean()) < 0.2
    conf = tr.keypoint_conf
    assert conf[vis].min() >= 0.75 and conf[vis].max() <= 1.0
    # Bigger errors get lower confidence.
    en = np.linalg.norm(err, axis=1)
    assert conf[vis][en > 6].mean() < conf[vis][en < 2].mean()


def test_occlusion_lowers_confidence(default_bout: SyntheticBout) -> None:
    tr, occ = default_bout.tracks, default_bout.occluded
    frac = occ.mean()
    assert 0.05 < frac < 0.6, frac
    occ_valid = occ & tr.keypoint_valid
    assert occ_valid.sum() > 100
    assert tr.keypoint_conf[occ_valid].max() < 0.3
    # Some occluded joints are dropped entirely.
    assert (occ & ~tr.keypoint_valid).sum() > 100
    # Invalid entries carry no confidence.
    assert np.all(tr.keypoint_conf[~tr.keypoint_valid] == 0.0)


def test_valid_keypoints_inside_image_and_boxes(default_bout: SyntheticBout) -> None:
    tr, rig = default_bout.tracks, default_bout.rig
    wh = rig.image_size_wh[tr.view].astype(float)
    clean = default_bout.clean_keypoints_px
    v = tr.keypoint_valid
    inside = (
        (clean >= 0).all(-1) & (clean[..., 0] <= wh[:, None, 0] - 1) & (clean[..., 1] <= wh[:, None, 1] - 1)
    )
    assert inside[v].all()
    # Some joints leave the image (feet/heads near the border) and are invalid there.
    assert (~v).any()
    bb = tr.bbox_xyxy_px
    kp = tr.keypoints_px
    assert np.all(bb[:, 2] > bb[:, 0]) and np.all(bb[:, 3] > bb[:, 1])
    in_box = (kp[..., 0] >= bb[:, None, 0] - 1e-9) & (kp[..., 0] <= bb[:, None, 2] + 1e-9)
    in_box &= (kp[..., 1] >= bb[:, None, 1] - 1e-9) & (kp[..., 1] <= bb[:, None, 3] + 1e-9)
    inside_img = (
        (kp[..., 0] >= 0)
        & (kp[..., 1] >= 0)
        & (kp[..., 0] <= wh[:, None, 0] - 1)
        & (kp[..., 1] <= wh[:, None, 1] - 1)
    )
    assert in_box[v & inside_img].all()
    assert np.all((tr.bbox_score > 0) & (tr.bbox_score <= 1))


def test_bystander_seen_by_some_cameras_only(default_bout: SyntheticBout) -> None:
    tr, who = default_bout.tracks, default_bout.gt_person_of_det
    views = np.unique(tr.view[who == -1])
    assert 1 <= views.size < tr.n_views
    for v in views:
        ids_by = np.unique(tr.track_id[(who == -1) & (tr.view == v)])
        ids_boxers = np.unique(tr.track_id[(who >= 0) & (tr.view == v)])
        assert ids_by.size == 1 and ids_by[0] not in ids_boxers
    # Eight cameras: still not all of them see it.
    b8 = make_bout(SyntheticConfig(n_cameras=8, n_frames=40))
    v8 = np.unique(b8.tracks.view[b8.gt_person_of_det == -1])
    assert 1 <= v8.size < 8
    none = make_bout(SyntheticConfig(bystander=False, n_frames=40))
    assert np.all(none.gt_person_of_det >= 0)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def test_injected_id_swap(default_bout: SyntheticBout) -> None:
    tr, who, swaps = default_bout.tracks, default_bout.gt_person_of_det, default_bout.swap_frames
    assert swaps.shape[1] == 2 and len(swaps) >= 1
    swapped_views = set(swaps[:, 0].tolist())
    for v, f0 in swaps:
        r0 = np.flatnonzero((tr.view == v) & (tr.frame == f0) & (who == 0))
        r1 = np.flatnonzero((tr.view == v) & (tr.frame == f0) & (who == 1))
        assert r0.size == 1 and r1.size == 1
        assert _iou(tr.bbox_xyxy_px[r0[0]], tr.bbox_xyxy_px[r1[0]]) >= SWAP_IOU
        for p in (0, 1):
            before = np.unique(tr.track_id[(tr.view == v) & (tr.frame < f0) & (who == p)])
            after = np.unique(tr.track_id[(tr.view == v) & (tr.frame >= f0) & (who == p)])
            other_before = np.unique(tr.track_id[(tr.view == v) & (tr.frame < f0) & (who == 1 - p)])
            assert before.size == 1 and after.size == 1
            assert after[0] == other_before[0]
    # Views without an injected swap keep one id per person.
    for v in set(range(tr.n_views)) - swapped_views:
        for p in (-1, 0, 1):
            assert np.unique(tr.track_id[(tr.view == v) & (who == p)]).size <= 1


def test_no_swaps_when_disabled() -> None:
    bout = make_bout(SyntheticConfig(id_swaps=False, n_frames=150))
    assert bout.swap_frames.shape == (0, 2)
    tr, who = bout.tracks, bout.gt_person_of_det
    for v in range(tr.n_views):
        ids = [np.unique(tr.track_id[(tr.view == v) & (who == p)]) for p in (0, 1)]
        assert ids[0].size == 1 and ids[1].size == 1 and ids[0][0] != ids[1][0]


def test_missed_detections_follow_miss_rate() -> None:
    kw = dict(n_frames=100, bystander=False, id_swaps=False)
    full = make_bout(SyntheticConfig(miss_rate=0.0, **kw)).tracks.n_dets
    some = make_bout(SyntheticConfig(miss_rate=0.2, **kw)).tracks.n_dets
    assert some / full == pytest.approx(0.8, abs=0.05)


def test_gt_n_views_counts_unoccluded_views(default_bout: SyntheticBout) -> None:
    nv = default_bout.gt.n_views
    assert nv.min() >= 0 and nv.max() <= default_bout.rig.n_views
    assert (nv >= 2).mean() > 0.7


def _point_segment_dist(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def test_segment_distance_matches_dense_sampling() -> None:
    from pipeline.synthetic.occlusion import _segment_segment_dist

    rng = np.random.default_rng(0)
    p1, q1, p2 = rng.normal(size=(3, 200, 3))
    q2 = np.where(rng.random((200, 1)) < 0.2, p2, rng.normal(size=(200, 3)))  # some spheres
    fast = _segment_segment_dist(p1, q1, p2, q2)
    s = np.linspace(0.0, 1.0, 2001)[:, None, None]
    pts = p1 + s * (q1 - p1)  # (S, 200, 3) dense samples of the first segment
    slow = _point_segment_dist(pts, p2, q2).min(axis=0)
    assert np.all(fast <= slow + 1e-12)
    np.testing.assert_allclose(fast, slow, atol=2e-3)


def test_occlusion_cull_matches_brute_force() -> None:
    """The culled ray/capsule test equals testing every (joint, capsule) pair."""
    from pipeline.synthetic.bout import BYSTANDER_HEIGHT_M
    from pipeline.synthetic.occlusion import RAY_MARGIN_M, _segment_segment_dist, capsules, occluded
    from pipeline.synthetic.skeleton import BodyDims, make_body

    bout = make_bout(SyntheticConfig(n_frames=30, seed=4))
    xyz = np.concatenate([bout.gt.xyz_m, bout.bystander_xyz_m[:, None]], axis=1)
    # Body volumes only need the segment dimensions: the boxers' are recorded in the bout.
    bodies = [BodyDims(**bout.limb_lengths_m[p]) for p in (0, 1)]
    bodies.append(make_body(BYSTANDER_HEIGHT_M, 1.0, np.random.default_rng(0)))
    caps = [capsules(xyz[:, p], bodies[p]) for p in range(3)]
    ends = np.concatenate([c[0] for c in caps], axis=1)
    radii = np.concatenate([c[1] for c in caps])
    joints = xyz.reshape(xyz.shape[0], -1, 3)
    fast = occluded(bout.rig.centers_world_m, joints, ends, radii, chunk_pairs=997)
    # Brute force: every (joint, capsule) pair, no cull.
    a, b = ends[:, None, :, 0], ends[:, None, :, 1]
    inside = _point_segment_dist(joints[:, :, None], a, b) < radii + 0.005
    for v, c in enumerate(bout.rig.centers_world_m):
        ray = joints - c
        end = joints - RAY_MARGIN_M * ray / np.linalg.norm(ray, axis=-1, keepdims=True)
        d = _segment_segment_dist(c[None, None, None], end[:, :, None], a, b)
        slow = ((d < radii) & ~inside).any(-1)
        np.testing.assert_array_equal(fast[v], slow)
    assert fast.any() and not fast.all()
