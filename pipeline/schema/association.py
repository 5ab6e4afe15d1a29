"""Cross-view identity association."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.schema.base import check_array


@dataclass(frozen=True)
class Association:
    """Maps every row of a ``Tracks2D`` to a global person id.

    Fields (``dets`` = rows of the ``Tracks2D`` this was computed from):
        person_ids: (persons,) the global ids in use (sorted, >= 0).
        person_names: (persons,) display names ("" when unknown).
        person_of_det: (dets,) global person id of each detection, ``-1`` for
            detections attributed to nobody (bystanders, referee, false positives).
        confidence: (dets,) association confidence in [0, 1].
    """

    person_ids: np.ndarray
    person_names: tuple[str, ...]
    person_of_det: np.ndarray
    confidence: np.ndarray

    def __post_init__(self) -> None:
        p = self.person_ids.shape[0] if isinstance(self.person_ids, np.ndarray) else -1
        check_array("Association.person_ids", self.person_ids, (p,), "iu")
        if len(self.person_names) != p:
            raise ValueError(f"Association.person_names: {len(self.person_names)} names for {p} persons")
        n = self.person_of_det.shape[0] if isinstance(self.person_of_det, np.ndarray) else -1
        check_array("Association.person_of_det", self.person_of_det, (n,), "iu")
        check_array("Association.confidence", self.confidence, (n,), "f", finite=True)
        if p and (np.any(self.person_ids < 0) or len(np.unique(self.person_ids)) != p):
            raise ValueError(f"Association.person_ids must be unique and >= 0, got {self.person_ids.tolist()}")
        used = np.unique(self.person_of_det[self.person_of_det >= 0])
        unknown = np.setdiff1d(used, self.person_ids)
        if unknown.size:
            raise ValueError(f"Association.person_of_det uses ids {unknown.tolist()} not in person_ids")
        if n and (self.confidence.min() < 0 or self.confidence.max() > 1):
            raise ValueError("Association.confidence must lie in [0, 1]")

    @property
    def n_persons(self) -> int:
        return int(self.person_ids.shape[0])

    def spans(self, view: np.ndarray, frame: np.ndarray, track_id: np.ndarray) -> list[dict]:
        """Runs of constant (view, track) -> person, as dicts with frame_start/frame_end (inclusive).

        ``view``, ``frame``, ``track_id`` are the columns of the matching ``Tracks2D``.
        """
        out: list[dict] = []
        order = np.lexsort((frame, track_id, view))
        cur: dict | None = None
        for i in order:
            key = (int(view[i]), int(track_id[i]), int(self.person_of_det[i]))
            if cur is not None and (cur["view"], cur["track"], cur["person"]) == key and int(frame[i]) == cur["frame_end"] + 1:
                cur["frame_end"] = int(frame[i])
                continue
            cur = {"view": key[0], "track": key[1], "person": key[2], "frame_start": int(frame[i]), "frame_end": int(frame[i])}
            out.append(cur)
        return out
