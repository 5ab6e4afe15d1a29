"""The viewer's event list and timeline marks flag punches an annotator corrected or added."""

from __future__ import annotations

import dataclasses

import numpy as np

from tests.webui.fixtures import sample_events
from webui.events import HUMAN_MARK, EventsView


def test_human_made_punches_are_flagged() -> None:
    base, _ = sample_events(40)  # the three punches of the events-view tests
    ev = dataclasses.replace(base, punch_source=np.array(["detector", "corrected", "annotator"]))
    v = EventsView(ev, None, {0: "Red", 1: "Blue"})
    assert v.marks(0) == ((6, "J✓"), (28, f"RH✓{HUMAN_MARK}")) and v.marks(1) == ((15, f"C▪{HUMAN_MARK}"),)
    assert HUMAN_MARK not in v.label(0) and v.label(1).endswith(HUMAN_MARK)
    table = v.listing(np.arange(3))
    assert f"| Blue | cross {HUMAN_MARK} | ▪ blocked |" in table and "| Red | jab | ✓ landed |" in table
    assert table.endswith(f"{HUMAN_MARK} set or added by an annotator.")
    assert HUMAN_MARK not in v.listing(np.array([0]))
