"""The viewer's event list and timeline marks flag punches an annotator corrected or added."""

from __future__ import annotations

import numpy as np

from pipeline.schema.analytics import BoutEvents
from webui.events import HUMAN_MARK, EventsView


def test_human_made_punches_are_flagged() -> None:
    ev = BoutEvents.empty(25.0, np.array([0, 1]))
    ev = BoutEvents(**{
        **ev.__dict__, "punch_person": np.array([0, 1, 0]), "punch_hand": np.array(["left", "right", "right"]),
        "punch_type": np.array(["jab", "cross", "rear_hook"]), "punch_start_frame": np.array([3, 12, 24]),
        "punch_peak_frame": np.array([6, 15, 28]), "punch_end_frame": np.array([9, 19, 32]),
        "punch_peak_speed_mps": np.array([7.5, 8.0, 6.5]), "punch_extension": np.array([0.95, 0.9, 0.7]),
        "punch_target": np.array(["head", "guard", "head"]), "punch_outcome": np.array(["landed", "blocked", "landed"]),
        "punch_confidence": np.array([0.9, 0.8, 0.7]), "punch_source": np.array(["detector", "corrected", "annotator"]),
    })  # fmt: skip
    v = EventsView(ev, None, {0: "Red", 1: "Blue"})
    assert v.marks(0) == ((6, "J✓"), (28, f"RH✓{HUMAN_MARK}")) and v.marks(1) == ((15, f"C▪{HUMAN_MARK}"),)
    assert HUMAN_MARK not in v.label(0) and v.label(1).endswith(HUMAN_MARK)
    table = v.listing(np.arange(3))
    assert f"| Blue | cross {HUMAN_MARK} | ▪ blocked |" in table and "| Red | jab | ✓ landed |" in table
    assert table.endswith(f"{HUMAN_MARK} set or added by an annotator.")
    assert HUMAN_MARK not in v.listing(np.array([0]))
