"""The report's charts, drawn with matplotlib and inlined as SVG: punch maps, ring-position
heatmaps, peak-speed histograms and the work-rate timeline.

Every data mark is its own artist tagged with ``svg.Marks``: in the SVG it is a
``<g class="mark">`` with ``data-*`` attributes holding the number it shows (``data-count``,
``data-seconds``) and a tooltip, so a test or a script can read a chart back.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.cm import ScalarMappable
from matplotlib.colors import LinearSegmentedColormap, Normalize, to_rgb
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, FancyBboxPatch, Patch, PathPatch, Polygon, Rectangle
from matplotlib.path import Path as MplPath
from matplotlib.ticker import MaxNLocator, MultipleLocator

from pipeline.report.data import ReportData, ReportOptions
from pipeline.report.svg import Marks, figure, inline_svg
from pipeline.schema.analytics import OUTCOME_COLORS, OUTCOMES

CLINCH_COLOR = "#9a9a9a"
"""Colour of the clinch bands on the work-rate timeline."""

# Front view of the opponent in guard, in a 220 x 310 unit box (y down): where each target
# region's dots gather, per side of the figure (the puncher's left hand lands on the figure's left).
_ANCHORS: dict[str, dict[str, tuple[float, float]]] = {
    "head": {"left": (100.0, 50.0), "right": (120.0, 50.0)},
    "body": {"left": (92.0, 150.0), "right": (128.0, 150.0)},
    "guard": {"left": (72.0, 78.0), "right": (148.0, 78.0)},
}
_SPREAD = {"head": 3.2, "body": 4.0, "guard": 3.0}
_BODY_FILL, _BODY_EDGE = "#e9e9ee", "#9a9aa6"


def opponent_name(data: ReportData, pid: int) -> str:
    others = [q for q in data.person_ids if q != pid]
    return data.name_of(others[0]) if len(others) == 1 else "the opponent"


def _message(kind: str, title: str, text: str, pid: int | None) -> str:
    """A small chart that only says why there is nothing to draw."""
    with figure(300, 44, layout=None) as fig:
        fig.text(0.03, 0.5, text, va="center")
        return inline_svg(fig, kind, title, None, pid)


def _silhouette(ax: Axes) -> None:
    """The opponent in guard, front view (legs, trunk, neck, head, forearms, upper arms, gloves)."""
    style: dict[str, Any] = {"facecolor": _BODY_FILL, "edgecolor": _BODY_EDGE, "linewidth": 1.2, "zorder": 1}
    for x in (80.0, 114.0):
        ax.add_patch(FancyBboxPatch((x, 212.0), 26.0, 90.0, boxstyle="round,pad=0,rounding_size=9", **style))
    c3, l2 = MplPath.CURVE3, MplPath.LINETO
    trunk = MplPath([(74, 96), (110, 84), (146, 96), (150, 210), (110, 222), (70, 210), (74, 96)],
                    [MplPath.MOVETO, c3, c3, l2, c3, c3, MplPath.CLOSEPOLY])  # fmt: skip
    ax.add_patch(PathPatch(trunk, **style))
    ax.add_patch(Rectangle((101.0, 74.0), 18.0, 20.0, **style))
    ax.add_patch(Circle((110.0, 50.0), 27.0, **style))
    for pts in ([(76, 100), (64, 156), (74, 160), (86, 106)], [(144, 100), (156, 156), (146, 160), (134, 106)],
                [(66, 156), (64, 92), (80, 92), (76, 158)], [(154, 156), (156, 92), (140, 92), (144, 158)]):  # fmt: skip
        ax.add_patch(Polygon(pts, closed=True, **style))
    for x in (72.0, 148.0):
        ax.add_patch(Circle((x, 80.0), 15.0, **style))


def punch_map(data: ReportData, pid: int) -> str:
    """Where ``pid``'s punches ended on the opponent: one dot per punch with a target region
    (head, body, guard), coloured by outcome; punches with no region near are counted below."""
    ev = data.events
    mine = np.flatnonzero(ev.punch_person == pid)
    title = f"{data.name_of(pid)}'s punches on {opponent_name(data, pid)}"
    marks = Marks()
    placed: dict[tuple[str, str], int] = {}
    counts = {"head": 0, "body": 0, "guard": 0, "none": 0}
    golden = math.pi * (3.0 - math.sqrt(5.0))
    with figure(230, 380, layout=None) as fig:
        ax = fig.add_axes((0.02, 0.17, 0.96, 0.81))
        ax.set_xlim(0, 220)
        ax.set_ylim(310, 0)
        ax.set_aspect("equal")
        ax.set_axis_off()
        _silhouette(ax)
        for i in mine.tolist():
            target, hand, out = str(ev.punch_target[i]), str(ev.punch_hand[i]), str(ev.punch_outcome[i])
            counts[target] = counts.get(target, 0) + 1
            if target not in _ANCHORS:
                continue
            k = placed.get((target, hand), 0)
            placed[(target, hand)] = k + 1
            x0, y0 = _ANCHORS[target][hand]
            r = _SPREAD[target] * math.sqrt(k)
            dot = Circle((x0 + r * math.cos(k * golden), y0 + r * math.sin(k * golden)), 4.2,
                         facecolor=OUTCOME_COLORS[out], edgecolor="#222222", linewidth=0.6, zorder=3)  # fmt: skip
            ax.add_patch(dot)
            marks.tag(dot, f"mark-{i}", target=target, outcome=out, type=ev.punch_type[i], hand=hand,
                      title=f"{ev.punch_type[i]}, {hand} hand, {out} ({float(ev.punch_peak_speed_mps[i]):.1f} m/s)")  # fmt: skip
        n_out = {o: int(np.sum(ev.punch_outcome[mine] == o)) for o in OUTCOMES}
        handles = [Line2D([], [], ls="", marker="o", markersize=7, markerfacecolor=OUTCOME_COLORS[o],
                          markeredgecolor="#222222", markeredgewidth=0.6, label=f"{o} {n_out[o]}") for o in OUTCOMES]  # fmt: skip
        fig.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.5, 0.06), ncols=3,
                   handletextpad=0.2, columnspacing=0.8)  # fmt: skip
        fig.text(0.5, 0.025, f"head {counts['head']} · body {counts['body']} · guard {counts['guard']}"
                 f" · off target {counts['none']}", ha="center", fontsize=9)  # fmt: skip
        return inline_svg(fig, "punch-map", title, marks, pid)


def _heat_extent(data: ReportData, cell: float) -> tuple[float, float, float, float] | None:
    assert data.positions_xy_m is not None and data.positions_valid is not None
    pts = data.positions_xy_m[data.positions_valid]
    if data.ring_xy_m is not None:
        pts = np.concatenate([pts.reshape(-1, 2), data.ring_xy_m])
    if pts.size == 0:
        return None
    lo = np.floor(pts.min(axis=0) / cell) * cell - cell
    hi = np.ceil(pts.max(axis=0) / cell) * cell + cell
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def _label_axes(ax: Axes, marks: Marks, x_label: str, y_label: str) -> None:
    """Axis labels (with units), tagged ``xlabel`` / ``ylabel``."""
    ax.set_xlabel(x_label)
    ax.set_ylabel(y_label)
    marks.tag(ax.xaxis.label, "xlabel", cls="xlabel")
    marks.tag(ax.yaxis.label, "ylabel", cls="ylabel")


def ring_heatmap(data: ReportData, pid: int, options: ReportOptions) -> str:
    """Top view of where ``pid`` stood (mid-hip): seconds per ``heat_cell_m`` cell in world x/y
    (metres), with the ring's outline when known, else the athletes' bounding box (dashed)."""
    title = f"{data.name_of(pid)}: ring position (top view)"
    if data.positions_xy_m is None or data.positions_valid is None:
        return _message("ring-heatmap", title, "no 3D positions for this result", pid)
    cell = options.heat_cell_m
    ext = _heat_extent(data, cell)
    if ext is None:
        return _message("ring-heatmap", title, f"{data.name_of(pid)} was never located", pid)
    x0, x1, y0, y1 = ext
    scale = min(250.0 / (x1 - x0), 250.0 / (y1 - y0))  # px per metre, equal on both axes
    p = data.person_ids.index(pid)
    xy = data.positions_xy_m[data.positions_valid[:, p], p]
    nx, ny = int(round((x1 - x0) / cell)), int(round((y1 - y0) / cell))
    hist = (np.histogram2d(xy[:, 0], xy[:, 1], bins=(nx, ny), range=((x0, x1), (y0, y1)))[0]
            if len(xy) else np.zeros((nx, ny)))  # fmt: skip
    seconds = hist / data.series.fps
    top = float(seconds.max()) if seconds.size and seconds.max() > 0 else 1.0
    color = data.color_of(pid)
    r, g, b = to_rgb(color)
    # Opaque tints (no seams between the colorbar's levels), from 12 % of the colour to all of it.
    pale = (0.88 + 0.12 * r, 0.88 + 0.12 * g, 0.88 + 0.12 * b)
    cmap = LinearSegmentedColormap.from_list(
        "time", [pale, (r, g, b)], N=32
    )  # < 50 levels: the colorbar stays vector
    norm = Normalize(0.0, top)
    marks = Marks()
    with figure((x1 - x0) * scale + 120, (y1 - y0) * scale + 78) as fig:
        fig.get_layout_engine().set(rect=(0.0, 0.07, 1.0, 0.93))  # type: ignore[call-arg, union-attr]
        ax = fig.add_subplot()
        for i, j in zip(*np.nonzero(seconds), strict=True):
            s = float(seconds[i, j])
            sq = Rectangle((x0 + i * cell, y0 + j * cell), cell, cell, facecolor=cmap(norm(s)), linewidth=0)
            ax.add_patch(sq)
            marks.tag(sq, f"mark-{i}-{j}", seconds=f"{s:.4f}", title=f"{s:.1f} s")
        if data.ring_xy_m is not None:
            ring = Polygon(data.ring_xy_m, closed=True, fill=False, edgecolor="#333333", linewidth=2)
            ax.add_patch(ring)
            marks.tag(ring, "ring", cls="ring")
            note = "ring outline from the session"
        else:
            all_xy = data.positions_xy_m[data.positions_valid]
            b0 = np.floor(all_xy.min(axis=0) / cell) * cell  # on the cell grid, so that the cells lie inside
            b1 = np.ceil(all_xy.max(axis=0) / cell) * cell
            box = Rectangle((float(b0[0]), float(b0[1])), float(b1[0] - b0[0]), float(b1[1] - b0[1]), fill=False,
                            edgecolor="#555555", linestyle=(0, (5, 3)), linewidth=1)  # fmt: skip
            ax.add_patch(box)
            marks.tag(box, "ring", cls="ring bbox")
            note = "ring unknown: dashed box = both athletes' extent"
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal")
        ticks = MaxNLocator(4, steps=[1, 2, 5, 10]).tick_values(0.0, max(x1 - x0, y1 - y0))
        step = float(ticks[1] - ticks[0]) if len(ticks) > 1 else 1.0  # one step on both axes: equal scales
        ax.xaxis.set_major_locator(MultipleLocator(step))
        ax.yaxis.set_major_locator(MultipleLocator(step))
        _label_axes(ax, marks, "world x (m)", "world y (m)")
        bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.8, aspect=18, pad=0.03)
        bar.set_label(f"s per {cell:g} m cell")
        bar.outline.set_visible(False)
        bar.solids.set_edgecolor("face")  # type: ignore[union-attr]  # no hairlines between the levels
        fig.text(0.02, 0.02, note, color="#555555", fontsize=9)
        return inline_svg(fig, "ring-heatmap", title, marks, pid)


def speed_histogram(data: ReportData, pid: int, options: ReportOptions) -> str:
    """Peak glove speeds of ``pid``'s punches: punches per ``speed_bin_mps`` bin, stacked by outcome."""
    ev = data.events
    title = f"{data.name_of(pid)}: peak glove speed"
    mine = ev.punch_person == pid
    if not mine.any():
        return _message("speed-histogram", title, f"{data.name_of(pid)} threw no punch", pid)
    bw = options.speed_bin_mps
    all_speeds = ev.punch_peak_speed_mps  # both athletes' histograms share the bins
    lo = math.floor(float(all_speeds.min()) / bw) * bw
    hi = max(lo + bw, math.ceil(float(all_speeds.max()) / bw + 1e-9) * bw)
    n_bins = int(round((hi - lo) / bw))
    edges = lo + bw * np.arange(n_bins + 1)
    idx = np.clip(((ev.punch_peak_speed_mps[mine] - lo) / bw).astype(int), 0, n_bins - 1)
    outcomes = ev.punch_outcome[mine]
    counts = {o: np.bincount(idx[outcomes == o], minlength=n_bins) for o in OUTCOMES}
    mean = float(ev.punch_peak_speed_mps[mine].mean())
    marks = Marks()
    with figure(340, 230) as fig:
        ax = fig.add_subplot()
        for b in range(n_bins):
            base = 0
            for o in OUTCOMES:
                c = int(counts[o][b])
                if not c:
                    continue
                rect = ax.bar(edges[b], c, width=bw, bottom=base, align="edge", color=OUTCOME_COLORS[o],
                              edgecolor="white", linewidth=1)[0]  # fmt: skip
                marks.tag(rect, f"mark-{o}-{b}", count=c, outcome=o, lo=f"{edges[b]:g}",
                          title=f"{c} {o}, {edges[b]:g}–{edges[b + 1]:g} m/s")  # fmt: skip
                base += c
        line = ax.axvline(mean, color="#222222", linestyle=(0, (4, 3)), linewidth=1)
        marks.tag(line, "mean", cls="mean", title=f"mean {mean:.2f} m/s")
        ax.set_xlim(float(edges[0]), float(edges[-1]))
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(axis="y", color="#e4e4e4")
        ax.set_axisbelow(True)
        _label_axes(ax, marks, "peak glove speed (m/s)", "punches")
        handles = [Patch(color=OUTCOME_COLORS[o], label=o) for o in OUTCOMES]
        handles.append(Line2D([], [], color="#222222", linestyle=(0, (4, 3)), label=f"mean {mean:.1f} m/s"))  # type: ignore[arg-type]
        fig.legend(handles=handles, loc="outside lower center", ncols=4, handlelength=1.2, columnspacing=0.8)
        return inline_svg(fig, "speed-histogram", title, marks, pid)


def work_rate_timeline(data: ReportData, options: ReportOptions) -> str:
    """Punches thrown per ``bin_s`` bin over the bout, one bar per athlete per bin (the last
    bin may be shorter: its bars are narrower); clinches as grey bands behind the bars."""
    ev, dur = data.events, data.duration_s
    bw = options.bin_s
    n_bins = max(1, int(math.ceil(dur / bw - 1e-9)))
    edges = np.minimum(bw * np.arange(n_bins + 1), dur)
    f0 = int(data.series.frame_indices[0]) if data.series.n_frames else 0
    t_peak = (ev.punch_peak_frame - f0) / data.series.fps
    pids = data.person_ids
    counts = {p: np.bincount(np.clip((t_peak[ev.punch_person == p] / bw).astype(int), 0, n_bins - 1), minlength=n_bins)
              for p in pids}  # fmt: skip
    top = max([1] + [int(c.max()) for c in counts.values()])
    marks = Marks()
    with figure(690, 260) as fig:
        ax = fig.add_subplot()
        for k, (s, e) in enumerate(zip(ev.clinch_start_frame, ev.clinch_end_frame, strict=True)):
            a, b = (int(s) - f0) / data.series.fps, (int(e) + 1 - f0) / data.series.fps
            band = ax.axvspan(a, b, color=CLINCH_COLOR, alpha=0.3, linewidth=0, zorder=0)
            marks.tag(
                band, f"clinch-{k}", cls="clinch", t0=f"{a:g}", t1=f"{b:g}", title=f"clinch {a:.1f}–{b:.1f} s"
            )
        for b in range(n_bins):
            # The athletes' bars side by side in the middle 70 % of their bin (a grouped bar chart).
            span = float(edges[b + 1] - edges[b])
            w = 0.7 * span / max(len(pids), 1)
            for k, p in enumerate(pids):
                c = int(counts[p][b])
                rect = ax.bar(edges[b] + 0.15 * span + k * w, c, width=0.94 * w, align="edge",
                              color=data.color_of(p), zorder=2)[0]  # fmt: skip
                marks.tag(rect, f"mark-{p}-{b}", athlete=p, count=c, t0=f"{edges[b]:g}", t1=f"{edges[b + 1]:g}",
                          title=f"{data.name_of(p)}: {c} punches, {edges[b]:g}–{edges[b + 1]:g} s")  # fmt: skip
        ax.set_xlim(0.0, float(dur))
        ax.set_ylim(0.0, top * 1.08)
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(axis="y", color="#e4e4e4")
        ax.set_axisbelow(True)
        _label_axes(ax, marks, "time from the first analysed frame (s)", f"punches per {bw:g} s")
        handles = [Patch(color=data.color_of(p), label=data.name_of(p)) for p in pids]
        handles.append(Patch(color=CLINCH_COLOR, alpha=0.3, label="clinch"))
        fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), handlelength=1.2)
        return inline_svg(fig, "work-rate", "work rate over the bout", marks)
