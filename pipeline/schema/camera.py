"""Calibrated multi-camera rig."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.schema.base import check_array


@dataclass(frozen=True)
class CameraRig:
    """A synchronised, calibrated rig of ``views`` pinhole cameras.

    Conventions: world in metres, z-up, right-handed. Camera frame is OpenCV's
    (x right, y down, z forward). ``T_world_cam`` maps camera coordinates to world
    coordinates (its translation column is the camera centre in the world).

    Fields:
        names: camera names, unique, one per view.
        K: (views, 3, 3) intrinsics, OpenCV convention, pixels.
        dist: (views, 5) OpenCV distortion ``k1 k2 p1 p2 k3`` (zeros = none).
        T_world_cam: (views, 4, 4) rigid camera-to-world transforms.
        image_size_wh: (views, 2) integer image width and height in pixels.
        fps: frames per second shared by the rig (frames are synchronised).
        time_offset_s: (views,) start time of each camera relative to the rig
            clock; a frame ``f`` of view ``v`` was captured at ``f/fps + offset``.
    """

    names: tuple[str, ...]
    K: np.ndarray
    dist: np.ndarray
    T_world_cam: np.ndarray
    image_size_wh: np.ndarray
    fps: float
    time_offset_s: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        v = len(self.names)
        if v == 0:
            raise ValueError("CameraRig: needs at least one camera")
        if len(set(self.names)) != v:
            raise ValueError(f"CameraRig: camera names must be unique, got {self.names}")
        check_array("CameraRig.K", self.K, (v, 3, 3), "f", finite=True)
        check_array("CameraRig.dist", self.dist, (v, 5), "f", finite=True)
        check_array("CameraRig.T_world_cam", self.T_world_cam, (v, 4, 4), "f", finite=True)
        check_array("CameraRig.image_size_wh", self.image_size_wh, (v, 2), "iu")
        if self.time_offset_s.size == 0:
            object.__setattr__(self, "time_offset_s", np.zeros(v))
        check_array("CameraRig.time_offset_s", self.time_offset_s, (v,), "f", finite=True)
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"CameraRig.fps must be positive and finite, got {self.fps}")
        if np.any(self.image_size_wh <= 0):
            raise ValueError(f"CameraRig.image_size_wh must be positive, got {self.image_size_wh.tolist()}")
        if np.any(self.K[:, 0, 0] <= 0) or np.any(self.K[:, 1, 1] <= 0):
            raise ValueError(f"CameraRig.K: focal lengths must be positive, got fx={self.K[:, 0, 0]}")
        R = self.T_world_cam[:, :3, :3]
        orth = np.abs(np.einsum("vij,vkj->vik", R, R) - np.eye(3)).max(axis=(1, 2))
        bad = np.flatnonzero((orth > 1e-4) | (np.linalg.det(R) < 0))
        if bad.size:
            raise ValueError(
                f"CameraRig.T_world_cam: rotation of camera(s) {[self.names[i] for i in bad]} "
                f"is not a proper rotation (orthogonality error {orth[bad].tolist()})"
            )
        if not np.allclose(self.T_world_cam[:, 3], [0, 0, 0, 1]):
            raise ValueError("CameraRig.T_world_cam: last row must be [0, 0, 0, 1]")

    @property
    def n_views(self) -> int:
        return len(self.names)

    @property
    def T_cam_world(self) -> np.ndarray:
        """(views, 4, 4) world-to-camera transforms."""
        R = self.T_world_cam[:, :3, :3]
        t = self.T_world_cam[:, :3, 3]
        out = np.zeros_like(self.T_world_cam)
        out[:, :3, :3] = np.transpose(R, (0, 2, 1))
        out[:, :3, 3] = -np.einsum("vji,vj->vi", R, t)
        out[:, 3, 3] = 1.0
        return out

    @property
    def P(self) -> np.ndarray:
        """(views, 3, 4) projection matrices ``K [R | t]`` (world -> undistorted pixels)."""
        return np.einsum("vij,vjk->vik", self.K, self.T_cam_world[:, :3, :])

    @property
    def centers_world_m(self) -> np.ndarray:
        """(views, 3) camera centres in the world frame."""
        return self.T_world_cam[:, :3, 3].copy()

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"camera {name!r} is not in the rig {self.names}") from None

    def subset(self, views: list[int] | tuple[int, ...]) -> CameraRig:
        """A rig with only the given view indices, in that order."""
        idx = list(views)
        return CameraRig(
            names=tuple(self.names[i] for i in idx),
            K=self.K[idx].copy(),
            dist=self.dist[idx].copy(),
            T_world_cam=self.T_world_cam[idx].copy(),
            image_size_wh=self.image_size_wh[idx].copy(),
            fps=self.fps,
            time_offset_s=self.time_offset_s[idx].copy(),
        )
