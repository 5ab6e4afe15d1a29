"""Progress of a run for the CLI (bars on a terminal, lines in a log or pipe) and the end-of-run
summary table."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

from pipeline.runner import StageReport

# The one metric per stage shown in the summary table (first key present wins).
KEY_METRICS: dict[str, tuple[str, ...]] = {
    "detect2d": ("detections", "valid_keypoints_pct"),
    "track": ("tracks", "edits_applied"),
    "associate": ("persons", "mean_confidence", "edits_applied"),
    "triangulate": ("reproj_median_px", "mean_views", "person_frames_min_pct"),
    "fit": ("reproj_median_px", "residual_3d_mm"),
    "physics": ("body_penetration_max_mm", "realtime_factor", "residual_force_mean_frac_bw", "reused_frames"),
    "analyze": ("punches", "clinches"),
    "evaluate": ("identity_accuracy_pct", "mpjpe_mm_filtered", "mpjpe_mm_fit", "mpjpe_mm_physics"),
}
"""The metrics shown per stage in the summary table (those present, in this order)."""


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


class LineProgress:
    """A ``ProgressSink`` printing a line when a stage starts and ends, and in between at most one
    line per ``every_s`` seconds (> 0) per stage. For logs and pipes, where rich draws its bars only
    once, at the end of the run."""

    def __init__(self, console: Console, every_s: float = 30.0, clock: Callable[[], float] = time.monotonic) -> None:
        if not every_s > 0:
            raise ValueError(f"LineProgress: every_s must be > 0, got {every_s}")
        self.console, self.every_s, self.clock = console, every_s, clock
        self.last: dict[str, float] = {}

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def _say(self, text: str) -> None:
        self.console.print(f"{time.strftime('%H:%M:%S')} {text}", markup=False, highlight=False, soft_wrap=True)

    def stage_started(self, stage: str, total: float | None) -> None:
        self.last[stage] = self.clock()
        self._say(f"{stage}: started")

    def stage_progress(self, stage: str, done: float, total: float | None, message: str) -> None:
        now = self.clock()
        if stage in self.last and now - self.last[stage] < self.every_s:
            return
        self.last[stage] = now
        part = f"{100.0 * done / total:.0f} %" if total else f"{done:g}"
        self._say(f"{stage}: {part}" + (f", {message}" if message else ""))

    def stage_finished(self, stage: str, status: str, duration_s: float, metrics: dict[str, Any]) -> None:
        self.last.pop(stage, None)
        what = "fresh, skipped" if status == "skipped" else f"done in {duration_s:.1f} s"
        metric = key_metric(stage, metrics)
        self._say(f"{stage}: {what}" + (f" ({metric})" if metric else ""))


def progress_for(console: Console) -> RichProgress | LineProgress:
    """Bars when ``console`` is a terminal, else lines (``LineProgress``)."""
    return RichProgress(console) if console.is_terminal else LineProgress(console)


def _fmt(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def key_metric(stage: str, metrics: dict[str, Any]) -> str:
    """Up to four of the stage's key metrics as ``name = value`` pairs."""
    keys = [k for k in KEY_METRICS.get(stage, ()) if k in metrics][:4]
    if not keys and metrics:
        keys = [next(iter(metrics))]
    return ", ".join(f"{k} = {_fmt(metrics[k])}" for k in keys)


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
