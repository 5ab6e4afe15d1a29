"""2D person detections and per-view tracks, stored flat (one row per detection).

A flat layout (``dets`` rows, each with its view and frame index) keeps the ragged
"any number of people per view and frame" structure vectorisable and npz-friendly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.schema.base import check_array, check_finite_where


@dataclass(frozen=True)
class Detections2D:
    """Person detections with top-down 2D keypoints.

    Fields (``dets`` = number of detections over all views and frames):
        joint_names: joint set of ``keypoints_px`` (see ``pipeline.schema.joints``).
        n_views, n_frames: the extent of the rig/video the rows index into.
        view: (dets,) int view index in ``[0, n_views)``.
        frame: (dets,) int frame index in ``[0, n_frames)``.
        bbox_xyxy_px: (dets, 4) box in pixels of the *distorted* image.
        bbox_score: (dets,) detector score in [0, 1].
        keypoints_px: (dets, joints, 2) pixel coordinates (distorted image).
        keypoint_conf: (dets, joints) confidence in [0, 1].
        keypoint_valid: (dets, joints) bool; False for joints the source did not
            provide or dropped (coordinates there are meaningless).
    """

    joint_names: tuple[str, ...]
    n_views: int
    n_frames: int
    view: np.ndarray
    frame: np.ndarray
    bbox_xyxy_px: np.ndarray
    bbox_score: np.ndarray
    keypoints_px: np.ndarray
    keypoint_conf: np.ndarray
    keypoint_valid: np.ndarray

    def __post_init__(self) -> None:
        n = self.view.shape[0] if isinstance(self.view, np.ndarray) and self.view.ndim == 1 else -1
        if n < 0:
            raise ValueError(f"{type(self).__name__}.view must be a 1-D int array")
        j = len(self.joint_names)
        if j == 0:
            raise ValueError(f"{type(self).__name__}: empty joint set")
        name = type(self).__name__
        check_array(f"{name}.view", self.view, (n,), "iu")
        check_array(f"{name}.frame", self.frame, (n,), "iu")
        check_array(f"{name}.bbox_xyxy_px", self.bbox_xyxy_px, (n, 4), "f", finite=True)
        check_array(f"{name}.bbox_score", self.bbox_score, (n,), "f", finite=True)
        check_array(f"{name}.keypoints_px", self.keypoints_px, (n, j, 2), "f")
        check_array(f"{name}.keypoint_conf", self.keypoint_conf, (n, j), "f")
        check_array(f"{name}.keypoint_valid", self.keypoint_valid, (n, j), "b")
        check_finite_where(f"{name}.keypoints_px", self.keypoints_px, self.keypoint_valid)
        check_finite_where(f"{name}.keypoint_conf", self.keypoint_conf, self.keypoint_valid)
        if self.n_views <= 0 or self.n_frames < 0:
            raise ValueError(f"{name}: n_views={self.n_views}, n_frames={self.n_frames} must be positive")
        if n and (self.view.min() < 0 or self.view.max() >= self.n_views):
            raise ValueError(f"{name}.view: values outside [0, {self.n_views}): {np.unique(self.view).tolist()}")
        if n and (self.frame.min() < 0 or self.frame.max() >= self.n_frames):
            raise ValueError(
                f"{name}.frame: values outside [0, {self.n_frames}): min {self.frame.min()}, max {self.frame.max()}"
            )
        c = self.keypoint_conf[self.keypoint_valid]
        if c.size and (c.min() < 0 or c.max() > 1):
            raise ValueError(f"{name}.keypoint_conf: values outside [0, 1] ({c.min()}..{c.max()})")

    @property
    def n_dets(self) -> int:
        return int(self.view.shape[0])

    def rows(self, view: int, frame: int) -> np.ndarray:
        """Row indices of the detections of ``view`` at ``frame``."""
        return np.flatnonzero((self.view == view) & (self.frame == frame))

    def select(self, mask_or_idx: np.ndarray) -> Detections2D:
        """A copy restricted to the given rows (bool mask or index array)."""
        return type(self)(**_select_fields(self, mask_or_idx))


def _select_fields(obj: Detections2D, idx: np.ndarray) -> dict:
    out: dict = {}
    for k, v in obj.__dict__.items():
        out[k] = v[idx] if isinstance(v, np.ndarray) else v
    return out


@dataclass(frozen=True)
class Tracks2D(Detections2D):
    """Detections with a persistent per-view track id.

    Extra field:
        track_id: (dets,) int, unique within a view; the same athlete keeps the
            same id over time in that view (until a tracker error). ``-1`` means
            the detection is not part of any track (and is ignored downstream).
    """

    track_id: np.ndarray = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.track_id is None:
            raise ValueError("Tracks2D.track_id is required")
        check_array("Tracks2D.track_id", self.track_id, (self.n_dets,), "iu")
        # A track id must not appear twice in one (view, frame).
        key = np.stack([self.view, self.frame, self.track_id], axis=1)[self.track_id >= 0]
        if key.size:
            uniq, counts = np.unique(key, axis=0, return_counts=True)
            if np.any(counts > 1):
                v, f, t = uniq[counts > 1][0]
                raise ValueError(f"Tracks2D: track {t} appears twice in view {v} frame {f}")

    @classmethod
    def from_detections(cls, dets: Detections2D, track_id: np.ndarray) -> Tracks2D:
        kw = dict(dets.__dict__)
        kw["track_id"] = np.asarray(track_id, dtype=np.int64)
        return cls(**kw)

    def detections(self) -> Detections2D:
        kw = {k: v for k, v in self.__dict__.items() if k != "track_id"}
        return Detections2D(**kw)
