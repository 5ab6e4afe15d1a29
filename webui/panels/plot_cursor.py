"""A current-frame cursor on the plots: a vertical line at the view's frame time on every chart.

The line is the grid of an extra x axis without labels whose only split is the cursor's
time (``cursor_axes``). Moving it sends about 250 bytes per chart whatever the bout's length,
where a cursor series would re-send every curve of the chart. The browser rebuilds a chart
when its axes change (8-11 ms per chart in headless software Chromium while the Plots tab is
open, under 2 ms when it is hidden), so while a view plays ``PlotCursor`` moves the line at
most ``PLAY_CURSOR_HZ`` times per second; paused, it is at the exact frame.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import viser
import viser.uplot as vup

from webui.panels.plots import PlotsHandles

PLAY_CURSOR_HZ = 4.0
"""Cursor moves per second at most while playing (> 0); paused, every frame change moves it."""
CURSOR_COLOR = "#000000"
"""Colour of the cursor line (CSS)."""
CURSOR_WIDTH_PX = 1.5
"""Width of the cursor line (CSS pixels)."""


def cursor_axes(time_s: float, base: tuple[vup.Axis, ...] = ({}, {})) -> tuple[vup.Axis, ...]:
    """The axes of a chart with the cursor at ``time_s`` (s, the charts' x unit): the chart's own
    x and y axes ``base`` (default: uPlot's, whose colours the viewer's theme fills), and the
    cursor's axis last."""
    if not math.isfinite(time_s):
        raise ValueError(f"cursor_axes: time_s must be finite, got {time_s}")
    cursor: vup.Axis = {
        "scale": "x",
        "side": 0,  # top, with no size: it takes no room from the plot
        "size": 0,
        "splits": (float(time_s),),
        "values": ("",),
        "grid": {"show": True, "stroke": CURSOR_COLOR, "width": CURSOR_WIDTH_PX},
        "ticks": {"show": False},
        "border": {"show": False},
    }
    return (*base, cursor)


def cursor_time_s(chart: viser.GuiUplotHandle) -> float | None:
    """Where ``chart``'s cursor is (s), as last sent to the browser; None before the first move."""
    axes = chart.axes
    if not axes or len(axes) < 3:
        return None
    splits = axes[-1].get("splits")
    return float(splits[0]) if splits else None


def plot_charts(h: PlotsHandles) -> tuple[viser.GuiUplotHandle, ...]:
    """Every chart of the Plots tab (each ``GuiUplotHandle`` field of ``h``, in field order)."""
    charts = (getattr(h, f.name) for f in dataclasses.fields(h))
    return tuple(c for c in charts if isinstance(c, viser.GuiUplotHandle))


@dataclass
class PlotCursor:
    """The cursor of one view's plots (each client has its own charts, hence its own cursor).

    Fields:
        charts: the charts it is drawn on (``plot_charts``).
        clock: seconds of a monotonic clock (``time.monotonic``; tests pass a fake one).
        play_hz: moves per second at most while playing (> 0).
    """

    charts: Sequence[viser.GuiUplotHandle]
    clock: Callable[[], float] = time.monotonic
    play_hz: float = PLAY_CURSOR_HZ
    time_s: float | None = None
    """Where the cursor is now (s); None before the first move."""
    moves: int = 0
    """Moves sent so far (tests and the bench)."""
    _moved_at: float = field(default=-math.inf, repr=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.play_hz) and self.play_hz > 0):
            raise ValueError(f"PlotCursor.play_hz must be positive, got {self.play_hz}")

    def show(self, time_s: float, playing: bool) -> bool:
        """Put the cursor at ``time_s`` (s); while ``playing``, only when ``1 / play_hz`` seconds
        have passed since the last move. Returns whether it moved (nothing is sent when it is
        already there or the move is skipped)."""
        if time_s == self.time_s:
            return False
        now = self.clock()
        if playing and now - self._moved_at < 1.0 / self.play_hz:
            return False
        for chart in self.charts:
            chart.axes = cursor_axes(time_s, tuple(chart.axes[:2]) if chart.axes else ({}, {}))
        self.time_s, self._moved_at = float(time_s), now
        self.moves += 1
        return True
