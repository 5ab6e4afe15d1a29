"""Boxing events: one row of marks per athlete under the timeline, previous / next punch, and
(in the Events tab) filters, the legend, the matching punches and defence, and the summary cards.

Each athlete row is a slider over the frames whose marks are that athlete's punches (label:
type and outcome, e.g. ``J✓``) and defence (``◇`` and the kind, e.g. ``◇Bk`` a block, at the
defence's peak); it follows the frame slider, and moving it (or clicking on the row) moves
the frame. viser's marks carry text only, so the outcome is a symbol (✓ landed, ▪ blocked,
· missed) rather than a colour (``webui.events.LEGEND``); the event chart under the rows shows
the same events coloured by outcome (``webui.panels.event_chart``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import viser
from viser._messages import GuiSliderMark

from pipeline.schema.analytics import EVADE_KINDS, OUTCOMES, PUNCH_TYPES
from webui.events import ALL, LEGEND, EventsView
from webui.panels.event_chart import make_event_chart, set_event_chart
from webui.scope import Scope


@dataclass
class EventRows:
    """What ``make_event_rows`` puts under the timeline."""

    rows: dict[int, viser.GuiSliderHandle[int]]
    """Athlete id -> his row of marks."""
    prev: viser.GuiButtonHandle
    next: viser.GuiButtonHandle
    chart: viser.GuiUplotHandle
    """The event chart (``webui.panels.event_chart``), rows in ``rows``' order."""


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
    legend: viser.GuiMarkdownHandle
    chart: viser.GuiUplotHandle
    """The event chart under the rows (``webui.panels.event_chart``)."""
    layout: viser.GuiMarkdownHandle
    """The camera-layout advice (``pipeline.geometry.layout``), shown only when there is one."""


NO_EVENT = "(pick an event to jump to it)"
TYPE_OPTIONS: tuple[str, ...] = (ALL, *(t.replace("_", " ") for t in PUNCH_TYPES), *EVADE_KINDS)
"""The Type filter: every event, a punch type, or a defence kind."""


def make_event_rows(server: Scope, athletes: list[tuple[int, str]], n_frames: int, fps: float) -> EventRows:
    """The per-athlete event rows, the previous / next punch buttons and the event chart (under
    the timeline); ``fps`` (> 0) the bout's frame rate."""
    rows = {
        pid: server.gui.add_slider(f"{name} punches", min=0, max=max(1, n_frames - 1), step=1, initial_value=0,
                                   hint=f"{name}'s punches and defence; click to jump. {LEGEND}")  # fmt: skip
        for pid, name in athletes
    }
    also = " (or defence, when the Type filter is a defence kind)"
    prev = server.gui.add_button("Previous punch", hint=f"Jump to the previous punch matching the Events filters{also}")
    nxt = server.gui.add_button("Next punch", hint=f"Jump to the next punch matching the Events filters{also}")
    return EventRows(rows, prev, nxt, make_event_chart(server, athletes, n_frames, fps))


def make_events(
    server: Scope,
    athletes: list[str],
    rows: EventRows,
    layout_advice: str = "",
) -> EventsHandles:
    """Filters, the event picker, the legend, the list and the summary (call it inside the Events
    tab), with the rows and buttons ``make_event_rows`` made under the timeline; above them the
    ``layout_advice`` when there is one (cameras that see depth poorly miss punches)."""
    layout = server.gui.add_markdown(f"⚠ **Camera layout.** {layout_advice}", visible=bool(layout_advice))
    athlete = server.gui.add_dropdown("Athlete", (ALL, *athletes), initial_value=ALL,
                                      hint="Who threw the punch, or who defended")  # fmt: skip
    kind = server.gui.add_dropdown("Type", TYPE_OPTIONS, initial_value=ALL, hint="A punch type or a defence kind")
    outcome = server.gui.add_dropdown("Outcome", (ALL, *OUTCOMES), initial_value=ALL,
                                      hint="Of the punch (for defence: of the punch defended)")  # fmt: skip
    event = server.gui.add_dropdown("Event", (NO_EVENT,), initial_value=NO_EVENT)
    legend = server.gui.add_markdown(LEGEND)
    listing = server.gui.add_markdown("")
    summary = server.gui.add_markdown("")
    return EventsHandles(rows.rows, rows.prev, rows.next, athlete, kind, outcome, event, listing, summary, legend, rows.chart,
                         layout)  # fmt: skip


def matching_rows(h: EventsHandles, view: EventsView) -> Any:
    """Punch rows passing the filters."""
    return view.matching(h.athlete.value, h.type.value, h.outcome.value)


def matching_defence(h: EventsHandles, view: EventsView) -> Any:
    """Defence rows passing the filters."""
    return view.defence_matching(h.athlete.value, h.type.value, h.outcome.value)


def set_events(h: EventsHandles, view: EventsView, n_frames: int, fps: float) -> None:
    """Show ``view``: the marks of each athlete's row, the event chart, the picker, the list, the
    summary (``fps`` > 0, the bout's frame rate)."""
    rows, defence = matching_rows(h, view), matching_defence(h, view)
    for pid, row in h.rows.items():
        row.max = max(1, n_frames - 1)
        marks = view.marks(pid, rows, defence)
        # Marks are set after creation like the timeline's (``panels.timeline.set_problems``).
        row._marks = tuple(GuiSliderMark(value=float(v), label=lab) for v, lab in marks) or None
    set_event_chart(h.chart, view, list(h.rows), n_frames, fps, rows, defence)
    h.event.options = (NO_EVENT, *view.picker_labels(rows, defence))
    h.event.value = NO_EVENT  # type: ignore[misc]
    h.listing.content = view.listing(rows, defence)
    h.summary.content = view.summary_cards()
    h.prev.disabled = h.next.disabled = view.jump_frames(rows, defence).size == 0


def wire_events(h: EventsHandles, get_view: Callable[[], EventsView], get_frame: Callable[[], int],
                set_frame: Callable[[int], None], n_frames: Callable[[], int], fps: Callable[[], float]) -> None:  # fmt: skip
    """Thin callbacks: filters refresh the panel, rows / picker / buttons move the frame."""

    def refresh(_: Any) -> None:
        set_events(h, get_view(), n_frames(), fps())

    for d in (h.athlete, h.type, h.outcome):
        d.on_update(refresh)

    def jump(which: str) -> Callable[[Any], None]:
        def cb(_: Any) -> None:
            view = get_view()
            rows, defence = matching_rows(h, view), matching_defence(h, view)
            f = (view.next_after if which == "next" else view.prev_before)(get_frame(), rows, defence)
            if f is not None:
                set_frame(f)

        return cb

    h.next.on_click(jump("next"))
    h.prev.on_click(jump("prev"))

    @h.event.on_update
    def _(_: Any) -> None:
        f = get_view().frame_of_label(h.event.value) if h.event.value != NO_EVENT else None
        if f is not None:
            set_frame(f)

    for row in h.rows.values():
        row.on_update(lambda e: set_frame(int(e.target.value)) if int(e.target.value) != get_frame() else None)


def follow_frame(h: EventsHandles, frame: int) -> None:
    """Keep every athlete row at the current frame (no-op when it already is)."""
    for row in h.rows.values():
        if int(row.value) != frame:
            row.value = frame  # type: ignore[misc]
