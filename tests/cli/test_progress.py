"""Progress lines where no terminal draws bars (logs, pipes, batch jobs)."""

from __future__ import annotations

import io
import re
from pathlib import Path

import pytest
from rich.console import Console
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.cli.progress import LineProgress, RichProgress, key_metric, progress_for
from tests.conftest import write_tiny_session


def test_lines_at_start_and_end_and_at_most_one_per_interval() -> None:
    now = [100.0]
    out = io.StringIO()
    sink = LineProgress(Console(file=out, width=200), every_s=30.0, clock=lambda: now[0])
    with sink:
        sink.stage_started("fit", 10.0)
        for t, done in ((101.0, 1), (129.0, 2), (131.0, 3), (140.0, 4), (162.0, 5)):
            now[0] = t
            sink.stage_progress("fit", done, 10.0, "frames")
        sink.stage_finished("fit", "ran", 62.04, {"reproj_median_px": 3.25, "other": 1})
        sink.stage_finished("track", "skipped", 0.0, {})
    lines = [re.sub(r"^\d\d:\d\d:\d\d ", "", ln) for ln in out.getvalue().splitlines()]
    assert lines == [
        "fit: started",
        "fit: 30 %, frames",  # 31 s after the start; 1 s and 29 s were too soon
        "fit: 50 %, frames",  # 31 s after the last line
        "fit: done in 62.0 s (reproj_median_px = 3.25)",
        "track: fresh, skipped",
    ]


def test_bars_on_a_terminal_lines_elsewhere() -> None:
    assert isinstance(progress_for(Console(file=io.StringIO())), LineProgress)
    assert isinstance(progress_for(Console(file=io.StringIO(), force_terminal=True)), RichProgress)
    with pytest.raises(ValueError, match="every_s must be > 0"):
        LineProgress(Console(), every_s=0)


def test_cornerman_run_into_a_pipe_says_each_stage(tmp_path: Path) -> None:
    s = write_tiny_session(tmp_path / "s", stages=("detect2d", "track", "associate", "triangulate"))
    r = CliRunner().invoke(app, ["run", str(s)])
    assert r.exit_code == 0, r.output
    for stage in ("detect2d", "track", "associate", "triangulate"):
        assert re.search(rf"^\d\d:\d\d:\d\d {stage}: started$", r.output, re.M), r.output
        assert re.search(rf"^\d\d:\d\d:\d\d {stage}: done in \d+\.\d s", r.output, re.M), r.output
    assert "cornerman pipeline summary" in r.output


def test_a_physics_run_says_how_many_frames_it_reused() -> None:
    """An incremental physics run that re-planned nothing takes a second: its real-time factor
    (0.35 on the Pose2Sim sample) only makes sense next to the frames it reused."""
    m = {"body_penetration_max_mm": 0.0, "realtime_factor": 0.35, "residual_force_mean_frac_bw": 0.73,
         "reused_frames": 100, "replanned_windows": 0}  # fmt: skip
    assert key_metric("physics", m).endswith("realtime_factor = 0.35, residual_force_mean_frac_bw = 0.73, reused_frames = 100")
