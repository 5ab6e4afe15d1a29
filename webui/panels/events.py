"""Boxing events: one row of punch marks per athlete under the timeline, previous / next
punch, and (in the Events tab) filters, the matching punches and the summary cards.

Each athlete row is a slider over the frames whose marks are that athlete's punches
(label: type and outcome, e.g. ``J✓``); it follows the frame slider, and moving it (or
clicking on the row) moves the frame. viser's marks carry text only, so the outcome is a
symbol (✓ landed, ▪ blocked, · missed) rather than a colour.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import viser
from viser._messages import GuiSliderMark

from pipeline.schema.analytics import OUTCOMES, PUNCH_TYPES
from webui.events import ALL, EventsView
from webui.scope import Scope


@dataclass
class EventsHandles:
    rows: dict[int, viser.GuiSliderHandle[int]]
    prev: viser.GuiButtonHandle
    next: viser.GuiButtonHandle
    athlete: viser.GuiDropdownHandle[str]
    type: viser.GuiDropdownHandle[str]
    outcome: viser.GuiDropdownHandle[str]
    event: viser.GuiDropdownHandle[str]
    listing: viser.GuiMarkdownHandle
    summary: viser.GuiMarkdownHandle


NO_EVENT = "(pick a punch to jump to it)"


def make_event_rows(server: Scope, athletes: list[tuple[int, str]], n_frames: int) -> tuple[
    dict[int, viser.GuiSliderHandle[int]], viser.GuiButtonHandle, viser.GuiButtonHandle
]:  # fmt: skip
    """The per-athlete punch rows and the previous / next punch buttons (under the timeline)."""
    rows = {
        pid: server.gui.add_slider(f"{name} punches", min=0, max=max(1, n_frames - 1), step=1, initial_value=0,
                                   hint=f"{name}'s punches (✓ landed, ▪ blocked, · missed); click to jump")  # fmt: skip
        for pid, name in athletes
    }
    prev = server.gui.add_button("Previous punch", hint="Jump to the previous punch matching the Events filters")
    nxt = server.gui.add_button("Next punch", hint="Jump to the next punch matching the Events filters")
    return rows, prev, nxt


def make_events(
    server: Scope,
    athletes: list[str],
    rows: tuple[dict[int, viser.GuiSliderHandle[int]], viser.GuiButtonHandle, viser.GuiButtonHandle],
) -> EventsHandles:
    """Filters, the punch picker, the list and the summary (call it inside the Events tab),
    with the rows and buttons ``make_event_rows`` made under the timeline."""
    athlete = server.gui.add_dropdown("Athlete", (ALL, *athletes), initial_value=ALL)
    kind = server.gui.add_dropdown("Type", (ALL, *(t.replace("_", " ") for t in PUNCH_TYPES)), initial_value=ALL)
    outcome = server.gui.add_dropdown("Outcome", (ALL, *OUTCOMES), initial_value=ALL)
    event = server.gui.add_dropdown("Punch", (NO_EVENT,), initial_value=NO_EVENT)
    listing = server.gui.add_markdown("")
    summary = server.gui.add_markdown("")
    return EventsHandles(rows[0], rows[1], rows[2], athlete, kind, outcome, event, listing, summary)


def matching_rows(h: EventsHandles, view: EventsView) -> Any:
    return view.matching(h.athlete.value, h.type.value, h.outcome.value)


def set_events(h: EventsHandles, view: EventsView, n_frames: int) -> None:
    """Show ``view``: the marks of each athlete's row, the picker, the list, the summary."""
    rows = matching_rows(h, view)
    for pid, row in h.rows.items():
        row.max = max(1, n_frames - 1)
        marks = view.marks(pid, rows)
        # Marks are set after creation like the timeline's (``panels.timeline.set_problems``).
        row._marks = tuple(GuiSliderMark(value=float(v), label=lab) for v, lab in marks) or None
    labels = tuple(view.label(int(i)) for i in rows)
    h.event.options = (NO_EVENT, *labels)
    h.event.value = NO_EVENT  # type: ignore[misc]
    h.listing.content = view.listing(rows)
    h.summary.content = view.summary_cards()
    h.prev.disabled = h.next.disabled = rows.size == 0


def wire_events(h: EventsHandles, get_view: Callable[[], EventsView], get_frame: Callable[[], int],
                set_frame: Callable[[int], None], n_frames: Callable[[], int]) -> None:  # fmt: skip
    """Thin callbacks: filters refresh the panel, rows / picker / buttons move the frame."""

    def refresh(_: Any) -> None:
        set_events(h, get_view(), n_frames())

    for d in (h.athlete, h.type, h.outcome):
        d.on_update(refresh)

    def jump(which: str) -> Callable[[Any], None]:
        def cb(_: Any) -> None:
            view = get_view()
            rows = matching_rows(h, view)
            f = view.next_after(get_frame(), rows) if which == "next" else view.prev_before(get_frame(), rows)
            if f is not None:
                set_frame(f)

        return cb

    h.next.on_click(jump("next"))
    h.prev.on_click(jump("prev"))

    @h.event.on_update
    def _(_: Any) -> None:
        if h.event.value == NO_EVENT or not h.event.value.startswith("#"):
            return
        i = int(h.event.value.split()[0][1:]) - 1
        ev = get_view().events
        if ev is not None and 0 <= i < ev.n_punches:
            set_frame(int(ev.punch_peak_frame[i]))

    for row in h.rows.values():
        row.on_update(lambda e: set_frame(int(e.target.value)) if int(e.target.value) != get_frame() else None)


def follow_frame(h: EventsHandles, frame: int) -> None:
    """Keep every athlete row at the current frame (no-op when it already is)."""
    for row in h.rows.values():
        if int(row.value) != frame:
            row.value = frame  # type: ignore[misc]
