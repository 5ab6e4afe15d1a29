"""The viewer's boxing events: per-athlete punch rows, the event chart, filters, next / previous punch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import viser

from tests.webui.fixtures import build_session, sample_events, wait_for, write_events
from webui.app import ViewerApp
from webui.events import EventsView
from webui.panels.event_chart import SERIES_COLORS


def test_events_view_filters_jumps_and_marks() -> None:
    ev, series = sample_events(40)
    v = EventsView(ev, series, {0: "Red", 1: "Blue"})
    assert v.matching().tolist() == [0, 1, 2]
    assert v.matching(athlete="Red", outcome="landed").tolist() == [0, 2]
    assert v.matching(punch_type="rear hook").tolist() == [2] and v.matching(outcome="missed").size == 0
    rows = v.matching()
    assert v.next_after(6, rows) == 15 and v.next_after(28, rows) == 6  # wraps around
    assert v.prev_before(15, rows) == 6 and v.prev_before(6, rows) == 28
    assert v.next_after(0, np.zeros(0, dtype=int)) is None
    assert v.marks(0) == ((6, "J✓"), (28, "RH✓")) and v.marks(1, v.matching(athlete="Red")) == ()
    assert "rear hook" in v.label(2) and "Red" in v.label(2)
    assert "| 2 | 0.60 | Blue | cross | ▪ blocked | guard | 8.0 |" in v.listing(rows)
    cards = v.summary_cards()
    assert "**Red** — 2 punches: 2 landed" in cards and "Clinches: 0." in cards
    assert "has not run" in EventsView(None, None, {}).listing(rows)


def test_viewer_event_rows_filters_and_punch_buttons(tmp_path: Path, server: viser.ViserServer) -> None:
    sdir = build_session(tmp_path, n_frames=40)
    app = ViewerApp(server, sdir, role="coach", max_image_width=160)
    try:
        assert app.events.listing.content.startswith("No analytics yet")
        write_events(sdir, *sample_events(40))
        app.reload()
        h = app.events
        assert sorted(h.rows) == [0, 1]
        assert [(mk.value, mk.label) for mk in h.rows[0]._marks] == [(6.0, "J✓"), (28.0, "RH✓")]
        assert [mk.label for mk in h.rows[1]._marks] == ["C▪"]
        assert "**Red**" in h.summary.content
        h.next.value = True  # the button click
        assert app.frame == 6 and all(int(r.value) == 6 for r in h.rows.values())
        h.next.value = True
        assert app.frame == 15
        h.prev.value = True
        assert app.frame == 6
        h.outcome.value = "landed"
        assert len(h.event.options) == 3 and "blocked" not in h.listing.content
        h.next.value = True
        assert app.frame == 28  # the blocked cross is filtered out
        h.event.value = h.event.options[1]  # pick the jab in the list
        assert app.frame == 6
        h.rows[1].value = 20  # clicking on Blue's row moves the frame
        assert app.frame == 20 and int(app.timeline.frame.value) == 20
    finally:
        app.close()


def test_event_chart_points_follow_the_filters_and_keep_the_cursor(tmp_path: Path, server: viser.ViserServer) -> None:
    ev, series = sample_events(40)
    v = EventsView(ev, series, {0: "Red", 1: "Blue"})
    pts = v.chart_rows([0, 1], 40)
    assert {k: np.flatnonzero(np.isfinite(a)).tolist() for k, a in pts.items()} == {
        "landed": [6, 28], "blocked": [15], "missed": [], "defence": []}  # fmt: skip
    assert pts["landed"][6] == pts["landed"][28] == 1.0 and pts["blocked"][15] == 2.0  # Red row 1, Blue row 2
    assert np.isfinite(v.chart_rows([1, 0], 40)["landed"]).sum() == 2 and v.chart_rows([1, 0], 40)["landed"][6] == 2.0
    assert all(np.isnan(a).all() for a in EventsView(None, None, {}).chart_rows([0, 1], 40).values())

    sdir = build_session(tmp_path, n_frames=40)
    write_events(sdir, ev, series)
    app = ViewerApp(server, sdir, role="coach", max_image_width=160)
    try:
        chart = app.events.chart
        t, *ys = chart.data
        assert len(ys) == len(SERIES_COLORS) and np.allclose(t, np.arange(40) / app.data.fps)
        landed = ys[list(SERIES_COLORS).index("landed")]
        assert np.flatnonzero(np.isfinite(landed)).tolist() == [6, 28]
        assert [s.get("points", {}).get("fill") for s in chart.series[1:]] == list(SERIES_COLORS.values())
        assert chart.axes is not None and chart.axes[1]["values"] == ("Red", "Blue")
        app.set_frame(15)  # the cursor line is drawn on the event chart too, beside its named rows
        at_15 = (15 / app.data.fps,)
        assert wait_for(lambda: len(chart.axes or ()) == 3 and chart.axes[-1]["splits"] == at_15, timeout_s=20)
        assert chart.axes[1]["values"] == ("Red", "Blue")
        app.events.outcome.value = "blocked"  # the chart follows the Events filters, as the mark rows
        _, *ys = chart.data
        assert [np.flatnonzero(np.isfinite(y)).tolist() for y in ys] == [[], [15], [], []]
        assert chart.axes[-1]["splits"] == at_15 and chart.axes[1]["values"] == ("Red", "Blue")  # the cursor stays
    finally:
        app.close()


def test_the_events_tab_warns_when_no_two_cameras_see_depth_well(tmp_path: Path, server: viser.ViserServer) -> None:
    for n_views, warned in ((2, True), (3, False)):  # the fixture's cameras are evenly spread: 2 face each other
        sdir = build_session(tmp_path / f"v{n_views}", n_frames=12, n_views=n_views)
        app = ViewerApp(server, sdir, role="coach", max_image_width=160)
        try:
            layout = app.events.layout
            assert layout.visible is warned
            if warned:
                assert layout.content.startswith("⚠ **Camera layout.** cam1 and cam2 look ")
                assert "(facing each other)" in layout.content
        finally:
            app.close()
