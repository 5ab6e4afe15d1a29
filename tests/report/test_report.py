"""The bout report (pipeline.report) on a hand-made analysed bout: its numbers are the
analyze summary's, its periods add up to the bout, its charts hold one mark per event,
it is self-contained and printable; and ``cornerman report`` on a session the runner analysed."""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from pipeline.report import ReportData, ReportOptions, load_report_data, render_report, slice_bout
from pipeline.report.html import SUMMARY_ROWS
from pipeline.schema.analytics import OUTCOME_COLORS, OUTCOMES, PUNCH_TYPES, BoutEvents
from pipeline.stages.analyze import AnalyzeOutput, summarize
from tests.report.fixtures import write_analysed_bout
from tests.report.helpers import Element, number, parse, svgs


@pytest.fixture(scope="module")
def bout(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, AnalyzeOutput, ReportData]:
    folder = tmp_path_factory.mktemp("report") / "bout"
    out = write_analysed_bout(folder)
    return folder, out, load_report_data(folder)


def _charts(root: Element, kind: str) -> list[Element]:
    return root.find_all("svg", data_chart=kind)


def test_the_data_is_a_real_bout(bout: tuple[Path, AnalyzeOutput, ReportData]) -> None:
    _, out, data = bout
    ev = out.events
    # The fixture must exercise every outcome and both athletes, or the checks below prove little.
    assert set(ev.punch_outcome.tolist()) == set(OUTCOMES) and set(ev.punch_person.tolist()) == {0, 1}
    assert data.names == {0: "Red", 1: "Blue"} and data.source == "fit" and data.title == "sparring test"
    assert data.positions_valid is not None and data.positions_valid.all()


def test_summary_tables_show_the_analyze_summary(bout: tuple[Path, AnalyzeOutput, ReportData]) -> None:
    _, out, data = bout
    root = parse(render_report(data))
    summary = summarize(out.events, out.series, {0: "Red", 1: "Blue"})
    table = root.find_all("table", **{"class": "summary"})[0]
    for a in summary["athletes"]:
        for key, _ in SUMMARY_ROWS:
            cells = table.find_all("td", data_key=key, data_athlete=str(a["person_id"]), data_period="bout")
            assert len(cells) == 1, key
            got, want = number(cells[0].text), a.get(key)
            assert got == (float(want) if isinstance(want, int | float) else want), (
                a["name"],
                key,
                got,
                want,
            )
        types = root.find_all("table", data_athlete=str(a["person_id"]), **{"class": "types"})[0]
        for t in PUNCH_TYPES:
            rows = types.find_all("tr", data_type=t)
            assert len(rows) == (1 if a["types"][t] else 0), t
            if rows:
                n = {
                    c.attrs["data-key"]: number(c.text)
                    for c in rows[0].find_all("td")
                    if "data-key" in c.attrs
                }
                assert n["thrown"] == a["types"][t] == sum(n[o] for o in OUTCOMES), (t, n)  # type: ignore[misc]
    header = root.find_all("header")[0].text
    assert (
        "sparring test" in header
        and "Red" in header
        and "Blue" in header
        and "12.0 s" in header
        and "fit" in header
    )


def test_periods_add_up_to_the_bout(bout: tuple[Path, AnalyzeOutput, ReportData]) -> None:
    _, out, data = bout
    html = render_report(data, ReportOptions(period_s=4.0))
    root = parse(html)
    assert "split into 4 s periods" in html
    for pid in (0, 1):
        table = root.find_all("table", data_athlete=str(pid), **{"class": "periods"})[0]
        for key in (
            "punches",
            "punches_landed",
            "punches_blocked",
            "punches_missed",
            "slips",
            "ducks",
            "clinch_s",
        ):
            per = [number(table.find_all("td", data_key=key, data_period=str(k))[0].text) for k in range(3)]
            whole = number(table.find_all("td", data_key=key, data_period="bout")[0].text)
            assert sum(per) == pytest.approx(whole, abs=0.02), (pid, key, per, whole)  # type: ignore[arg-type]
        assert not table.find_all("td", data_period="3")
    # The punches of a span are those whose strike lies in it.
    ev, fps = out.events, out.series.fps
    for k in range(3):
        sub, series = slice_bout(ev, out.series, 4.0 * k, 4.0 * (k + 1))
        assert sub.n_punches == int(
            np.sum((ev.punch_peak_frame >= 200 * k) & (ev.punch_peak_frame < 200 * (k + 1)))
        )
        assert series.n_frames == int(4.0 * fps)
    with pytest.raises(ValueError, match="no analysed frame"):
        slice_bout(ev, out.series, 20.0, 24.0)


def _marks(chart: Element) -> list[Element]:
    """The chart's tagged data marks: matplotlib artists written as ``<g class="mark" data-*>``."""
    return chart.find_all("g", **{"class": "mark"})


def _fill(mark: Element) -> str:
    """The fill colour matplotlib wrote on the mark's path."""
    fills = {
        m
        for p in mark.find_all("path")
        for m in re.findall(r"fill: (#[0-9a-f]{6})", p.attrs.get("style", ""))
    }
    assert len(fills) == 1, (mark.attrs, fills)
    return fills.pop()


def test_charts_have_one_mark_per_event_and_labelled_axes(
    bout: tuple[Path, AnalyzeOutput, ReportData],
) -> None:
    _, out, data = bout
    ev, opts = out.events, ReportOptions()
    html = render_report(data, opts)
    root = parse(html)
    assert len(svgs(html)) == 4 * 2 + 1  # every chart is well-formed XML
    for kind in ("punch-map", "ring-heatmap", "speed-histogram"):
        assert sorted(c.attrs["data-athlete"] for c in _charts(root, kind)) == ["0", "1"], kind
    assert len(_charts(root, "work-rate")) == 1
    for pid in (0, 1):
        mine = ev.punch_person == pid
        dots = _marks(_charts(root, "punch-map")[pid])
        assert len(dots) == int(np.sum(mine & (ev.punch_target != "none")))
        for o in OUTCOMES:
            assert sum(d.attrs["data-outcome"] == o for d in dots) == int(
                np.sum(mine & (ev.punch_target != "none") & (ev.punch_outcome == o))
            )
        assert all(_fill(d) == OUTCOME_COLORS[d.attrs["data-outcome"]] for d in dots)
        for t in ("head", "body", "guard"):
            assert sum(d.attrs["data-target"] == t for d in dots) == int(
                np.sum(mine & (ev.punch_target == t))
            )
        bars = _marks(_charts(root, "speed-histogram")[pid])
        for o in OUTCOMES:
            assert sum(int(b.attrs["data-count"]) for b in bars if b.attrs["data-outcome"] == o) == int(
                np.sum(mine & (ev.punch_outcome == o))
            )
        assert all(_fill(b) == OUTCOME_COLORS[b.attrs["data-outcome"]] for b in bars)
        rate = [b for b in _marks(_charts(root, "work-rate")[0]) if b.attrs["data-athlete"] == str(pid)]
        assert len(rate) == math.ceil(data.duration_s / opts.bin_s) and sum(
            int(b.attrs["data-count"]) for b in rate
        ) == int(mine.sum())
        assert all(_fill(b) == data.color_of(pid) for b in rate)
        cells = _marks(_charts(root, "ring-heatmap")[pid])
        assert data.positions_valid is not None
        seconds = sum(float(c.attrs["data-seconds"]) for c in cells)
        assert seconds == pytest.approx(data.positions_valid[:, pid].sum() / data.series.fps, rel=1e-6)
        assert len(cells) > 4  # the athlete moved around
    # Clinches (the fixture has none): one grey band each, over their seconds (end frame inclusive).
    f0 = int(data.series.frame_indices[0])
    clinched = replace(
        ev, clinch_start_frame=np.array([f0 + 100, f0 + 400]), clinch_end_frame=np.array([f0 + 149, f0 + 424])
    )
    rate_chart = _charts(parse(render_report(replace(data, events=clinched), opts)), "work-rate")[0]
    bands = rate_chart.find_all("g", **{"class": "clinch"})
    assert [(float(b.attrs["data-t0"]), float(b.attrs["data-t1"])) for b in bands] == [(2.0, 3.0), (8.0, 8.5)]
    assert not _charts(root, "work-rate")[0].find_all("g", **{"class": "clinch"})
    for kind, units in (("ring-heatmap", "(m)"), ("speed-histogram", "(m/s)"), ("work-rate", "(s)")):
        for chart in _charts(root, kind):
            labels = [
                g.text.strip() for c in ("xlabel", "ylabel") for g in chart.find_all("g", **{"class": c})
            ]
            assert len(labels) == 2 and units in labels[0], (kind, labels)
            # matplotlib kept the labels as text (svg.fonttype none), not glyph outlines
            assert all(any(t.text.strip() == lab for t in chart.find_all("text")) for lab in labels), labels
    assert "ring unknown" in html and len(root.find_all("g", **{"class": "ring bbox"})) == 2
    assert not root.find_all("g", **{"class": "ring"})


def test_self_contained_and_printable(bout: tuple[Path, AnalyzeOutput, ReportData]) -> None:
    html = render_report(bout[2])
    assert html.startswith("<!doctype html>")
    for outside in (
        "<script",
        "<link",
        " src=",
        "@import",
        "http://",
        "https://",
        "xlink:",
        "<?xml",
        "<!DOCTYPE",
    ):
        assert outside not in html, outside
    assert not re.findall(r"url\((?!#)", html)  # only references to elements of the page (clip paths)
    ids = re.findall(r'\bid="([^"]+)"', html)
    assert len(ids) > 100 and len(ids) == len(set(ids))  # several matplotlib SVGs on one page share no id
    refs = set(re.findall(r'(?:url\(#|href="#)([^")]+)', html))
    assert refs and refs <= set(ids), refs - set(ids)  # every clip path and marker it uses is on the page
    assert render_report(bout[2]) == html  # deterministic: fixed hash salt, no date in the SVG
    css = parse(html).find_all("style")[0].text
    assert "@media print" in css and "size:A4" in css and "break-before:page" in css
    sections = parse(html).find_all("section")
    assert [s.attrs["id"] for s in sections] == [
        "summary",
        "rounds",
        "fatigue",
        "punch-maps",
        "ring",
        "speeds",
        "work-rate",
    ]


def test_given_rounds_and_ring_and_missing_parts(bout: tuple[Path, AnalyzeOutput, ReportData]) -> None:
    data = bout[2]
    ring = np.array([[-3.0, -3.0], [3.0, -3.0], [3.0, 3.0], [-3.0, 3.0]])
    html = render_report(replace(data, ring_xy_m=ring, rounds_s=((0.0, 5.0), (6.0, 12.0))))
    root = parse(html)
    assert "Rounds from the session" in html and "round 2" in html and "ring unknown" not in html
    rings = root.find_all("g", **{"class": "ring"})
    assert len(rings) == 2 and not root.find_all("g", **{"class": "ring bbox"})
    # the ring's four corners, drawn closed, in the same place in both heatmaps
    assert all(len(re.findall(r"[ML] ", r.find_all("path")[0].attrs["d"])) == 5 for r in rings)
    empty = BoutEvents.empty(data.series.fps, data.series.person_ids)
    html = render_report(replace(data, events=empty, positions_xy_m=None, positions_valid=None))
    assert html.count("threw no punch") == 2 * 2 and "no 3D positions" in html  # types + histograms
    root = parse(html)
    for kind in ("punch-map", "speed-histogram", "ring-heatmap"):
        assert len(_charts(root, kind)) == 2 and not any(_marks(c) for c in _charts(root, kind)), kind
    rate = _marks(_charts(root, "work-rate")[0])
    assert len(rate) == 2 * math.ceil(data.duration_s / 10.0) and all(
        r.attrs["data-count"] == "0" for r in rate
    )
    with pytest.raises(ValueError, match="period_s"):
        ReportOptions(period_s=0.0)
    with pytest.raises(ValueError, match="rounds_s"):
        replace(data, rounds_s=((5.0, 2.0),))


def test_cli_report_on_a_session_the_runner_analysed(tmp_path: Path) -> None:
    from pipeline.cli.main import app
    from pipeline.runner import run
    from tests.conftest import write_tiny_session

    s = write_tiny_session(
        tmp_path / "s", stages=("detect2d", "track", "associate", "triangulate", "analyze"), n_frames=30
    )
    runner = CliRunner()
    r = runner.invoke(app, ["report", str(s), "--out", str(tmp_path / "r.html")])
    assert r.exit_code == 2 and "analyze stage has not run" in r.output and not (tmp_path / "r.html").exists()
    run(s)
    r = runner.invoke(app, ["report", str(s), "--out", str(tmp_path / "no" / "r.html")])
    assert r.exit_code == 2 and "does not exist" in r.output
    r = runner.invoke(app, ["report", str(s), "--out", str(tmp_path / "r.html"), "--bin-s", "0.2"])
    assert r.exit_code == 0, r.output
    html = (tmp_path / "r.html").read_text()
    root = parse(html)
    assert len(svgs(html)) == 9 and "tiny — bout report" in html
    data = load_report_data(s)
    assert data.source == "filtered" and data.positions_valid is not None and data.positions_valid.any()
    rate = _marks(_charts(root, "work-rate")[0])
    assert len(rate) == 2 * math.ceil(data.duration_s / 0.2 - 1e-9)
    assert sum(int(b.attrs["data-count"]) for b in rate) == data.events.n_punches


def test_rounds_and_ring_come_from_session_json(tmp_path: Path) -> None:
    import json

    from pipeline.schema import SessionConfig

    folder = tmp_path / "bout"
    write_analysed_bout(folder)
    d = json.loads((folder / "session.json").read_text())
    d.update(rounds_s=[[0, 4], [5, 9.5]], ring_xy_m=[[-3, -3], [3, -3], [3, 3], [-3, 3]])
    (folder / "session.json").write_text(json.dumps(d))
    data = load_report_data(folder)
    assert (
        data.rounds_s == ((0.0, 4.0), (5.0, 9.5))
        and data.ring_xy_m is not None
        and data.ring_xy_m.shape == (4, 2)
    )
    html = render_report(data)
    assert "Rounds from the session" in html and "round 2" in html and "ring unknown" not in html
    for bad, why in (({"rounds_s": [[4, 2]]}, "rounds_s"), ({"rounds_s": [[0, 5], [3, 8]]}, "overlapping"),
                     ({"ring_xy_m": [[0, 0], [1, 1]]}, "ring_xy_m"), ({"rounds_s": "1-2"}, "number pairs")):  # fmt: skip
        with pytest.raises(ValueError, match=why):
            SessionConfig.from_dict({**d, **bad})


def test_the_report_names_a_camera_layout_that_sees_depth_poorly(tmp_path: Path) -> None:
    from pipeline.io.calibration import save_toml
    from tests.conftest import make_rig

    folder = tmp_path / "bout"
    write_analysed_bout(folder)
    assert load_report_data(folder).layout_advice == ""  # no calibration file: nothing to say
    assert "Camera layout" not in render_report(load_report_data(folder))
    (folder / "inputs").mkdir(exist_ok=True)
    save_toml(make_rig(2), folder / "inputs" / "calibration.toml")  # two cameras on opposite sides
    data = load_report_data(folder)
    assert data.layout_advice.startswith("cam1 and cam2 look ") and "(facing each other)" in data.layout_advice
    note = parse(render_report(data)).find_all("p", **{"class": "note layout"})
    assert len(note) == 1 and "⚠ Camera layout: cam1 and cam2 look" in note[0].text
    save_toml(make_rig(3), folder / "inputs" / "calibration.toml")
    assert load_report_data(folder).layout_advice == ""
