"""The bout report's new parts on the hand-made analysed bout, with the ring and three rounds in
session.json: blocks, parries and ring-zone rows in the summary tables, and the fatigue section
(table and chart) holding the summary's numbers."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

from pipeline.report import ReportData, load_report_data, render_report
from pipeline.stages.analyze import AnalyzeOutput, summarize
from pipeline.stages.analyze.zones import RING_ZONES
from tests.report.fixtures import write_analysed_bout
from tests.report.helpers import number, parse

RING = [[-1.6, -1.6], [1.6, -1.6], [1.6, 1.6], [-1.6, 1.6]]  # small: the boxers reach every zone
ROUNDS = [[0.0, 4.0], [4.0, 8.0], [8.0, 12.0]]


@pytest.fixture(scope="module")
def bout(tmp_path_factory: pytest.TempPathFactory) -> tuple[AnalyzeOutput, ReportData, dict]:
    folder = tmp_path_factory.mktemp("report_fatigue") / "bout"
    out = write_analysed_bout(folder)
    d = json.loads((folder / "session.json").read_text())
    d.update(rounds_s=ROUNDS, ring_xy_m=RING)
    (folder / "session.json").write_text(json.dumps(d))
    data = load_report_data(folder)
    summary = summarize(out.events, out.series, {0: "Red", 1: "Blue"}, ring_xy_m=RING, rounds_s=data.rounds_s)
    return out, data, summary


def test_summary_table_has_blocks_parries_and_ring_zones(
    bout: tuple[AnalyzeOutput, ReportData, dict],
) -> None:
    out, data, summary = bout
    assert "block" in out.events.evade_kind.tolist()  # the fixture's jabs on the guard are blocked
    table = parse(render_report(data)).find_all("table", **{"class": "summary"})[0]
    for a in summary["athletes"]:
        for key in ("blocks", "parries", *(f"ring_{z}_pct" for z in RING_ZONES)):
            cell = table.find_all("td", data_key=key, data_athlete=str(a["person_id"]), data_period="bout")[0]
            assert number(cell.text) == pytest.approx(a[key]), (key, cell.text, a[key])
        shares = [a[f"ring_{z}_pct"] for z in RING_ZONES]
        assert sum(shares) == pytest.approx(100.0, abs=0.3) and max(shares) < 90.0  # they move around
    assert sum(a["blocks"] for a in summary["athletes"]) == int((out.events.evade_kind == "block").sum())
    # the per-round tables carry the zones too, and the rounds add up to the bout
    root = parse(render_report(data))
    for pid in (0, 1):
        t = root.find_all("table", data_athlete=str(pid), **{"class": "periods"})[0]
        per = [number(t.find_all("td", data_key="blocks", data_period=str(k))[0].text) for k in range(3)]
        assert sum(per) == summary["athletes"][pid]["blocks"]  # type: ignore[arg-type]
        assert t.find_all("td", data_key="ring_ropes_pct", data_period="0")
    # without the ring in the session, the zones read "—"
    bare = parse(render_report(replace(data, ring_xy_m=None))).find_all("table", **{"class": "summary"})[0]
    assert bare.find_all("td", data_key="ring_centre_pct", data_athlete="0")[0].text.strip() == "—"


def test_fatigue_section_table_and_chart(bout: tuple[AnalyzeOutput, ReportData, dict]) -> None:
    _, data, summary = bout
    html = render_report(data)
    root = parse(html)
    assert [s.attrs["id"] for s in root.find_all("section")].index("fatigue") == 2
    charts = root.find_all("svg", data_chart="fatigue")
    assert sorted(c.attrs["data-athlete"] for c in charts) == ["0", "1"]
    for a in summary["athletes"]:
        pid = a["person_id"]
        table = root.find_all("table", data_athlete=str(pid), **{"class": "fatigue"})[0]
        chart = [c for c in charts if c.attrs["data-athlete"] == str(pid)][0]
        for key in ("peak_speed_median_mps", "guard_height_median_m", "punches_per_min"):
            values = [p[key] for p in a["by_period"]]
            cells = [table.find_all("td", data_key=key, data_period=str(k))[0].text.strip() for k in range(3)]
            assert cells == ["—" if v is None else f"{v:g}" for v in values], (key, cells, values)
            trend = a["fatigue"][key]
            assert table.find_all("td", data_key=key, data_period="trend")[0].text.strip() == trend["trend"]
            dots = [m for m in chart.find_all("g", **{"class": "mark"}) if m.attrs["data-key"] == key]
            assert [float(d.attrs["data-value"]) for d in dots] == [v for v in values if v is not None]
            lines = [m for m in chart.find_all("g", **{"class": "trend"}) if m.attrs["data-key"] == key]
            if trend["slope_per_min"] is None:
                assert (
                    not lines
                    and table.find_all("td", data_key=key, data_period="slope")[0].text.strip() == "—"
                )
            else:
                assert len(lines) == 1 and float(lines[0].attrs["data-slope"]) == trend["slope_per_min"]
                assert lines[0].attrs["data-trend"] == trend["trend"] in ("rising", "falling", "flat")
    # guard heights are known in every round: three points and a trend for both athletes
    assert all(a["fatigue"]["guard_height_median_m"]["periods"] == 3 for a in summary["athletes"])
    assert "least-squares slope" in html
