"""``cornerman analyze`` prints blocks, parries, the ring zones (session.json's ring) and the
fatigue table per round (its round times; per minute without them)."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.stages.analyze import summarize
from tests.report.fixtures import write_analysed_bout

runner = CliRunner()


def test_analyze_prints_ring_zones_blocks_and_fatigue(tmp_path: Path) -> None:
    s = tmp_path / "bout"
    out = write_analysed_bout(s)
    r = runner.invoke(
        app, ["analyze", str(s), "--no-run", "--json", str(tmp_path / "a.json")], env={"COLUMNS": "240"}
    )
    assert r.exit_code == 0, r.output
    assert "blocks" in r.output and "parries" in r.output and "ring centre %" in r.output
    assert "fatigue indicators per minute" in r.output and "0:00–0:12" in r.output
    bare = json.loads((tmp_path / "a.json").read_text())
    assert bare["athletes"][0]["ring_centre_pct"] is None and bare["period_kind"] == "periods"
    d = json.loads((s / "session.json").read_text())
    ring, rounds = [[-1.6, -1.6], [1.6, -1.6], [1.6, 1.6], [-1.6, 1.6]], [[0.0, 6.0], [6.0, 12.0]]
    d.update(ring_xy_m=ring, rounds_s=rounds)
    (s / "session.json").write_text(json.dumps(d))
    r = runner.invoke(
        app, ["analyze", str(s), "--no-run", "--json", str(tmp_path / "b.json")], env={"COLUMNS": "240"}
    )
    assert r.exit_code == 0, r.output
    assert "fatigue indicators per round" in r.output and "round 2" in r.output
    got = json.loads((tmp_path / "b.json").read_text())
    want = summarize(
        out.events, out.series, {0: "Red", 1: "Blue"}, ring_xy_m=ring, rounds_s=((0.0, 6.0), (6.0, 12.0))
    )
    for g, w in zip(got["athletes"], want["athletes"], strict=True):
        assert g["ring_ropes_pct"] == w["ring_ropes_pct"] is not None and g["blocks"] == w["blocks"]
        assert g["fatigue"] == w["fatigue"] and len(g["by_period"]) == 2
        trend = g["fatigue"]["punches_per_min"]
        line = next(x for x in r.output.splitlines() if f"{g['name']}: punches / min" in x)
        assert trend["trend"] in line and f"{trend['slope_per_min']:+g}" in line, line
