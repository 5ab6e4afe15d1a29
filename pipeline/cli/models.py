"""``cornerman models``: list, download and verify the registry's models.

``cornerman models`` alone (or ``cornerman models list``) shows every model, which ones a
video session needs, the folders they are looked up in and how to get each one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.progress import BarColumn, DownloadColumn, Progress, TransferSpeedColumn
from rich.table import Table

from pipeline.registry import (
    MODELS,
    UNKNOWN_SHA256,
    download_model,
    find_model,
    get_model,
    how_to_get,
    labelled_search_dirs,
    verify_file,
)
from pipeline.shared import MODELS_ENV, shared_models_dir

app = typer.Typer(
    invoke_without_command=True, help="Model registry: list (the default), download, verify."
)
console = Console()

ModelsDir = Annotated[
    Path | None,
    typer.Option(
        "--models-dir",
        help=f"Folder searched first (then the shared models folder, ${MODELS_ENV}, then the cache).",
    ),
]


def session_models(cfg: Any = None) -> list[tuple[str, str]]:
    """``(role, registry name)`` of the model files a video session needs with ``cfg`` (a
    ``Detect2DConfig``; default: its defaults, the one place they are set)."""
    from pipeline.stages.detect2d import Detect2DConfig

    cfg = cfg if cfg is not None else Detect2DConfig()
    out = [("person detector (detector)", cfg.detector), ("keypoint model (pose_model)", cfg.pose_model)]
    foot = getattr(cfg, "foot_model", "none")
    if foot not in ("none", cfg.pose_model):
        out.append(("foot keypoints (foot_model)", foot))
    return out


@app.callback()
def models_main(ctx: typer.Context, models_dir: ModelsDir = None) -> None:
    """Model registry: with no command, the same as `cornerman models list`."""
    if ctx.invoked_subcommand is None:
        list_models(models_dir)


@app.command("list")
def list_models(models_dir: ModelsDir = None) -> None:
    """Every known model, the ones a video session needs, where they are looked up and how to get them."""
    t = Table(title="known models")
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

    console.print("\n[bold]A video session needs[/] (session.json stage_config.detect2d; other models: set "
                  "detector / pose_model there):")  # fmt: skip
    for role, name in session_models():
        info = get_model(name)
        p = find_model(name, models_dir)
        if p is not None:
            console.print(f"  [green]found[/]   {role}: {name} -> {p}", soft_wrap=True)
        else:
            console.print(f"  [red]missing[/] {role}: {name} ({info.filename}); {how_to_get(info)}", soft_wrap=True)

    console.print("\n[bold]Model files are looked up in[/] (first hit wins):")
    for i, (label, d) in enumerate(labelled_search_dirs(models_dir), start=1):
        state = "" if d.is_dir() else "  (does not exist yet)"
        console.print(f"  {i}. {d}  — {label}{state}", soft_wrap=True)
    if shared_models_dir() is None:
        console.print(
            f"  (no shared models folder: set {MODELS_ENV} to a folder of .onnx files to use one)", soft_wrap=True
        )
    console.print(
        "A session uses its own folder with `cornerman new … --models-dir DIR` or `cornerman run … --models-dir DIR` "
        "(stored as session.json stage_config.detect2d.models_dir).",
        soft_wrap=True,
    )


@app.command()
def download(
    name: Annotated[str, typer.Argument(help="Model name (see `cornerman models list`).")],
    models_dir: ModelsDir = None,
    force: Annotated[bool, typer.Option("--force", help="Download again even if present.")] = False,
) -> None:
    """Download a model (resumes interrupted downloads; verifies the sha256).

    The name may be spelled with ``-`` or ``_`` in any case (``rtmpose-m``)."""
    try:
        info = get_model(name)
    except ValueError as e:
        console.print(f"[bold red]error:[/] {e}", soft_wrap=True)
        raise typer.Exit(code=2) from e
    name = info.name
    if not info.url:
        console.print(f"[bold red]error:[/] {name} is not downloadable: {info.source}", soft_wrap=True)
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
            console.print(f"[bold red]error:[/] {e}", soft_wrap=True)
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
