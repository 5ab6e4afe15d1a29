"""`cornerman --help` lists each command by its docstring's first paragraph on one line."""

from __future__ import annotations

import re

import typer
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.cli.summaries import one_line_summaries, summary

WIDE = {"COLUMNS": "400", "TERMINAL_WIDTH": "400"}


def _rows(output: str) -> dict[str, str]:
    """Command name -> its description, from a wide help screen's command panel."""
    rows = {}
    for line in output.splitlines():
        m = re.match(r"│ (\S+)\s{2,}(.*?)\s*│$", line)
        if m:
            rows[m.group(1)] = m.group(2)
    return rows


def test_summary_joins_the_first_paragraph() -> None:
    doc = """Print the summary: punches, speeds,
    slips and   ducks.

    Details that stay on the command's own help page."""
    assert summary(doc) == "Print the summary: punches, speeds, slips and ducks."


def test_wrapped_docstrings_list_on_one_row() -> None:
    out = CliRunner().invoke(app, ["--help"], env=WIDE).output
    rows = _rows(out)
    # analyze's docstring wraps after "work rate," and report's after "timeline)"
    assert "speeds, work rate, slips, ducks, blocks" in rows["analyze"], out
    assert "work-rate timeline) to print or save as PDF." in rows["report"], out
    assert rows["export"].endswith("with --events csv|json the boxing events."), out
    sub = _rows(CliRunner().invoke(app, ["dataset", "--help"], env=WIDE).output)
    assert sub["validate"].endswith("exit code 2 with the problems listed when it is invalid."), sub


def test_an_explicit_short_help_is_kept() -> None:
    demo = typer.Typer()

    @demo.command(short_help="Short.")
    def one() -> None:
        """A long
        wrapped help."""

    @demo.command()
    def two() -> None:
        """Two
        lines."""

    one_line_summaries(demo)
    assert [c.short_help for c in demo.registered_commands] == ["Short.", "Two lines."]
