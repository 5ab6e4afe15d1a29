"""Write a synthetic bout as a cornerman session folder (the embedded demo)."""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import logging
from pathlib import Path

import numpy as np

from pipeline.io.calibration import save_toml
from pipeline.schema.base import to_arrays
from pipeline.schema.session import SessionConfig
from pipeline.synthetic.bout import SyntheticBout, make_bout
from pipeline.synthetic.config import SyntheticConfig

log = logging.getLogger(__name__)

GENERATOR_VERSION = 2
"""Bump when the generator's output changes, so stale demo sessions are regenerated."""

CALIBRATION = "inputs/calibration.toml"
TRACKS = "inputs/tracks2d.npz"
GROUND_TRUTH = "inputs/ground_truth.npz"
GT_LABELS = "inputs/gt_labels.npz"
GT_EVENTS = "inputs/ground_truth_events.npz"
"""The choreography's labelled events (``pipeline.synthetic.truth.BoutTruth``)."""
INPUT_FILES: tuple[str, ...] = (CALIBRATION, TRACKS, GROUND_TRUTH, GT_LABELS, GT_EVENTS)
MARKER = "inputs/synthetic.json"
"""Records the generating config and the sha256 of every written input."""


def _write_npz_atomic(path: Path, arrays: dict[str, np.ndarray]) -> None:
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # type: ignore[arg-type]  # numpy stubs mistake **kw for allow_pickle
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_bytes(buf.getvalue())
    tmp.replace(path)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_session(bout: SyntheticBout, session_dir: Path, name: str = "demo bout") -> Path:
    """Write ``bout`` into ``session_dir`` (created if needed) and return the folder.

    Files: ``session.json`` (``source="tracks"``), ``inputs/calibration.toml``,
    ``inputs/tracks2d.npz`` (``Tracks2D``), ``inputs/ground_truth.npz`` (``Keypoints3D``,
    source "gt") and ``inputs/gt_labels.npz`` (arrays ``person_of_det`` (dets,),
    ``foot_contact`` (frames, 2, 2) and ``swap_frames`` (S, 2) [view, frame]) and
    ``inputs/ground_truth_events.npz`` (``BoutTruth``: punches with type and outcome, feints,
    slips and ducks, clinch frames). Every file is written to a temporary name and renamed
    into place.
    """
    session_dir = Path(session_dir)
    (session_dir / "inputs").mkdir(parents=True, exist_ok=True)
    save_toml(bout.rig, session_dir / CALIBRATION)
    _write_npz_atomic(session_dir / TRACKS, to_arrays(bout.tracks))
    _write_npz_atomic(session_dir / GROUND_TRUTH, to_arrays(bout.gt))
    _write_npz_atomic(session_dir / GT_EVENTS, to_arrays(bout.truth))
    _write_npz_atomic(
        session_dir / GT_LABELS,
        {
            "person_of_det": bout.gt_person_of_det,
            "foot_contact": bout.foot_contact,
            "swap_frames": bout.swap_frames,
        },
    )
    SessionConfig(
        name=name,
        source="tracks",
        calibration=CALIBRATION,
        tracks=TRACKS,
        ground_truth=GROUND_TRUTH,
        ground_truth_labels=GT_LABELS,
        fps=float(bout.rig.fps),
    ).save(session_dir)
    return session_dir


def _fingerprint(cfg: SyntheticConfig) -> dict[str, object]:
    return {"generator_version": GENERATOR_VERSION, "config": dataclasses.asdict(cfg)}


def _is_current(session_dir: Path, cfg: SyntheticConfig) -> bool:
    marker = session_dir / MARKER
    if not marker.exists() or not (session_dir / "session.json").exists():
        return False
    try:
        rec = json.loads(marker.read_text())
        SessionConfig.load(session_dir)
    except (json.JSONDecodeError, ValueError) as e:
        log.info("demo session %s is not reusable: %s", session_dir, e)
        return False
    want = json.loads(json.dumps(_fingerprint(cfg)))  # tuples -> lists, as stored
    if rec.get("fingerprint") != want:
        return False
    files = rec.get("files", {})
    for rel in INPUT_FILES:
        p = session_dir / rel
        if not p.exists() or files.get(rel) != _sha256(p):
            return False
    return True


def make_demo_session(session_dir: Path, cfg: SyntheticConfig = SyntheticConfig()) -> Path:
    """Create (or reuse) the demo session for ``cfg`` in ``session_dir`` and return it.

    Deterministic: the arrays depend only on ``cfg``. If the folder already holds inputs
    generated from the same config by the same generator version, unchanged on disk, it is
    left untouched (its artifacts stay fresh); otherwise the inputs are (re)written.
    """
    session_dir = Path(session_dir)
    if _is_current(session_dir, cfg):
        log.info("reusing demo session %s", session_dir)
        return session_dir
    bout = make_bout(cfg)
    write_session(bout, session_dir, name="demo bout")
    rec = {
        "fingerprint": _fingerprint(cfg),
        "files": {rel: _sha256(session_dir / rel) for rel in INPUT_FILES},
    }
    tmp = session_dir / (MARKER + ".tmp")
    tmp.write_text(json.dumps(rec, indent=2, sort_keys=True))
    tmp.replace(session_dir / MARKER)
    log.info("wrote demo session %s (%d detections)", session_dir, bout.tracks.n_dets)
    return session_dir
