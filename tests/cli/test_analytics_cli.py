"""``cornerman analyze`` and ``cornerman export --events`` on a tiny session."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from pipeline.cli.main import app
from tests.conftest import write_tiny_session

runner = CliRunner()


def test_analyze_prints_the_summary_and_export_writes_events(tmp_path: Path) -> None:
    s = write_tiny_session(tmp_path / "s", stages=("detect2d", "track", "associate", "triangulate", "analyze"))
    r = runner.invoke(app, ["analyze", str(s), "--no-run"])
    assert r.exit_code == 2 and "has not run" in r.output
    r = runner.invoke(app, ["export", str(s), "--events", "csv"])
    assert r.exit_code == 2 and "has not run" in r.output
    r = runner.invoke(app, ["analyze", str(s), "--json", str(tmp_path / "summary.json")])
    assert r.exit_code == 0, r.output
    assert "boxing" in r.output and "punches thrown" in r.output and "Red" in r.output and "Blue" in r.output
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["source"] == "filtered" and [a["person_id"] for a in summary["athletes"]] == [0, 1]
    r = runner.invoke(app, ["export", str(s), "--events", "csv"])
    assert r.exit_code == 0, r.output
    assert (s / "events.csv").read_text().startswith("event,athlete_id,athlete,start_frame")
    r = runner.invoke(app, ["export", str(s), "--events", "json", "-o", str(tmp_path / "ev.json")])
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "ev.json").read_text())
    assert doc["format"] == "cornerman.events/v1" and doc["source"] == "filtered" and "punches" in doc
    for args, msg in (
        (["--events", "xml"], "csv or json"),
        (["--events", "csv", "-o", str(tmp_path)], "is a folder"),
        (["--events", "csv", "-o", str(tmp_path / "no" / "e.csv")], "does not exist"),
        (["--events", "csv", "--calibration"], "give one"),
    ):
        r = runner.invoke(app, ["export", str(s), *args])
        assert r.exit_code == 2 and msg in r.output, (args, r.output)
