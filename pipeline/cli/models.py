"""``cornerman models``: list, download and verify the registry's models."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, DownloadColumn, Progress, TransferSpeedColumn
from rich.table import Table

from pipeline.registry import MODELS, UNKNOWN_SHA256, cache_dir, download_model, find_model, verify_file

app = typer.Typer(no_args_is_help=True, help="Model registry: list, download, verify.")
console = Console()

ModelsDir = Annotated[
    Path | None,
    typer.Option("--models-dir", help="Folder to use (default: CORNERMAN_MODELS_DIR, then the cache)."),
]


@app.command("list")
def list_models(models_dir: ModelsDir = None) -> None:
    """Every known model, where it is found, and its source."""
    t = Table(title=f"models (cache: {cache_dir()})")
    for c in ("name", "task", "decoder", "input", "licence", "sha256", "found at"):
        t.add_column(c)
    for m in MODELS.values():
        p = find_model(m.name, models_dir)
        sha = "trust on first use" if m.sha256 == UNKNOWN_SHA256 else m.sha256[:12] + "…"
        t.add_row(
            m.name, m.task, m.decoder, f"{m.input_size_hw[0]}x{m.input_size_hw[1]}", m.licence, sha,
            str(p) if p else ("-" if m.url else "(manual: not published as ONNX)"),
        )  # fmt: skip
    console.print(t)


@app.command()
def download(
    name: Annotated[str, typer.Argument(help="Model name (see `cornerman models list`).")],
    models_dir: ModelsDir = None,
    force: Annotated[bool, typer.Option("--force", help="Download again even if present.")] = False,
) -> None:
    """Download a model (resumes interrupted downloads; verifies the sha256)."""
    if name not in MODELS:
        console.print(f"[bold red]error:[/] unknown model {name!r}; known: {', '.join(sorted(MODELS))}")
        raise typer.Exit(code=2)
    if not MODELS[name].url:
        console.print(f"[bold red]error:[/] {name} is not downloadable: {MODELS[name].source}")
        raise typer.Exit(code=2)
    with Progress(
        *Progress.get_default_columns()[:1], BarColumn(), DownloadColumn(), TransferSpeedColumn()
    ) as prog:
        task = prog.add_task(name, total=None)
        try:
            p = download_model(
                name, models_dir, lambda done, total: prog.update(task, completed=done, total=total), force
            )
        except ValueError as e:
            console.print(f"[bold red]error:[/] {e}")
            raise typer.Exit(code=1) from e
    console.print(f"[green]ok[/] {name} -> {p}")


@app.command()
def verify(models_dir: ModelsDir = None) -> None:
    """Check the sha256 of every model present; exit code 1 on any mismatch."""
    t = Table()
    for c in ("name", "file", "status"):
        t.add_column(c)
    bad = False
    for m in MODELS.values():
        p = find_model(m.name, models_dir)
        if p is None:
            t.add_row(m.name, "-", "absent")
            continue
        try:
            verify_file(m, p)
            t.add_row(m.name, str(p), "[green]ok[/]")
        except ValueError:
            bad = True
            t.add_row(m.name, str(p), "[red]MISMATCH[/]")
    console.print(t)
    if bad:
        raise typer.Exit(code=1)
