"""The event chart under the timeline: one row per athlete, a point at each punch's strike
coloured by its outcome (``OUTCOME_COLORS``: the report's colours) and one at each defence's
peak (``DEFENCE_COLOR``), with the plots' current-frame line (``PlotCursor``).

It shows what the athletes' mark rows show (the same Events filters), in colour: viser's
slider marks carry text only. viser's charts take no clicks, so jumping stays with the mark
rows, the Event picker and previous / next punch.
"""

from __future__ import annotations

import numpy as np
import viser
import viser.uplot as vup

from pipeline.schema.analytics import OUTCOME_COLORS
from webui.events import DEFENCE_COLOR, DEFENCE_SERIES, EventsView
from webui.scope import Scope

CHART_TITLE = "Punches (strike) and defence"
CHART_HEIGHT_PX = 130
"""Height of the chart (CSS pixels, > 0)."""
POINT_SIZE_PX = 9.0
"""Diameter of an event's point (CSS pixels, > 0)."""
SERIES_COLORS: dict[str, str] = {**OUTCOME_COLORS, DEFENCE_SERIES: DEFENCE_COLOR}
"""Colour of each series of the chart (``EventsView.chart_rows`` keys)."""
CHART_LEGEND_HTML = (
    '<div style="font-size: 0.8em; padding: 0 0.75em">'
    + " · ".join(f'<span style="color: {c}; font-size: 1.4em">●</span> {k}' for k, c in SERIES_COLORS.items())
    + "</div>"
)
"""The legend under the chart, in the series' colours (uPlot's own legend draws its swatches
with the line's width, 0 here)."""


def chart_series() -> tuple[vup.Series, ...]:
    """The x series, then one points-only series per outcome and one for defence (no line: a
    series' points are single frames, so no two are ever joined)."""
    out: list[vup.Series] = [vup.Series(label="time (s)")]
    for key, color in SERIES_COLORS.items():
        points: vup.Series_Points = {"show": True, "size": POINT_SIZE_PX, "fill": color, "stroke": "#222222", "width": 1}
        out.append(vup.Series(label=key, stroke=color, width=0, points=points))
    return tuple(out)


def chart_axes(names: list[str]) -> tuple[vup.Axis, vup.Axis]:
    """The default time axis and a y axis naming one row per athlete (row k + 1 = ``names[k]``)."""
    y: vup.Axis = {"scale": "y", "splits": tuple(float(k + 1) for k in range(len(names))), "values": tuple(names)}
    return {}, y


def chart_scales(n_rows: int, n_frames: int, fps: float) -> dict[str, vup.Scale]:
    """Fixed ranges: the whole bout in seconds (as the plots), and the athletes' rows."""
    dur = max(n_frames - 1, 1) / fps
    return {
        "x": vup.Scale(time=False, auto=False, range=(0.0, dur)),
        "y": vup.Scale(auto=False, range=(0.5, max(n_rows, 1) + 0.5)),
    }


def chart_data(
    view: EventsView, pids: list[int], n_frames: int, fps: float, rows: np.ndarray | None, defence: np.ndarray | None
) -> tuple[np.ndarray, ...]:
    """(time s, then one array per ``SERIES_COLORS`` key) for ``view``'s events of ``rows`` / ``defence``."""
    n = max(int(n_frames), 2)
    ys = view.chart_rows(pids, n, rows, defence)
    return (np.arange(n) / fps, *(ys[k] for k in SERIES_COLORS))


def make_event_chart(scope: Scope, athletes: list[tuple[int, str]], n_frames: int, fps: float) -> viser.GuiUplotHandle:
    """The chart with no events yet (``set_event_chart`` fills it), and its legend under it."""
    pids, names = [p for p, _ in athletes], [n for _, n in athletes]
    empty = EventsView(None, None, {})
    chart = scope.gui.add_uplot(
        chart_data(empty, pids, n_frames, fps, None, None), chart_series(), title=CHART_TITLE,
        scales=chart_scales(len(pids), n_frames, fps), axes=chart_axes(names), height=CHART_HEIGHT_PX,
        legend=vup.Legend(show=False),
    )  # fmt: skip
    scope.gui.add_html(CHART_LEGEND_HTML)
    return chart


def set_event_chart(
    chart: viser.GuiUplotHandle, view: EventsView, pids: list[int], n_frames: int, fps: float,
    rows: np.ndarray | None, defence: np.ndarray | None,
) -> None:  # fmt: skip
    """Show ``view``'s events of ``rows`` / ``defence`` on ``chart``, keeping its current-frame line."""
    chart.scales = chart_scales(len(pids), n_frames, fps)
    cursor = tuple(chart.axes[2:]) if chart.axes else ()
    chart.axes = (*chart_axes([view.name(p) for p in pids]), *cursor)
    chart.data = chart_data(view, pids, n_frames, fps, rows, defence)
