"""``cornerman bench incremental``: what an annotator's identity fix costs to re-run.

A fully run session (the demo bout made as ``cornerman demo`` makes it, or a copy of
``session=PATH``; the source is never modified) gets one identity swap at ``frame`` in
``camera``, written through the annotation overlay the server writes
(``pipeline.schema.annotations``, checked by ``check_annotation``). The runner then re-runs
the stale stages, each reusing its previous artifacts (docs/design/incremental.md).

One row per re-run stage: its incremental time, the full time of the same stage (from the
session's manifests before the edit; ``full=true`` first re-runs every stage in full, forced,
for a like-for-like time on the same machine state), their ratio, and from the manifests what
was reused: reused frames, the first re-planned / re-fitted frame, the first changed input frame.

The demo's identities are right, so a swap alone breaks them: the later frames become an
input the physics cannot track. By default (``fix=true``) the bench times what an annotator's
fix costs: the swap goes in first as a tracking error (run, not timed), then a second,
identical swap undoes it (``SwapIdentities`` twice is the identity) and that re-run is timed
against the full run of the right identities. ``fix=false`` times the breaking swap itself.
"""

from __future__ import annotations

import logging
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

FROM_FRAME_KEYS = ("replanned_from_frame", "refit_from_frame")
"""Manifest metrics naming the first frame a stage recomputed (physics, fit)."""


def _full_session(work: Path, session: str | None, frames: int, cameras: int, seed: int) -> Path:
    """A fully run session in ``work``: a copy of ``session`` brought up to date by the runner
    (stale stages re-run in full), or the demo bout made and run as ``cornerman demo`` does."""
    from pipeline.runner import run as run_stages

    dst = work / "session"
    if session is None:
        from pipeline.synthetic import SyntheticConfig, make_demo_session

        make_demo_session(dst, SyntheticConfig(seed=seed, n_frames=frames, n_cameras=cameras))
    else:
        src = Path(session)
        if not (src / "session.json").is_file():
            raise ValueError(f"session={session}: no session.json in that folder")
        shutil.copytree(src, dst, symlinks=True)
    run_stages(dst)
    return dst


def apply_swap(session_dir: Path, frame: int, camera: str, person_a: int, person_b: int) -> str:
    """Append a ``swap_identities`` edit (persons ``person_a``/``person_b`` from ``frame`` on in
    ``camera``) to ``session_dir``'s ``annotations.json``, checked as the server checks it;
    returns the first stage it makes stale. ``ValueError`` when the edit does not fit the session."""
    from pipeline.runner.annotation_bounds import annotation_bounds
    from pipeline.schema.annotation_checks import check_annotation
    from pipeline.schema.annotations import (
        CONSUMED_BY,
        SwapIdentities,
        load_annotations,
        save_annotations,
    )

    edit = SwapIdentities(frame=frame, person_a=person_a, person_b=person_b, view=camera)
    try:
        check_annotation(edit, annotation_bounds(session_dir))
    except ValueError as e:
        raise ValueError(f"frame={frame} camera={camera!r}: {e}") from e
    path = session_dir / "annotations.json"
    save_annotations(path, [*load_annotations(path), edit])
    return CONSUMED_BY[edit.kind]


def _stage_rows(before: dict[str, Any], reports: list[Any]) -> list[dict[str, Any]]:
    """One row per stage that ran after the edit: incremental vs full seconds and what the
    stage's manifest metrics say it reused. ``before``: stage -> (duration_s, metrics) of the
    full run."""
    rows: list[dict[str, Any]] = []
    for r in reports:
        if r.action != "ran":
            continue
        full_s = float(before[r.stage][0]) if r.stage in before else float("nan")
        m = r.metrics
        frm = next((int(m[k]) for k in FROM_FRAME_KEYS if k in m), -1)
        rows.append(
            {
                "stage": r.stage,
                "incremental_s": round(float(r.duration_s), 2),
                "full_s": round(full_s, 2),
                "ratio": round(float(r.duration_s) / full_s, 3) if full_s > 0 else float("nan"),
                "reused_frames": int(m.get("reused_frames", -1)),
                "recomputed_from_frame": frm,
                "first_changed_input_frame": int(m.get("first_changed_input_frame", -1)),
                "first_changed_reference_frame": int(m.get("first_changed_reference_frame", -1)),
                "incremental": str(m.get("incremental", "")),
            }
        )
    inc = sum(r["incremental_s"] for r in rows)
    full = sum(r["full_s"] for r in rows)
    rows.append(
        {
            "stage": "all re-run stages",
            "incremental_s": round(inc, 2),
            "full_s": round(full, 2),
            "ratio": round(inc / full, 3) if full > 0 else float("nan"),
        }
    )
    return rows


def run_bench(
    session: str | None = None,
    frame: int = 240,
    camera: str = "cam02",
    person_a: int = 0,
    person_b: int = 1,
    full: bool = False,
    frames: int = 300,
    cameras: int = 4,
    seed: int = 0,
    keep: str | None = None,
    fix: bool = True,
) -> list[dict[str, Any]]:
    """Rows: one per stage re-run after the swap, then their sum (see the module docstring).

    session: a fully run session folder to copy (default: make the demo bout of ``frames``
    frames, ``cameras`` cameras, ``seed``); frame (>= 0), camera: where the swap starts;
    person_a, person_b: the swapped persons; full: re-run every stage in full first for the
    full times; keep: copy the edited session there afterwards (a folder that must not exist);
    fix: time the fix of a swap made first as a tracking error (default: what issue 38's
    target names, an identity fix), else the swap itself.
    """
    from pipeline.artifacts.store import ArtifactStore
    from pipeline.runner import STAGE_ORDER
    from pipeline.runner import run as run_stages

    for name, v in (
        ("frame", frame),
        ("person_a", person_a),
        ("person_b", person_b),
        ("frames", frames),
        ("cameras", cameras),
        ("seed", seed),
    ):
        if isinstance(v, bool) or not isinstance(v, int):
            raise ValueError(f"{name}={v!r}: must be an integer")
    for name, flag in (("full", full), ("fix", fix)):
        if not isinstance(flag, bool):
            raise ValueError(f"{name}={flag!r}: must be true or false")
    if frame < 0:
        raise ValueError(f"frame={frame}: must be >= 0")
    if keep is not None and Path(keep).exists():
        raise ValueError(f"keep={keep}: already exists; give a new folder")
    with tempfile.TemporaryDirectory(prefix="cornerman-incremental-") as tmp:
        s = _full_session(Path(tmp), session, frames, cameras, seed)
        if full:
            t0 = time.perf_counter()
            run_stages(s, force=True)
            log.info("full forced re-run: %.1f s", time.perf_counter() - t0)
        store = ArtifactStore(s)
        before: dict[str, Any] = {}
        for name in STAGE_ORDER:
            m = store.manifest(name)
            if m is not None:
                before[name] = (m.duration_s, m.metrics)
        first = apply_swap(s, frame, camera, person_a, person_b)
        log.info("swap at frame %d in %s: stale from %s", frame, camera, first)
        if fix:
            t0 = time.perf_counter()
            run_stages(s)
            log.info("the swap as a tracking error: %.1f s; now the fix", time.perf_counter() - t0)
            apply_swap(s, frame, camera, person_a, person_b)
        reports = run_stages(s)
        edit = f"{'fix of an identity swap' if fix else 'identity swap'} at frame {frame} in {camera}"
        rows = [{**r, "edit": edit} for r in _stage_rows(before, reports)]
        if keep is not None:
            shutil.copytree(s, keep, symlinks=True)
    return rows


COLUMNS = (
    ("stage", "stage"),
    ("incremental_s", "incr s"),
    ("full_s", "full s"),
    ("ratio", "ratio"),
    ("reused_frames", "reused frames"),
    ("recomputed_from_frame", "from frame"),
    ("first_changed_input_frame", "1st changed input"),
    ("first_changed_reference_frame", "1st changed ref"),
    ("incremental", "manifest says"),
)
"""Table columns: row key -> header (-1: the stage does not report it)."""

TARGET = "target (issue 38): physics after a late edit <= 25 % of a full physics run"


def print_table(rows: list[dict[str, Any]]) -> None:
    """The rows as one table, wide enough for the manifest's text also in a pipe."""
    from rich.console import Console
    from rich.table import Table

    edit = rows[0].get("edit", "an identity swap") if rows else "an identity swap"
    table = Table(title=f"incremental re-run after {edit}", caption=TARGET)
    for key, head in COLUMNS:
        table.add_column(head, justify="left" if key in ("stage", "incremental") else "right")
    for r in rows:
        cells = []
        for key, _ in COLUMNS:
            v = r.get(key, "")
            cells.append(f"{v:.3g}" if key == "ratio" and isinstance(v, float) else str(v))
        table.add_row(*cells)
    Console(width=max(Console().width, 200)).print(table)
