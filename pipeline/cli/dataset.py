"""``cornerman dataset``: export sessions as a versioned dataset release, validate a release.

``cornerman dataset export SESSION... --out DIR`` writes the folder ``pipeline.dataset.layout``
describes; ``cornerman dataset validate DIR`` checks one and exits with code 2 when it is invalid.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

if TYPE_CHECKING:  # the commands import pipeline.dataset (numpy, jsonschema) when they run, not at CLI start
    from pipeline.dataset import AnnotationRecord

app = typer.Typer(
    help="Dataset releases: export sessions to a versioned, documented folder (export); check one (validate).",
    no_args_is_help=True,
)
console = Console()


def _fail(msg: str) -> None:
    console.print(f"[bold red]error:[/] {escape(msg)}", soft_wrap=True)
    raise typer.Exit(code=2)


def annotation_histories(home: Path, sessions: list[Path]) -> dict[Path, list[AnnotationRecord]]:
    """Session folder (resolved) -> its annotation history with authors and times, from the server
    database in ``home`` (``cornerman.db``), for the sessions the server knows. ``{}`` when ``home``
    has no database; the database is only read."""
    db_path = home / "cornerman.db"
    if not db_path.is_file():
        return {}
    from sqlmodel import Session, select

    from pipeline.dataset import AnnotationRecord
    from server import crud
    from server.db import make_engine
    from server.models import Bout

    wanted = {Path(s).resolve() for s in sessions}
    out: dict[Path, list[AnnotationRecord]] = {}
    with Session(make_engine(db_path)) as db:
        for bout in db.exec(select(Bout)).all():
            folder = Path(bout.folder).resolve() if bout.folder else None
            if folder not in wanted or bout.id is None:
                continue
            rows = crud.list_annotations(db, bout_id=bout.id, include_superseded=True)
            out[folder] = [
                AnnotationRecord(
                    edit=dict(a.payload),
                    id=a.id,
                    author=a.author or None,
                    created_utc=a.created_at.strftime("%Y-%m-%dT%H:%M:%SZ"),
                    active=a.superseded_by is None and a.kind != "undo",
                    superseded_by=a.superseded_by,
                    undoes=a.undoes,
                )
                for a in rows
            ]
    return out


@app.command("export")
def export_cmd(
    sessions: Annotated[
        list[Path], typer.Argument(help="Session folders to release (their stages already run).")
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="Release folder to create (new or empty).")],
    force: Annotated[
        bool, typer.Option("--force", help="Replace --out when it holds a previous release.")
    ] = False,
    allow_stale: Annotated[
        bool,
        typer.Option(
            "--allow-stale", help="Release stale stages as they are (marked stale in the datasheet)."
        ),
    ] = False,
    licence: Annotated[
        str,
        typer.Option(
            "--licence", help="Licence text for datasheet.md, e.g. 'CC BY 4.0' (default: a placeholder)."
        ),
    ] = "",
    server_home: Annotated[
        Path | None,
        typer.Option(
            "--server-home",
            help="Server home whose database holds the annotation history (authors, times); default "
            "$CORNERMAN_HOME or data/server. Sessions it does not know get their annotations.json, authors unknown.",
        ),
    ] = None,
    no_server: Annotated[
        bool,
        typer.Option(
            "--no-server", help="Ignore the server database: annotations.json's edits, authors unknown."
        ),
    ] = False,
) -> None:
    """Write a dataset release: calibration, video hashes, 2D tracks with identities, 3D keypoints per
    stage, body parameters, events, annotations, datasheet.md, JSON Schemas and checksums."""
    from pipeline.dataset import export_release

    home = server_home or Path(os.environ.get("CORNERMAN_HOME", "data/server"))
    if no_server and server_home is not None:
        _fail("--no-server and --server-home contradict each other; give one")
    if server_home is not None and not (server_home / "cornerman.db").is_file():
        _fail(f"--server-home {server_home}: no server database (cornerman.db) there")
    try:
        histories = {} if no_server else annotation_histories(home, sessions)
        with Progress(
            TextColumn("[bold]dataset"), BarColumn(), TextColumn("{task.completed:.0f}/{task.total:.0f} sessions"),
            TimeElapsedColumn(), TextColumn("{task.description}"), console=console,
        ) as bar:  # fmt: skip
            task = bar.add_task("checking the sessions", total=len(sessions))
            summary = export_release(
                sessions, out, force=force, allow_stale=allow_stale, histories=histories, licence=licence,
                progress=lambda done, total, msg: bar.update(task, completed=done, total=total, description=msg),
            )  # fmt: skip
    except (ValueError, LookupError) as e:
        _fail(str(e))
        return
    known = sum(Path(s).resolve() in histories for s in sessions)
    console.print(
        f"wrote release {escape(str(summary.out))}: {len(summary.session_ids)} session(s) ({', '.join(summary.session_ids)}), "
        f"{summary.n_files} files, {summary.size_bytes / 1e6:.1f} MB; annotation authors from the server for "
        f"{known}/{len(sessions)} session(s)"
        + ("" if licence else "; no --licence given: datasheet.md has a placeholder to fill"),
        soft_wrap=True,
    )


@app.command("validate")
def validate_cmd(release: Annotated[Path, typer.Argument(help="Release folder.")]) -> None:
    """Check a release against its checksums, JSON Schemas, NPZ layouts and cross-references;
    exit code 2 with the problems listed when it is invalid."""
    from pipeline.dataset import validate_release

    with console.status(f"validating {escape(str(release))}"):
        report = validate_release(release)
    kinds = ", ".join(f"{n} {k}" for k, n in sorted(report.kinds.items()))
    if report.ok:
        console.print(
            f"[bold green]valid[/]: {escape(str(release))} ({len(report.sessions)} session(s): {', '.join(report.sessions)}; "
            f"{report.n_files} files: {kinds})",
            soft_wrap=True,
        )
        return
    console.print(
        f"[bold red]invalid[/]: {escape(str(release))}: {len(report.problems)} problem(s) (file: problem)",
        soft_wrap=True,
    )
    for p in report.problems:
        console.print(f"  {p.file}: {p.message}", soft_wrap=True, markup=False, highlight=False)
    raise typer.Exit(code=2)
