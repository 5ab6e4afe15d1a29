"""Defence events (slips, ducks, blocks, parries) in the viewer: marks on the defender's row, the
Type filter, the list and the picker, next / previous, the legend and the summary cards."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import viser

from pipeline.schema.analytics import EVADE_KINDS, BoutEvents
from tests.webui.fixtures import build_session, sample_events, write_events
from webui.app import ViewerApp
from webui.events import DEFENCE_ABBREV, DEFENCE_MARK, HUMAN_MARK, LEGEND, EventsView
from webui.panels.event_chart import SERIES_COLORS
from webui.panels.events import NO_EVENT

RED, BLUE = 0, 1


def _with_defence(n_frames: int = 40) -> tuple[BoutEvents, object]:
    """Red: jab (missed, 6), rear hook (landed, 28), lead hook (missed, 34); Blue: cross (blocked, 15).
    Blue parries the jab, Red blocks the cross (an annotator corrected it), Blue ducks the lead hook."""
    base, series = sample_events(n_frames)
    ev = dataclasses.replace(
        base,
        punch_person=np.array([RED, BLUE, RED, RED]), punch_hand=np.array(["left", "right", "right", "left"]),
        punch_type=np.array(["jab", "cross", "rear_hook", "lead_hook"]), punch_start_frame=np.array([3, 12, 24, 31]),
        punch_peak_frame=np.array([6, 15, 28, 34]), punch_end_frame=np.array([9, 19, 32, 37]),
        punch_peak_speed_mps=np.array([7.5, 8.0, 6.5, 7.0]), punch_extension=np.array([0.95, 0.9, 0.7, 0.7]),
        punch_target=np.array(["none", "guard", "head", "none"]),
        punch_outcome=np.array(["missed", "blocked", "landed", "missed"]),
        punch_confidence=np.array([0.9, 0.8, 0.7, 0.6]),
        evade_person=np.array([BLUE, RED, BLUE]), evade_kind=np.array(["parry", "block", "duck"]),
        evade_start_frame=np.array([4, 13, 32]), evade_peak_frame=np.array([6, 15, 35]),
        evade_end_frame=np.array([8, 17, 37]), evade_displacement_m=np.array([0.12, 0.05, 0.15]),
        evade_punch=np.array([0, 1, 3]), evade_source=np.array(["detector", "corrected", "detector"]),
        punch_source=np.full(4, "detector"), clinch_source=np.zeros(0, dtype="<U1"),
    )  # fmt: skip
    return ev, series


def test_defence_filters_marks_list_picker_and_cards() -> None:
    ev, series = _with_defence()
    v = EventsView(ev, series, {RED: "Red", BLUE: "Blue"})  # type: ignore[arg-type]
    assert tuple(DEFENCE_ABBREV) == EVADE_KINDS
    assert all(f"{DEFENCE_MARK}{a} {k}" in LEGEND for k, a in DEFENCE_ABBREV.items())
    # Filters: athlete = the defender, type = the kind, outcome = that of the punch defended.
    assert v.defence_matching().tolist() == [0, 1, 2]
    assert v.defence_matching(kind="block").tolist() == [1] and v.defence_matching(
        athlete="Blue"
    ).tolist() == [0, 2]
    assert (
        v.defence_matching(outcome="blocked").tolist() == [1]
        and v.defence_matching(outcome="landed").size == 0
    )
    assert v.defence_matching(kind="jab").size == 0 and v.matching(punch_type="parry").size == 0
    # Marks on the defender's row, in frame order among the punches; the annotator's flag too.
    assert v.marks(BLUE) == ((6, "◇P"), (15, "C▪"), (35, "◇D"))
    assert v.marks(RED) == ((6, "J·"), (15, f"◇Bk{HUMAN_MARK}"), (28, "RH✓"), (34, "LH·"))
    blocks = v.defence_matching(kind="block")
    assert v.marks(RED, v.matching(punch_type="block"), blocks) == ((15, f"◇Bk{HUMAN_MARK}"),)
    # Next / previous: punches when any matches, else the defence rows.
    assert v.next_after(0, v.matching(), v.defence_matching()) == 6
    assert v.next_after(20, np.zeros(0, np.int64), v.defence_matching(kind="duck")) == 35
    assert v.prev_before(20, np.zeros(0, np.int64), v.defence_matching(athlete="Blue")) == 6
    # Picker: punches and defence in frame order; each label jumps to its frame.
    labels = v.picker_labels(v.matching(), v.defence_matching())
    assert [lab.split()[0] for lab in labels] == ["#1", "D1", "#2", "D2", "#3", "#4", "D3"]
    assert v.frame_of_label(labels[-1]) == 35 and v.frame_of_label(labels[2]) == 15
    assert "Blue parry ◇P vs Red's jab #1" in labels[1]
    assert v.frame_of_label("D9 nothing") is None and v.frame_of_label(NO_EVENT) is None
    # The list: a defence table after the punches.
    table = v.listing(v.matching(), v.defence_matching())
    assert f"| D2 | 0.60 | Red | ◇Bk block {HUMAN_MARK} | #2 Blue's cross | ▪ blocked | 0.05 |" in table
    assert "| D1 | 0.24 | Blue | ◇P parry | #1 Red's jab | · missed | 0.12 |" in table
    assert table.index("| # |") < table.index("| D# |")
    only = v.listing(np.zeros(0, np.int64), blocks)
    assert "| # |" not in only and "| D2 |" in only and "| D1 |" not in only
    assert v.listing(np.zeros(0, np.int64), np.zeros(0, np.int64)) == "No event matches the filters."
    cards = v.summary_cards()
    assert "0 slips, 0 ducks, 1 blocks, 0 parries" in cards.split("**Blue**")[0]  # Red's card
    assert "0 slips, 1 ducks, 0 blocks, 1 parries" in cards.split("**Blue**")[1]


def test_viewer_shows_defence_marks_and_filters_on_it(tmp_path: Path, server: viser.ViserServer) -> None:
    sdir = build_session(tmp_path, n_frames=40)
    app = ViewerApp(server, sdir, role="coach", max_image_width=160)
    try:
        ev, series = _with_defence(40)
        write_events(sdir, ev, series)
        app.reload()
        h = app.events
        assert [mk.label for mk in h.rows[BLUE]._marks] == ["◇P", "C▪", "◇D"]
        defence = h.chart.data[1 + list(SERIES_COLORS).index("defence")]  # the event chart's purple points
        row = {p: k + 1.0 for k, p in enumerate(h.rows)}
        assert np.flatnonzero(np.isfinite(defence)).tolist() == [6, 15, 35]
        assert defence[6] == defence[35] == row[BLUE] and defence[15] == row[RED]
        assert "◇Bk block" in h.listing.content and h.legend.content == LEGEND
        assert "1 blocks" in h.summary.content and "1 parries" in h.summary.content
        assert "parry" in h.type.options and "jab" in h.type.options
        h.type.value = "duck"
        assert [mk.label for mk in h.rows[BLUE]._marks] == ["◇D"] and h.rows[RED]._marks is None
        assert len(h.event.options) == 2 and "| # |" not in h.listing.content
        h.next.value = True  # no punch is a duck: Next visits the ducks
        assert app.frame == 35
        h.type.value = "All"
        h.event.value = next(o for o in h.event.options if o.startswith("D2 "))
        assert app.frame == 15
    finally:
        app.close()
