"""``cornerman bench incremental``: what an annotator's identity fix costs to re-run.

A fully run session (the demo bout made as ``cornerman demo`` makes it, or a copy of
``session=PATH``; the source is never modified) gets one identity swap at ``frame`` in
``camera``, written through the annotation overlay the server writes
(``pipeline.schema.annotations``, checked by ``check_annotation``). The runner then re-runs
the stale stages, each reusing its previous artifacts (docs/design/incremental.md).

One row per re-run stage: its incremental time, the full time of the same stage (from the
session's manifests before the edit; ``full=true`` re-runs every stage of a copy in full,
forced, just before the timed re-run, for a like-for-like time on the same machine state),
their ratio, and from the manifests what was reused: reused frames, the first re-planned /
re-fitted frame, the first changed input frame.

The demo's identities are right, so a swap alone breaks them: the later frames become an
input the physics cannot track. By default (``fix=true``) the bench times what an annotator's
fix costs: the swap goes in first as a tracking error (run, not timed), then a second,
identical swap undoes it (``SwapIdentities`` twice is the identity) and that re-run is timed
against the full run of the right identities. ``fix=false`` times the breaking swap itself.

The wall times of identical re-runs can differ by a third on a shared 2-core machine (three
fixes at frame 270 of the demo took 16.0, 22.6 and 25.3 s).
``repeat=N`` times the edit's re-run N times, each on a fresh copy of the session as it was
just before it (with ``full=true``, each after a forced full re-run of another copy, so both
see the same machine state), and reports the median, with every run's time beside it.
"""

from __future__ import annotations

import logging
import shutil
import statistics
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


def _stage_rows(full_runs: list[dict[str, float]], runs: list[list[Any]]) -> list[dict[str, Any]]:
    """One row per stage that ran after the edit: the median of its incremental seconds over
    ``runs`` (each run's stage reports) against the median of its full seconds over
    ``full_runs`` (stage -> duration_s of a full run), and what the last run's manifest metrics
    say it reused; then the sum over the stages (of the medians)."""
    rows: list[dict[str, Any]] = []
    for r in runs[-1]:
        if r.action != "ran":
            continue
        inc_runs = [float(x.duration_s) for run in runs for x in run if x.stage == r.stage and x.action == "ran"]
        full_list = [f[r.stage] for f in full_runs if r.stage in f]
        inc_s = statistics.median(inc_runs)
        full_s = statistics.median(full_list) if full_list else float("nan")
        m = r.metrics
        frm = next((int(m[k]) for k in FROM_FRAME_KEYS if k in m), -1)
        rows.append(
            {
                "stage": r.stage,
                "incremental_s": round(inc_s, 2),
                "full_s": round(full_s, 2),
                "ratio": round(inc_s / full_s, 3) if full_s > 0 else float("nan"),
                "incremental_runs_s": [round(v, 2) for v in inc_runs],
                "full_runs_s": [round(v, 2) for v in full_list],
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
    repeat: int = 1,
) -> list[dict[str, Any]]:
    """Rows: one per stage re-run after the swap, then their sum (see the module docstring).

    session: a fully run session folder to copy (default: make the demo bout of ``frames``
    frames, ``cameras`` cameras, ``seed``); frame (>= 0), camera: where the swap starts;
    person_a, person_b: the swapped persons; full: time a forced full re-run of a copy before
    each timed re-run (else the full times are the session's manifests); keep: copy the
    edited session there afterwards (a folder that must not exist);
    fix: time the fix of a swap made first as a tracking error (default: what issue 38's
    target names, an identity fix), else the swap itself; repeat (>= 1): how many times the
    re-run (and with ``full``, the forced full run) is timed, each on a fresh copy (medians).
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
        ("repeat", repeat),
    ):
        if isinstance(v, bool) or not isinstance(v, int):
            raise ValueError(f"{name}={v!r}: must be an integer")
    for name, flag in (("full", full), ("fix", fix)):
        if not isinstance(flag, bool):
            raise ValueError(f"{name}={flag!r}: must be true or false")
    if frame < 0:
        raise ValueError(f"frame={frame}: must be >= 0")
    if repeat < 1:
        raise ValueError(f"repeat={repeat}: must be >= 1")
    if keep is not None and Path(keep).exists():
        raise ValueError(f"keep={keep}: already exists; give a new folder")
    with tempfile.TemporaryDirectory(prefix="cornerman-incremental-") as tmp:
        s = _full_session(Path(tmp), session, frames, cameras, seed)
        store = ArtifactStore(s)
        manifests: dict[str, float] = {}
        for name in STAGE_ORDER:
            m = store.manifest(name)
            if m is not None:
                manifests[name] = m.duration_s
        first = apply_swap(s, frame, camera, person_a, person_b)
        log.info("swap at frame %d in %s: stale from %s", frame, camera, first)
        if fix:
            t0 = time.perf_counter()
            run_stages(s)
            log.info("the swap as a tracking error: %.1f s; now the fix", time.perf_counter() - t0)
            apply_swap(s, frame, camera, person_a, person_b)
        full_runs: list[dict[str, float]] = [] if full else [manifests]
        runs: list[list[Any]] = []
        timed = s
        for i in range(repeat):
            if full:
                forced = Path(tmp) / f"full{i}"
                shutil.copytree(s, forced, symlinks=True)
                t0 = time.perf_counter()
                full_runs.append({r.stage: float(r.duration_s) for r in run_stages(forced, force=True) if r.action == "ran"})
                log.info("full forced re-run %d/%d: %.1f s", i + 1, repeat, time.perf_counter() - t0)
                shutil.rmtree(forced)
            if repeat > 1:  # a fresh copy each time; the last one is kept
                if timed is not s:
                    shutil.rmtree(timed)
                timed = Path(tmp) / f"timed{i}"
                shutil.copytree(s, timed, symlinks=True)
            runs.append(run_stages(timed))
            log.info("timed re-run %d/%d done", i + 1, repeat)
        edit = f"{'fix of an identity swap' if fix else 'identity swap'} at frame {frame} in {camera}"
        rows = [{**r, "edit": edit} for r in _stage_rows(full_runs, runs)]
        if keep is not None:
            shutil.copytree(timed, keep, symlinks=True)
    return rows


COLUMNS = (
    ("stage", "stage"),
    ("incremental_s", "incr s"),
    ("full_s", "full s"),
    ("ratio", "ratio"),
    ("incremental_runs_s", "incr runs s"),
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
            if key == "ratio" and isinstance(v, float):
                cells.append(f"{v:.3g}")
            elif isinstance(v, list):
                cells.append(" ".join(f"{x:g}" for x in v))
            else:
                cells.append(str(v))
        table.add_row(*cells)
    Console(width=max(Console().width, 200)).print(table)
