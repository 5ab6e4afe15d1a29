"""Small multi-view fixtures built in code: a ring rig, two boxers (+ a referee), 2D tracks.

Used by the associate / triangulate / filtering tests (fixed seeds, a few dozen frames).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry import project
from pipeline.geometry.rotations import look_at_T_world_cam
from pipeline.schema import COCO17, CameraRig, Keypoints3D, Tracks2D

# Standing boxer in guard, person frame: x = person's right, y = forward, z = up (metres).
TEMPLATE = np.array(
    [
        [0.00, 0.10, 1.62],
        [-0.03, 0.08, 1.66],
        [0.03, 0.08, 1.66],
        [-0.07, 0.00, 1.64],
        [0.07, 0.00, 1.64],
        [-0.19, 0.00, 1.45],
        [0.19, 0.00, 1.45],
        [-0.25, 0.15, 1.20],
        [0.25, 0.15, 1.20],
        [-0.15, 0.35, 1.40],
        [0.15, 0.35, 1.40],
        [-0.10, 0.00, 0.95],
        [0.10, 0.00, 0.95],
        [-0.12, 0.05, 0.50],
        [0.12, 0.05, 0.50],
        [-0.13, 0.00, 0.08],
        [0.13, 0.00, 0.08],
    ]
)


def make_rig(n_views: int = 4, radius_m: float = 6.0, dist_k1: float = -0.05, fps: float = 50.0) -> CameraRig:
    """Cameras on a circle around the ring, 2.5 m high, looking at the centre."""
    T, K, D = [], [], []
    for v in range(n_views):
        a = 2 * np.pi * v / n_views + 0.3
        eye = np.array([radius_m * np.cos(a), radius_m * np.sin(a), 2.5 + 0.3 * (v % 2)])
        T.append(look_at_T_world_cam(eye, np.array([0.0, 0.0, 1.0])))
        K.append([[1000.0 + 50 * v, 0, 960], [0, 1000.0 + 50 * v, 540], [0, 0, 1]])
        D.append([dist_k1 * (v % 2), 0.01 * (v % 2), 0, 0, 0])
    return CameraRig(
        names=tuple(f"cam{v}" for v in range(n_views)),
        K=np.array(K),
        dist=np.array(D),
        T_world_cam=np.array(T),
        image_size_wh=np.tile([1920, 1080], (n_views, 1)),
        fps=fps,
    )


def _pose(root: np.ndarray, heading: float, t: float, phase: float) -> np.ndarray:
    J = TEMPLATE.copy()
    punch = max(0.0, np.sin(3.0 * t + phase)) ** 4
    J[10, 1] += 0.35 * punch  # right wrist jab
    J[8, 1] += 0.15 * punch
    J[:, 2] += 0.03 * np.sin(5.0 * t + phase)
    c, s = np.cos(heading), np.sin(heading)
    # person frame -> world: y (forward) along the heading direction.
    R = np.array([[s, c, 0], [-c, s, 0], [0, 0, 1]])
    return J @ R.T + root


def make_motion(n_frames: int, fps: float, referee: bool, referee_radius_m: float = 2.4) -> np.ndarray:
    """(frames, persons, 17, 3) world joints: two boxers circling each other (+ a referee
    walking a circle of ``referee_radius_m`` around the ring centre)."""
    n_p = 3 if referee else 2
    out = np.zeros((n_frames, n_p, 17, 3))
    for f in range(n_frames):
        t = f / fps
        phi = 0.6 * t
        centre = np.array([0.3 * np.sin(0.2 * t), 0.2 * np.cos(0.25 * t), 0.0])
        d = np.array([np.cos(phi), np.sin(phi), 0.0])
        for p, sgn in enumerate((1.0, -1.0)):
            root = centre + sgn * 0.9 * d
            heading = np.arctan2(-sgn * d[1], -sgn * d[0])
            out[f, p] = _pose(root, heading, t, phase=1.3 * p)
        if referee:
            a = 0.1 * t + 2.0
            root = np.array([referee_radius_m * np.cos(a), referee_radius_m * np.sin(a), 0.0])
            out[f, 2] = _pose(root, np.arctan2(-root[1], -root[0]), t, phase=0.5)
    return out


@dataclass
class Scene:
    rig: CameraRig
    tracks: Tracks2D
    gt_xyz: np.ndarray  # (frames, persons, 17, 3), boxers first
    gt_person_of_det: np.ndarray  # (dets,) 0/1 boxers, -1 referee

    def gt_keypoints(self) -> Keypoints3D:
        f, p = self.gt_xyz.shape[:2]
        return Keypoints3D(
            joint_names=COCO17,
            person_ids=np.arange(2),
            frame_indices=np.arange(f),
            fps=self.rig.fps,
            xyz_m=self.gt_xyz[:, :2].copy(),
            valid=np.ones((f, 2, 17), bool),
            confidence=np.ones((f, 2, 17)),
            n_views=np.zeros((f, 2, 17), np.int64),
            reproj_err_px=np.full((f, 2, 17), np.nan),
            source="gt",
        )


def make_scene(
    n_views: int = 4,
    n_frames: int = 40,
    noise_px: float = 2.0,
    miss_det: float = 0.0,
    miss_joint: float = 0.02,
    referee: bool = False,
    referee_radius_m: float = 2.4,
    swaps: tuple[tuple[int, int], ...] = (),
    empty_views: tuple[int, ...] = (),
    seed: int = 0,
    fps: float = 50.0,
) -> Scene:
    """Project the motion into a ring rig and build flat ``Tracks2D`` rows.

    ``swaps``: (view, frame) pairs where the per-view track ids of the two boxers swap
    from that frame on. ``empty_views``: cameras that see nobody. ``referee_radius_m``
    beyond the ring of cameras (6 m) puts the referee outside the capture volume.
    """
    rng = np.random.default_rng(seed)
    rig = make_rig(n_views, fps=fps)
    X = make_motion(n_frames, fps, referee, referee_radius_m)
    uv, depth = project(rig, X)  # (views, frames, persons, joints, 2)
    rows: dict[str, list] = {k: [] for k in ("view", "frame", "bbox", "score", "kp", "conf", "valid", "tid", "gt")}
    n_p = X.shape[1]
    for v in range(n_views):
        if v in empty_views:
            continue
        tid = {p: 10 * v + p for p in range(n_p)}
        for f in range(n_frames):
            for vs, fs in swaps:
                if vs == v and fs == f:
                    tid[0], tid[1] = tid[1], tid[0]
            for p in range(n_p):
                if rng.random() < miss_det:
                    continue
                kp = uv[v, f, p] + rng.normal(0, noise_px, (17, 2))
                w, h = rig.image_size_wh[v]
                valid = (depth[v, f, p] > 0) & (kp[:, 0] >= 0) & (kp[:, 0] < w) & (kp[:, 1] >= 0) & (kp[:, 1] < h)
                valid &= rng.random(17) >= miss_joint
                if valid.sum() < 5:
                    continue
                lo, hi = kp[valid].min(0), kp[valid].max(0)
                m = 0.1 * (hi - lo)
                rows["view"].append(v)
                rows["frame"].append(f)
                rows["bbox"].append(np.r_[lo - m, hi + m])
                rows["score"].append(0.9)
                rows["kp"].append(kp)
                rows["conf"].append(np.where(valid, rng.uniform(0.5, 1.0, 17), 0.0))
                rows["valid"].append(valid)
                rows["tid"].append(tid[p])
                rows["gt"].append(p if p < 2 else -1)
    tracks = Tracks2D(
        joint_names=COCO17,
        n_views=n_views,
        n_frames=n_frames,
        view=np.array(rows["view"], np.int64),
        frame=np.array(rows["frame"], np.int64),
        bbox_xyxy_px=np.array(rows["bbox"], float).reshape(-1, 4),
        bbox_score=np.array(rows["score"], float),
        keypoints_px=np.array(rows["kp"], float).reshape(-1, 17, 2),
        keypoint_conf=np.array(rows["conf"], float).reshape(-1, 17),
        keypoint_valid=np.array(rows["valid"], bool).reshape(-1, 17),
        track_id=np.array(rows["tid"], np.int64),
    )
    return Scene(rig=rig, tracks=tracks, gt_xyz=X[:, :2].copy(), gt_person_of_det=np.array(rows["gt"], np.int64))
