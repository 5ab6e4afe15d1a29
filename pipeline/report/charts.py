"""The report's charts as inline SVG strings: punch maps, ring-position heatmaps, peak-speed
histograms and the work-rate timeline.

Every data mark carries ``class="mark"`` and ``data-*`` attributes with the number it shows
(``data-count``, ``data-seconds``), so a test or a script can read a chart back.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.report.data import ReportData, ReportOptions
from pipeline.report.svg import FONT, Frame, count_ticks, esc, fmt, legend, nice_ticks, svg
from pipeline.schema.analytics import OUTCOMES

OUTCOME_COLORS: dict[str, str] = {"landed": "#1a7f37", "blocked": "#e0a100", "missed": "#8c8c8c"}
"""Colour of each punch outcome in every chart."""

# Front view of the opponent in guard (viewBox 220 x 310 px): where each target region's
# dots gather, per side of the figure (the puncher's left hand lands on the figure's left).
_ANCHORS: dict[str, dict[str, tuple[float, float]]] = {
    "head": {"left": (100.0, 50.0), "right": (120.0, 50.0)},
    "body": {"left": (92.0, 150.0), "right": (128.0, 150.0)},
    "guard": {"left": (72.0, 78.0), "right": (148.0, 78.0)},
}
_SPREAD_PX = {"head": 3.2, "body": 4.0, "guard": 3.0}

_SILHOUETTE = (
    '<g class="silhouette" fill="#e9e9ee" stroke="#9a9aa6" stroke-width="1.5">'
    '<rect x="80" y="212" width="26" height="90" rx="9"/><rect x="114" y="212" width="26" height="90" rx="9"/>'
    '<path d="M74 96 Q110 84 146 96 L150 210 Q110 222 70 210 Z"/>'
    '<rect x="101" y="74" width="18" height="20"/>'
    '<circle cx="110" cy="50" r="27"/>'
    '<path d="M76 100 L64 156 L74 160 L86 106 Z"/><path d="M144 100 L156 156 L146 160 L134 106 Z"/>'
    '<path d="M66 156 L64 92 L80 92 L76 158 Z"/><path d="M154 156 L156 92 L140 92 L144 158 Z"/>'
    '<circle cx="72" cy="80" r="15"/><circle cx="148" cy="80" r="15"/>'
    "</g>"
)


def opponent_name(data: ReportData, pid: int) -> str:
    others = [q for q in data.person_ids if q != pid]
    return data.name_of(others[0]) if len(others) == 1 else "the opponent"


def punch_map(data: ReportData, pid: int) -> str:
    """Where ``pid``'s punches ended on the opponent: one dot per punch with a target region
    (head, body, guard), coloured by outcome; punches with no region near are counted below."""
    ev = data.events
    mine = np.flatnonzero(ev.punch_person == pid)
    body = [_SILHOUETTE]
    placed: dict[tuple[str, str], int] = {}
    counts = {"head": 0, "body": 0, "guard": 0, "none": 0}
    golden = math.pi * (3.0 - math.sqrt(5.0))
    for i in mine.tolist():
        target, hand, out = str(ev.punch_target[i]), str(ev.punch_hand[i]), str(ev.punch_outcome[i])
        counts[target] = counts.get(target, 0) + 1
        if target not in _ANCHORS:
            continue
        k = placed.get((target, hand), 0)
        placed[(target, hand)] = k + 1
        ax, ay = _ANCHORS[target][hand]
        r = _SPREAD_PX[target] * math.sqrt(k)
        x, y = ax + r * math.cos(k * golden), ay + r * math.sin(k * golden)
        body.append(
            f'<circle class="mark" cx="{fmt(x)}" cy="{fmt(y)}" r="4.2" fill="{OUTCOME_COLORS[out]}" stroke="#222" '
            f'stroke-width="0.6" data-target="{esc(target)}" data-outcome="{esc(out)}" data-type="{esc(ev.punch_type[i])}" '
            f'data-hand="{esc(hand)}"><title>{esc(ev.punch_type[i])}, {esc(hand)} hand, {esc(out)} '
            f"({float(ev.punch_peak_speed_mps[i]):.1f} m/s)</title></circle>"
        )
    n_out = {o: int(np.sum(ev.punch_outcome[mine] == o)) for o in OUTCOMES}
    body.append(legend([(OUTCOME_COLORS[o], f"{o} {n_out[o]}") for o in OUTCOMES], 8, 326, step=72))
    body.append(
        f'<text {FONT} x="8" y="346" fill="#333">head {counts["head"]} · body {counts["body"]} · guard {counts["guard"]}'
        f" · off target {counts['none']}</text>"
    )
    title = f"{data.name_of(pid)}'s punches on {opponent_name(data, pid)}"
    return svg("punch-map", 220, 356, "".join(body), title, pid)


def _heat_extent(data: ReportData, cell: float) -> tuple[float, float, float, float] | None:
    assert data.positions_xy_m is not None and data.positions_valid is not None
    pts = data.positions_xy_m[data.positions_valid]
    if data.ring_xy_m is not None:
        pts = np.concatenate([pts.reshape(-1, 2), data.ring_xy_m])
    if pts.size == 0:
        return None
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    lo = np.floor(lo / cell) * cell - cell
    hi = np.ceil(hi / cell) * cell + cell
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def ring_heatmap(data: ReportData, pid: int, options: ReportOptions) -> str:
    """Top view of where ``pid`` stood (mid-hip): seconds per ``heat_cell_m`` cell in world x/y
    (metres), with the ring's outline when known, else the athletes' bounding box (dashed)."""
    title = f"{data.name_of(pid)}: ring position (top view)"
    if data.positions_xy_m is None or data.positions_valid is None:
        return svg(
            "ring-heatmap",
            300,
            60,
            f'<text {FONT} x="8" y="30">no 3D positions for this result</text>',
            title,
            pid,
        )
    cell = options.heat_cell_m
    ext = _heat_extent(data, cell)
    if ext is None:
        return svg(
            "ring-heatmap",
            300,
            60,
            f'<text {FONT} x="8" y="30">{esc(data.name_of(pid))} was never located</text>',
            title,
            pid,
        )
    x0, x1, y0, y1 = ext
    scale = min(250.0 / (x1 - x0), 250.0 / (y1 - y0))
    fr = Frame(
        width=52 + 14 + (x1 - x0) * scale,
        height=14 + 78 + (y1 - y0) * scale,
        x0=x0,
        x1=x1,
        y0=y0,
        y1=y1,
        bottom=78,
    )
    p = data.person_ids.index(pid)
    xy = data.positions_xy_m[data.positions_valid[:, p], p]
    nx, ny = int(round((x1 - x0) / cell)), int(round((y1 - y0) / cell))
    hist, _, _ = (
        np.histogram2d(xy[:, 0], xy[:, 1], bins=(nx, ny), range=((x0, x1), (y0, y1)))
        if len(xy)
        else (np.zeros((nx, ny)), None, None)
    )
    seconds = hist / data.series.fps
    top = float(seconds.max()) if seconds.size else 0.0
    color = data.color_of(pid)
    out = []
    for i, j in zip(*np.nonzero(seconds), strict=True):
        s = float(seconds[i, j])
        ax, ay = x0 + i * cell, y0 + j * cell
        px, py = fr.x(ax), fr.y(ay + cell)
        out.append(f'<rect class="mark" x="{fmt(px)}" y="{fmt(py)}" width="{fmt(cell * scale)}" height="{fmt(cell * scale)}" '
                   f'fill="{esc(color)}" fill-opacity="{0.12 + 0.88 * s / top:.3f}" data-seconds="{s:.4f}">'
                   f"<title>{s:.1f} s</title></rect>")  # fmt: skip
    if data.ring_xy_m is not None:
        pts = " ".join(f"{fmt(fr.x(x))},{fmt(fr.y(y))}" for x, y in data.ring_xy_m)
        out.append(f'<polygon class="ring" points="{pts}" fill="none" stroke="#333" stroke-width="2"/>')
        note = "ring outline from the session"
    else:
        all_xy = data.positions_xy_m[data.positions_valid]
        bx0, by0 = (
            np.floor(all_xy.min(axis=0) / cell) * cell
        )  # on the cell grid, so that the cells lie inside
        bx1, by1 = np.ceil(all_xy.max(axis=0) / cell) * cell
        out.append(f'<rect class="ring bbox" x="{fmt(fr.x(bx0))}" y="{fmt(fr.y(by1))}" width="{fmt((bx1 - bx0) * scale)}" '
                   f'height="{fmt((by1 - by0) * scale)}" fill="none" stroke="#555" stroke-dasharray="5 3"/>')  # fmt: skip
        note = "ring unknown: dashed box = both athletes' extent"
    ticks = nice_ticks(0.0, max(x1 - x0, y1 - y0), 4)
    step = ticks[1] - ticks[0] if len(ticks) > 1 else 1.0  # one step on both axes: equal scales
    xt = np.arange(math.ceil(x0 / step) * step, x1 + 1e-9, step).round(6).tolist()
    yt = np.arange(math.ceil(y0 / step) * step, y1 + 1e-9, step).round(6).tolist()
    axes = fr.axes("world x (m)", "world y (m)", xt, yt, grid=False)
    ly = fr.height - 34
    scale_bar = "".join(
        f'<rect x="{fmt(8 + k * 14)}" y="{fmt(ly)}" width="14" height="9" fill="{esc(color)}" fill-opacity="{0.12 + 0.88 * k / 4:.2f}"/>'
        for k in range(5)
    )
    scale_bar += (f'<text {FONT} x="{fmt(8 + 5 * 14 + 4)}" y="{fmt(ly + 8)}">0–{top:.1f} s per {cell:g} m cell</text>'
                  f'<text {FONT} x="8" y="{fmt(fr.height - 4)}" fill="#555">{esc(note)}</text>')  # fmt: skip
    return svg("ring-heatmap", fr.width, fr.height, axes + "".join(out) + scale_bar, title, pid)


def speed_histogram(data: ReportData, pid: int, options: ReportOptions) -> str:
    """Peak glove speeds of ``pid``'s punches: punches per ``speed_bin_mps`` bin, stacked by outcome."""
    ev = data.events
    title = f"{data.name_of(pid)}: peak glove speed"
    all_speeds = ev.punch_peak_speed_mps
    mine = ev.punch_person == pid
    if not mine.any():
        return svg(
            "speed-histogram",
            320,
            60,
            f'<text {FONT} x="8" y="30">{esc(data.name_of(pid))} threw no punch</text>',
            title,
            pid,
        )
    bw = options.speed_bin_mps
    lo = math.floor(float(all_speeds.min()) / bw) * bw
    hi = max(lo + bw, math.ceil(float(all_speeds.max()) / bw + 1e-9) * bw)
    n_bins = int(round((hi - lo) / bw))
    edges = lo + bw * np.arange(n_bins + 1)
    idx = np.clip(((ev.punch_peak_speed_mps[mine] - lo) / bw).astype(int), 0, n_bins - 1)
    outcomes = ev.punch_outcome[mine]
    counts = {o: np.bincount(idx[outcomes == o], minlength=n_bins) for o in OUTCOMES}
    top = int(np.sum(list(counts.values()), axis=0).max())
    yt = count_ticks(top)
    fr = Frame(width=330, height=210, x0=float(edges[0]), x1=float(edges[-1]), y0=0.0, y1=yt[-1], bottom=64)
    out = []
    for b in range(n_bins):
        base = 0
        for o in OUTCOMES:
            c = int(counts[o][b])
            if not c:
                continue
            x, y = fr.x(edges[b]), fr.y(base + c)
            out.append(f'<rect class="mark" x="{fmt(x + 1)}" y="{fmt(y)}" width="{fmt(fr.x(edges[b + 1]) - x - 2)}" '
                       f'height="{fmt(fr.y(base) - y)}" fill="{OUTCOME_COLORS[o]}" data-count="{c}" data-outcome="{o}" '
                       f'data-lo="{edges[b]:g}"><title>{c} {o}, {edges[b]:g}–{edges[b + 1]:g} m/s</title></rect>')  # fmt: skip
            base += c
    mean = float(ev.punch_peak_speed_mps[mine].mean())
    out.append(f'<line class="mean" x1="{fmt(fr.x(mean))}" x2="{fmt(fr.x(mean))}" y1="{fmt(fr.top)}" y2="{fmt(fr.y(0))}" '
               f'stroke="#222" stroke-dasharray="4 3"><title>mean {mean:.2f} m/s</title></line>')  # fmt: skip
    axes = fr.axes("peak glove speed (m/s)", "punches", None, yt)
    leg = legend(
        [(OUTCOME_COLORS[o], o) for o in OUTCOMES] + [("#222", f"mean {mean:.1f} m/s")], 8, 202, step=68
    )
    return svg("speed-histogram", fr.width, fr.height, axes + "".join(out) + leg, title, pid)


def work_rate_timeline(data: ReportData, options: ReportOptions) -> str:
    """Punches thrown per ``bin_s`` bin over the bout, one bar per athlete per bin (the last
    bin may be shorter: its bars are narrower); clinches as grey bands above the plot."""
    ev, dur = data.events, data.duration_s
    bw = options.bin_s
    n_bins = max(1, int(math.ceil(dur / bw - 1e-9)))
    edges = np.minimum(bw * np.arange(n_bins + 1), dur)
    f0 = int(data.series.frame_indices[0]) if data.series.n_frames else 0
    t_peak = (ev.punch_peak_frame - f0) / data.series.fps
    pids = data.person_ids
    counts = {p: np.bincount(np.clip((t_peak[ev.punch_person == p] / bw).astype(int), 0, n_bins - 1), minlength=n_bins)
              for p in pids}  # fmt: skip
    top = max(1, int(max(c.max() for c in counts.values())) if pids else 1)
    yt = count_ticks(top)
    fr = Frame(width=680, height=250, x0=0.0, x1=float(dur), y0=0.0, y1=yt[-1], top=24, bottom=64)
    out = []
    for s, e in zip(ev.clinch_start_frame, ev.clinch_end_frame, strict=True):
        a, b = (int(s) - f0) / data.series.fps, (int(e) + 1 - f0) / data.series.fps
        out.append(f'<rect class="clinch" x="{fmt(fr.x(a))}" y="{fmt(fr.top - 10)}" width="{fmt(fr.x(b) - fr.x(a))}" '
                   f'height="8" fill="#9a9a9a"><title>clinch {a:.1f}–{b:.1f} s</title></rect>')  # fmt: skip
    for b in range(n_bins):
        # The athletes' bars side by side in the middle 70 % of their bin (a grouped bar chart).
        x_lo, x_hi = fr.x(edges[b]), fr.x(edges[b + 1])
        w = 0.7 * (x_hi - x_lo) / max(len(pids), 1)
        x_start = x_lo + 0.15 * (x_hi - x_lo)
        for k, p in enumerate(pids):
            c = int(counts[p][b])
            y = fr.y(c)
            out.append(f'<rect class="mark" x="{fmt(x_start + k * w)}" y="{fmt(y)}" width="{fmt(max(w - 1, 0.5))}" '
                       f'height="{fmt(fr.y(0) - y)}" fill="{esc(data.color_of(p))}" data-athlete="{p}" data-count="{c}" '
                       f'data-t0="{edges[b]:g}" data-t1="{edges[b + 1]:g}"><title>{esc(data.name_of(p))}: {c} punches, '
                       f"{edges[b]:g}–{edges[b + 1]:g} s</title></rect>")  # fmt: skip
    axes = fr.axes("time from the first analysed frame (s)", f"punches per {bw:g} s", None, yt)
    leg = legend(
        [(data.color_of(p), data.name_of(p)) for p in pids] + [("#9a9a9a", "clinch (band above)")],
        8,
        242,
        step=110,
    )
    return svg("work-rate", fr.width, fr.height, axes + "".join(out) + leg, "work rate over the bout")
