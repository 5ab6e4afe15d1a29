"""Exports of 3D results: JSON (documented in the README) and NPZ.

JSON format (``keypoints3d_to_json``)::

    {
      "format": "cornerman.keypoints3d/v1",
      "source": "filtered" | "fit" | "physics" | ...,
      "fps": 50.0,
      "units": "m",
      "frame": "floor world (calibrate/world.json), z-up, right-handed",
      "joint_names": ["nose", ...],
      "persons": [
        {"id": 0, "name": "Red",
         "frame_indices": [0, 1, ...],
         "joints": [[[x, y, z] | null, ...joints], ...frames],
         "confidence": [[c, ...joints], ...frames]}
      ]
    }

``null`` marks a joint without an estimate in that frame.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from pipeline.schema.base import to_arrays
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.sources import RESULT_ARTIFACTS

if TYPE_CHECKING:
    from pipeline.io.export.selection import ExportSelection

ExportFormat = Literal["json", "npz"]
JSON_FORMAT_ID = "cornerman.keypoints3d/v1"

KEYPOINTS3D_ARTIFACTS = RESULT_ARTIFACTS

SOURCE_ORDER: dict[str, tuple[str, ...]] = {
    # The most accurate result available. Physics is left out until it tracks the
    # kinematic input within its accuracy target (see `cornerman bench physics`).
    "best": ("fit", "filtered"),
    # The last stage that produced keypoints.
    "latest": ("physics", "fit", "filtered"),
}
KeypointSource = Literal["best", "latest", "raw", "filtered", "fit", "physics"]


def find_keypoints3d(session_dir: Path, source: str = "best") -> tuple[Keypoints3D, str]:
    """Load the 3D keypoints of ``source`` from a session; returns them and the source chosen.

    ``LookupError`` when no candidate stage has produced them yet; ``ValueError`` for an
    unknown source name.
    """
    from pipeline.artifacts import ArtifactStore

    if source not in SOURCE_ORDER and source not in KEYPOINTS3D_ARTIFACTS:
        raise ValueError(f"unknown 3D source {source!r}; choose one of {sorted([*SOURCE_ORDER, *KEYPOINTS3D_ARTIFACTS])}")
    candidates = SOURCE_ORDER.get(source, (source,))
    store = ArtifactStore(session_dir)
    for cand in candidates:
        stage, name = KEYPOINTS3D_ARTIFACTS[cand]
        if store.has(stage, f"{name}.npz"):
            return store.load(stage, name, Keypoints3D), cand
    raise LookupError(f"{session_dir}: no 3D keypoints ({', '.join(candidates)}) yet; run the session's stages first")


def keypoints3d_to_json(kp: Keypoints3D, names: dict[int, str] | None = None) -> dict[str, Any]:
    """The README's JSON export as a dict (coordinates rounded to 0.1 mm)."""
    names = names or {}
    persons = []
    for pi, pid in enumerate(kp.person_ids.tolist()):
        xyz = np.round(kp.xyz_m[:, pi], 4)
        valid = kp.valid[:, pi]
        joints = [
            [xyz[f, j].tolist() if valid[f, j] else None for j in range(len(kp.joint_names))] for f in range(kp.n_frames)
        ]
        conf = np.round(np.where(valid, kp.confidence[:, pi], 0.0), 3).tolist()
        persons.append(
            {
                "id": int(pid),
                "name": names.get(int(pid), ""),
                "frame_indices": kp.frame_indices.tolist(),
                "joints": joints,
                "confidence": conf,
            }
        )
    return {
        "format": JSON_FORMAT_ID,
        "source": kp.source,
        "fps": float(kp.fps),
        "units": "m",
        "frame": "floor world (calibrate/world.json), z-up, right-handed",
        "joint_names": list(kp.joint_names),
        "persons": persons,
    }


def export_keypoints3d(kp: Keypoints3D, fmt: ExportFormat, names: dict[int, str] | None = None) -> bytes:
    """Serialise keypoints in ``fmt`` ("json" or "npz")."""
    if fmt == "json":
        return json.dumps(keypoints3d_to_json(kp, names), separators=(",", ":")).encode()
    if fmt == "npz":
        buf = io.BytesIO()
        np.savez_compressed(buf, **to_arrays(kp))  # type: ignore[arg-type]  # numpy stub, see schema.base
        return buf.getvalue()
    raise ValueError(f"unknown export format {fmt!r}; supported: json, npz")


def write_export(kp: Keypoints3D, fmt: ExportFormat, path: Path, names: dict[int, str] | None = None) -> Path:
    data = export_keypoints3d(kp, fmt, names)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)
    return path


def _stem(sel: ExportSelection, chosen: str) -> str:
    return f"keypoints3d_{chosen}"


def build_json(sel: ExportSelection) -> dict[str, bytes]:
    """The registry's ``json`` format: the selected keypoints as the README's JSON."""
    kp, chosen = sel.keypoints()
    return {f"{_stem(sel, chosen)}.json": export_keypoints3d(kp, "json", dict(sel.names))}


def build_npz(sel: ExportSelection) -> dict[str, bytes]:
    """The registry's ``npz`` format: the selected ``Keypoints3D`` fields as arrays."""
    kp, chosen = sel.keypoints()
    return {f"{_stem(sel, chosen)}.npz": export_keypoints3d(kp, "npz", dict(sel.names))}
