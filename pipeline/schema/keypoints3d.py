"""3D keypoints of several persons over time."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from pipeline.schema.base import check_array, check_finite_where, check_unit_interval_where

Keypoints3DSource = Literal["raw", "filtered", "fit", "physics", "gt"]
SOURCES: tuple[str, ...] = ("raw", "filtered", "fit", "physics", "gt")
"""The result names of ``pipeline.schema.sources`` plus ``gt`` (ground truth)."""
_LEGACY_SOURCES = {"triangulation": "raw"}
"""Names older artifacts carry, read as today's."""


@dataclass(frozen=True)
class Keypoints3D:
    """3D joints, world frame (metres, z-up).

    Fields:
        joint_names: joint set (``joints``).
        person_ids: (persons,) global person ids matching ``Association.person_ids``.
        frame_indices: (frames,) video frame index of each row (strictly increasing).
        fps: frame rate of ``frame_indices``.
        xyz_m: (frames, persons, joints, 3) positions in metres.
        valid: (frames, persons, joints) bool; False = no estimate (values meaningless).
        confidence: (frames, persons, joints) in [0, 1].
        n_views: (frames, persons, joints) int number of views used (0 when not
            triangulated, e.g. interpolated or model-derived).
        reproj_err_px: (frames, persons, joints) mean reprojection error over the
            views used, in pixels (NaN when not applicable).
        source: which stage produced it.
        filled: (frames, persons, joints) bool; True where the joint was not measured but
            placed from the person's skeleton (``pipeline.stages.joint_fill``); such joints
            are valid with a reduced confidence. Empty on input means none.
    """

    joint_names: tuple[str, ...]
    person_ids: np.ndarray
    frame_indices: np.ndarray
    fps: float
    xyz_m: np.ndarray
    valid: np.ndarray
    confidence: np.ndarray
    n_views: np.ndarray
    reproj_err_px: np.ndarray
    source: str
    filled: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def __post_init__(self) -> None:
        f = self.frame_indices.shape[0] if isinstance(self.frame_indices, np.ndarray) else -1
        p = self.person_ids.shape[0] if isinstance(self.person_ids, np.ndarray) else -1
        j = len(self.joint_names)
        check_array("Keypoints3D.frame_indices", self.frame_indices, (f,), "iu")
        check_array("Keypoints3D.person_ids", self.person_ids, (p,), "iu")
        check_array("Keypoints3D.xyz_m", self.xyz_m, (f, p, j, 3), "f")
        check_array("Keypoints3D.valid", self.valid, (f, p, j), "b")
        check_array("Keypoints3D.confidence", self.confidence, (f, p, j), "f")
        check_array("Keypoints3D.n_views", self.n_views, (f, p, j), "iu")
        check_array("Keypoints3D.reproj_err_px", self.reproj_err_px, (f, p, j), "f")
        if self.filled.size == 0:
            object.__setattr__(self, "filled", np.zeros((f, p, j), dtype=bool))
        check_array("Keypoints3D.filled", self.filled, (f, p, j), "b")
        check_finite_where("Keypoints3D.xyz_m", self.xyz_m, self.valid)
        check_unit_interval_where("Keypoints3D.confidence", self.confidence, self.valid)
        if self.source in _LEGACY_SOURCES:
            object.__setattr__(self, "source", _LEGACY_SOURCES[self.source])
        if self.source not in SOURCES:
            raise ValueError(f"Keypoints3D.source must be one of {SOURCES}, got {self.source!r}")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"Keypoints3D.fps must be positive, got {self.fps}")
        if f > 1 and np.any(np.diff(self.frame_indices) <= 0):
            raise ValueError("Keypoints3D.frame_indices must be strictly increasing")

    @property
    def n_frames(self) -> int:
        return int(self.frame_indices.shape[0])

    @property
    def n_persons(self) -> int:
        return int(self.person_ids.shape[0])

    @classmethod
    def empty(
        cls,
        joint_names: tuple[str, ...],
        person_ids: np.ndarray,
        frame_indices: np.ndarray,
        fps: float,
        source: str,
    ) -> Keypoints3D:
        """All-invalid keypoints of the given extent (a starting point for stages)."""
        f, p, j = len(frame_indices), len(person_ids), len(joint_names)
        return cls(
            joint_names=joint_names,
            person_ids=np.asarray(person_ids, dtype=np.int64),
            frame_indices=np.asarray(frame_indices, dtype=np.int64),
            fps=float(fps),
            xyz_m=np.zeros((f, p, j, 3)),
            valid=np.zeros((f, p, j), dtype=bool),
            confidence=np.zeros((f, p, j)),
            n_views=np.zeros((f, p, j), dtype=np.int64),
            reproj_err_px=np.full((f, p, j), np.nan),
            source=source,
        )

    def replace(self, **kw: object) -> Keypoints3D:
        """A copy with fields replaced; ``filled`` is dropped when the extent changes
        (frames, persons or joints) and no new ``filled`` is given."""
        d = dict(self.__dict__)
        if "filled" not in kw and any(k in kw for k in ("frame_indices", "person_ids", "joint_names")):
            d["filled"] = np.zeros(0, dtype=bool)
        d.update(kw)
        return Keypoints3D(**d)  # type: ignore[arg-type]

    def person_index(self, person_id: int) -> int:
        idx = np.flatnonzero(self.person_ids == person_id)
        if idx.size == 0:
            raise ValueError(f"person {person_id} not in {self.person_ids.tolist()}")
        return int(idx[0])
