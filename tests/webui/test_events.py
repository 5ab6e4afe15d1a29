"""The viewer's boxing events: per-athlete punch rows, filters, next / previous punch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import viser

from pipeline.artifacts import ArtifactStore, Manifest
from pipeline.schema.analytics import AthleteSeries, BoutEvents
from tests.webui.fixtures import build_session
from webui.app import ViewerApp
from webui.events import EventsView


def _events(n_frames: int) -> tuple[BoutEvents, AthleteSeries]:
    ev = BoutEvents.empty(25.0, np.array([0, 1]))
    ev = BoutEvents(**{
        **ev.__dict__, "punch_person": np.array([0, 1, 0]), "punch_hand": np.array(["left", "right", "right"]),
        "punch_type": np.array(["jab", "cross", "rear_hook"]), "punch_start_frame": np.array([3, 12, 24]),
        "punch_peak_frame": np.array([6, 15, 28]), "punch_end_frame": np.array([9, 19, 32]),
        "punch_peak_speed_mps": np.array([7.5, 8.0, 6.5]), "punch_extension": np.array([0.95, 0.9, 0.7]),
        "punch_target": np.array(["head", "guard", "head"]), "punch_outcome": np.array(["landed", "blocked", "landed"]),
        "punch_confidence": np.array([0.9, 0.8, 0.7]),
    })  # fmt: skip
    f = n_frames
    series = AthleteSeries(
        frame_indices=np.arange(f), fps=25.0, person_ids=np.array([0, 1]), valid=np.ones((f, 2), bool),
        distance_m=np.full(f, 1.2), distance_valid=np.ones(f, bool), stance=np.ones((f, 2), np.int64),
        stance_width_m=np.full((f, 2), 0.5), guard_height_m=np.zeros((f, 2, 2)), punches_per_min=np.zeros((f, 2)),
    )  # fmt: skip
    return ev, series


def test_events_view_filters_jumps_and_marks() -> None:
    ev, series = _events(40)
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
        ev, series = _events(40)
        m = Manifest(stage="analyze", code_version="test", config={}, config_hash="0", inputs={}, metrics={"source": "filtered"})
        ArtifactStore(sdir).write(m, {"events": ev, "series": series})
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
