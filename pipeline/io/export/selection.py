"""What an export covers: a session, a result source, some athletes and a frame range."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit, PhysicsResult

T = TypeVar("T")


@dataclass(frozen=True)
class ExportSelection:
    """The part of a session an export writes.

    Fields:
        session_dir: the session folder (holds ``session.json`` and the artifacts).
        source: 3D source for keypoint formats: ``best``, ``latest``, ``raw``, ``filtered``,
            ``fit`` or ``physics`` (see ``pipeline.io.export.keypoints.SOURCE_ORDER``).
        athletes: person ids to export; empty = every athlete.
        frames: ``(first, stop)`` video frame indices, half-open; ``None`` = the whole bout.
        names: athlete name per person id (empty string when unnamed).
    """

    session_dir: Path
    source: str = "best"
    athletes: tuple[int, ...] = ()
    frames: tuple[int, int] | None = None
    names: Mapping[int, str] = field(default_factory=dict)

    def name_of(self, pid: int) -> str:
        """The athlete's name, or ``person{pid}`` when unnamed."""
        return self.names.get(int(pid)) or f"person{int(pid)}"

    def keypoints(self) -> tuple[Keypoints3D, str]:
        """The selected 3D keypoints and the source chosen; ``LookupError`` when none exist."""
        from pipeline.io.export.keypoints import find_keypoints3d

        kp, chosen = find_keypoints3d(self.session_dir, self.source)
        return self._restrict(kp, "keypoints"), chosen

    def bodyfit(self) -> BodyFit:
        """The fit stage's body-model parameters, restricted; ``LookupError`` when the fit has not run."""
        return self._restrict(self._load("fit", "bodyfit", BodyFit), "body fit")

    def physics(self) -> tuple[PhysicsResult, str]:
        """The physics result (restricted to the frames; persons stay, the scene holds all) and
        the scene MJCF text; ``LookupError`` when physics has not run."""
        from pipeline.artifacts import ArtifactStore

        res = self._load("physics", "result", PhysicsResult)
        xml_path = ArtifactStore(self.session_dir).stage_dir("physics") / "scene.xml"
        rows = self._frame_rows(res.frame_indices, "physics result")
        return _take_rows(res, rows), xml_path.read_text()

    def _load(self, stage: str, name: str, cls: type[T]) -> T:
        from pipeline.artifacts import ArtifactStore

        store = ArtifactStore(self.session_dir)
        if not store.has(stage, f"{name}.npz"):
            raise LookupError(f"{self.session_dir}: the {stage} stage has not produced {name}.npz yet; run it first")
        return store.load(stage, name, cls)

    def _frame_rows(self, frame_indices: np.ndarray, what: str) -> np.ndarray:
        if self.frames is None:
            return np.arange(len(frame_indices))
        a, b = self.frames
        rows = np.flatnonzero((frame_indices >= a) & (frame_indices < b))
        if rows.size == 0:
            lo, hi = (int(frame_indices[0]), int(frame_indices[-1])) if len(frame_indices) else (0, -1)
            raise ValueError(f"--frames {a}:{b}: no frame of the {what} in that range (it has {lo}..{hi})")
        return rows

    def _person_cols(self, person_ids: np.ndarray, what: str) -> np.ndarray:
        if not self.athletes:
            return np.arange(len(person_ids))
        known = [int(p) for p in person_ids]
        missing = [p for p in self.athletes if p not in known]
        if missing:
            raise ValueError(f"--athlete {missing}: not in the {what} (athletes: {known})")
        return np.array([known.index(p) for p in self.athletes])

    def _restrict(self, obj: Any, what: str) -> Any:
        rows = self._frame_rows(obj.frame_indices, what)
        cols = self._person_cols(obj.person_ids, what)
        return _take_persons(_take_rows(obj, rows), cols)


def _take_rows(obj: Any, rows: np.ndarray) -> Any:
    """``obj`` with only frame rows ``rows`` of every per-frame array (leading axis = frames)."""
    n = len(obj.frame_indices)
    changes: dict[str, Any] = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == n and f.name != "person_ids":
            changes[f.name] = v[rows]
    if isinstance(obj, PhysicsResult) and obj.contact_frame.size:
        keep = np.isin(obj.contact_frame, rows)
        remap = np.full(n, -1, dtype=np.int64)
        remap[rows] = np.arange(len(rows))
        changes.update(
            contact_frame=remap[obj.contact_frame[keep]],
            contact_person=obj.contact_person[keep],
            contact_body=obj.contact_body[keep],
            contact_depth_m=obj.contact_depth_m[keep],
        )
    return dataclasses.replace(obj, **changes)


_PERSON_AXIS = {
    Keypoints3D: ("xyz_m", "valid", "confidence", "n_views", "reproj_err_px", "filled"),
    BodyFit: ("pose", "root_translation_m", "valid"),
}


def _take_persons(obj: Any, cols: np.ndarray) -> Any:
    """``obj`` with only person columns ``cols`` (axis 1 of per-frame arrays, axis 0 of per-person)."""
    changes: dict[str, Any] = {"person_ids": obj.person_ids[cols]}
    for name in _PERSON_AXIS[type(obj)]:
        v = getattr(obj, name)
        if v.ndim >= 2:
            changes[name] = v[:, cols]
    if isinstance(obj, BodyFit):
        changes.update(shape=obj.shape[cols], loss_final=obj.loss_final[cols])
    return dataclasses.replace(obj, **changes)


def parse_frames(text: str | None) -> tuple[int, int] | None:
    """``"a:b"`` (video frames, half-open; either end may be empty) as ``(a, b)``; ``None`` for none.

    ``ValueError`` names the problem for anything else (``"5"``, ``"b:a"``, negatives).
    """
    if text is None or text.strip() in ("", ":"):
        return None
    parts = text.split(":")
    if len(parts) != 2:
        raise ValueError(f"--frames {text!r}: give FIRST:STOP (video frames, STOP excluded), e.g. 100:400")
    try:
        a = int(parts[0]) if parts[0].strip() else 0
        b = int(parts[1]) if parts[1].strip() else 2**31 - 1
    except ValueError:
        raise ValueError(f"--frames {text!r}: FIRST and STOP must be whole frame numbers") from None
    if a < 0 or b <= a:
        raise ValueError(f"--frames {text!r}: need 0 <= FIRST < STOP")
    return a, b
