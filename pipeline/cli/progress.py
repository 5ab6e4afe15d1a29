"""Rich progress bars and the end-of-run summary table for the CLI."""

from __future__ import annotations

from typing import Any

from rich.console import Console
from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

from pipeline.runner import StageReport

# The one metric per stage shown in the summary table (first key present wins).
KEY_METRICS: dict[str, tuple[str, ...]] = {
    "detect2d": ("detections", "valid_keypoints_pct"),
    "track": ("tracks",),
    "associate": ("identity_accuracy_pct", "persons", "mean_confidence"),
    "triangulate": ("median_reproj_px", "valid_pct"),
    "fit": ("mpjpe_vs_triangulation_mm", "loss_final"),
    "physics": ("penetration_max_mm", "real_time_factor"),
    "evaluate": ("mpjpe_mm", "pcp_pct"),
}


class RichProgress:
    """A ``ProgressSink`` drawing one bar per stage."""

    def __init__(self, console: Console) -> None:
        self.progress = Progress(
            SpinnerColumn(),
            TextColumn("[bold]{task.fields[stage]:<12}"),
            BarColumn(),
            TextColumn("{task.percentage:>5.1f}%"),
            TimeElapsedColumn(),
            TextColumn("{task.fields[message]}"),
            console=console,
            transient=False,
        )
        self.tasks: dict[str, Any] = {}

    def __enter__(self) -> RichProgress:
        self.progress.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.progress.__exit__(*exc)  # type: ignore[arg-type]

    def stage_started(self, stage: str, total: float | None) -> None:
        self.tasks[stage] = self.progress.add_task("", total=total or 1.0, stage=stage, message="running")

    def stage_progress(self, stage: str, done: float, total: float | None, message: str) -> None:
        if stage not in self.tasks:
            self.stage_started(stage, total)
        kw: dict[str, Any] = {"completed": done, "message": message}
        if total:
            kw["total"] = total
        self.progress.update(self.tasks[stage], **kw)

    def stage_finished(self, stage: str, status: str, duration_s: float, metrics: dict[str, Any]) -> None:
        if stage not in self.tasks:
            self.tasks[stage] = self.progress.add_task("", total=1.0, stage=stage, message="")
        t = self.progress.tasks[self.tasks[stage]] if isinstance(self.tasks[stage], int) else None
        total = t.total if t is not None and t.total else 1.0
        self.progress.update(self.tasks[stage], completed=total, total=total, message="fresh, skipped" if status == "skipped" else "done")


def key_metric(stage: str, metrics: dict[str, Any]) -> str:
    for k in KEY_METRICS.get(stage, ()):
        if k in metrics:
            v = metrics[k]
            return f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}"
    if metrics:
        k, v = next(iter(metrics.items()))
        return f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}"
    return ""


def summary_table(reports: list[StageReport]) -> Table:
    table = Table(title="cornerman pipeline summary")
    table.add_column("stage")
    table.add_column("action")
    table.add_column("time [s]", justify="right")
    table.add_column("key metric")
    for r in reports:
        table.add_row(r.stage, r.action, f"{r.duration_s:.2f}", key_metric(r.stage, r.metrics))
    return table


def rows_table(title: str, rows: list[dict[str, Any]]) -> Table:
    """A generic table of dict rows (benchmarks that do not bring their own printer)."""
    table = Table(title=title)
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    for c in cols:
        table.add_column(c)
    for r in rows:
        table.add_row(*[f"{r[c]:.4g}" if isinstance(r.get(c), float) else str(r.get(c, "")) for c in cols])
    return table
