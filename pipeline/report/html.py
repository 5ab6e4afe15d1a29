"""The bout report: one self-contained HTML page (inline CSS and SVG, no script, nothing
fetched) that a coach reads on screen and prints or saves as PDF (A4, one section per page).

``render_report(data, options) -> str`` is pure: the numbers come from ``ReportData`` (the
analyze stage's events and series) through ``pipeline.stages.analyze.athlete_summary``, the
same summary as ``cornerman analyze`` and ``GET /api/sessions/{id}/summary``.
"""

from __future__ import annotations

import datetime as dt
from typing import Any

import numpy as np

from pipeline.report import charts
from pipeline.report.data import Period, ReportData, ReportOptions, periods, slice_bout
from pipeline.report.fatigue_chart import PANELS, fatigue_chart
from pipeline.report.svg import esc
from pipeline.schema.analytics import OUTCOMES, PUNCH_TYPES
from pipeline.stages.analyze.summary import athlete_summary, summarize
from pipeline.stages.analyze.zones import CENTRE_SCALE, CORNER_RADIUS_M, RING_ZONES, ROPES_BAND_M

SUMMARY_ROWS: tuple[tuple[str, str], ...] = (
    ("punches", "punches thrown"),
    ("punches_landed", "landed"),
    ("punches_blocked", "blocked"),
    ("punches_missed", "missed"),
    ("landed_pct", "accuracy (landed %)"),
    ("peak_speed_max_mps", "peak glove speed, max (m/s)"),
    ("peak_speed_mean_mps", "peak glove speed, mean (m/s)"),
    ("peak_speed_median_mps", "peak glove speed, median (m/s)"),
    ("punches_per_min", "work rate (punches / min)"),
    ("slips", "slips"),
    ("ducks", "ducks"),
    ("blocks", "blocks"),
    ("parries", "parries"),
    ("clinch_s", "clinch time (s)"),
    ("stance", "stance"),
    ("orthodox_pct", "orthodox (% of frames)"),
    ("stance_width_mean_m", "stance width, mean (m)"),
    ("guard_height_mean_m", "gloves above chin, mean (m)"),
    ("guard_height_median_m", "gloves above chin, median (m)"),
    ("distance_mean_m", "distance to opponent, mean (m)"),
    *((f"ring_{z}_pct", f"ring: {z} (% of time)") for z in RING_ZONES),
)
"""Summary keys (``pipeline.stages.analyze.summary``) and their labels, in table order."""

TYPE_LABELS: dict[str, str] = {t: t.replace("_", " ") for t in PUNCH_TYPES}

CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;color:#222;max-width:1000px;margin:24px auto;padding:0 16px}
h1{font-size:1.5rem;margin:0 0 .2rem}h2{font-size:1.15rem;border-bottom:2px solid #222;padding-bottom:2px;margin:1.6rem 0 .6rem}
h3{font-size:.95rem;margin:.8rem 0 .3rem}.meta{color:#444;font-size:.9rem;line-height:1.5}.note{color:#555;font-size:.8rem;max-width:60rem}
table{border-collapse:collapse;font-size:.8rem;margin:.3rem 0 .8rem;font-variant-numeric:tabular-nums}
th,td{padding:3px 9px;border-bottom:1px solid #ddd;text-align:right}th{background:#f2f2f2}
th:first-child,td:first-child{text-align:left}.sw{display:inline-block;width:.7em;height:.7em;border-radius:2px;margin-right:.3em}
.charts{display:flex;flex-wrap:wrap;gap:18px;align-items:flex-start}figure{margin:0}
figcaption{font-size:.8rem;font-weight:600;margin-bottom:2px}svg.chart{max-width:100%;height:auto;display:block}
button.print{float:right;padding:.3rem .8rem;cursor:pointer}
@page{size:A4;margin:14mm}
@media print{
  body{max-width:none;margin:0;padding:0}
  section{break-before:page;page-break-before:always}
  section.first{break-before:auto;page-break-before:auto}
  figure,table,h2,h3{break-inside:avoid;page-break-inside:avoid}
  h2,h3{break-after:avoid;page-break-after:avoid}
  *{-webkit-print-color-adjust:exact;print-color-adjust:exact}
  .screen-only{display:none}
}
"""


def _cell(v: Any) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:g}"
    return esc(v)


def _athlete_head(data: ReportData, pid: int) -> str:
    return f'<span class="sw" style="background:{esc(data.color_of(pid))}"></span>{esc(data.name_of(pid))}'


def _summary_table(data: ReportData, summary: dict[str, Any]) -> str:
    heads = "".join(f"<th>{_athlete_head(data, a['person_id'])}</th>" for a in summary["athletes"])
    rows = []
    for key, label in SUMMARY_ROWS:
        cells = "".join(
            f'<td data-key="{key}" data-athlete="{a["person_id"]}" data-period="bout">{_cell(a.get(key))}</td>'
            for a in summary["athletes"]
        )
        rows.append(f"<tr><td>{esc(label)}</td>{cells}</tr>")
    return f'<table class="summary"><tr><th>whole bout</th>{heads}</tr>{"".join(rows)}</table>'


def _type_table(data: ReportData, pid: int) -> str:
    ev = data.events
    mine = ev.punch_person == pid
    rows = []
    for t in PUNCH_TYPES:
        sel = mine & (ev.punch_type == t)
        n = int(sel.sum())
        if not n:
            continue
        by = {o: int(np.sum(ev.punch_outcome[sel] == o)) for o in OUTCOMES}
        speed = ev.punch_peak_speed_mps[sel]
        cells = [
            n,
            *by.values(),
            round(100.0 * by["landed"] / n, 1),
            round(float(speed.mean()), 2),
            round(float(speed.max()), 2),
        ]
        names = ["thrown", *OUTCOMES, "landed_pct", "speed_mean", "speed_max"]
        rows.append(f'<tr data-type="{t}"><td>{esc(TYPE_LABELS[t])}</td>'
                    + "".join(f'<td data-key="{k}">{_cell(v)}</td>' for k, v in zip(names, cells, strict=True)) + "</tr>")  # fmt: skip
    if not rows:
        return f'<p class="note">{esc(data.name_of(pid))} threw no punch.</p>'
    head = "<tr><th>type</th><th>thrown</th><th>landed</th><th>blocked</th><th>missed</th><th>accuracy (%)</th>" \
           "<th>peak speed mean (m/s)</th><th>peak speed max (m/s)</th></tr>"  # fmt: skip
    return f'<table class="types" data-athlete="{pid}">{head}{"".join(rows)}</table>'


def _period_table(
    data: ReportData, pid: int, spans: list[tuple[Period, dict[str, Any]]], whole: dict[str, Any]
) -> str:
    heads = "".join(f"<th>{esc(p.label)}</th>" for p, _ in spans) + "<th>bout</th>"
    rows = []
    for key, label in SUMMARY_ROWS:
        cells = "".join(
            f'<td data-key="{key}" data-period="{k}">{_cell(s.get(key))}</td>'
            for k, (_, s) in enumerate(spans)
        )
        rows.append(
            f'<tr><td>{esc(label)}</td>{cells}<td data-key="{key}" data-period="bout">{_cell(whole.get(key))}</td></tr>'
        )
    return f'<table class="periods" data-athlete="{pid}"><tr><th></th>{heads}</tr>{"".join(rows)}</table>'


def _fatigue_table(athlete: dict[str, Any]) -> str:
    """Rows: the fatigue indicators; columns: the periods, then the trend per minute and its sign."""
    per = athlete["by_period"]
    heads = "".join(f"<th>{esc(p['label'])}</th>" for p in per) + "<th>trend / min</th><th>trend</th>"
    rows = []
    for key, label in PANELS.items():
        cells = "".join(f'<td data-key="{key}" data-period="{k}">{_cell(p.get(key))}</td>' for k, p in enumerate(per))
        t = athlete["fatigue"][key]
        slope = "—" if t["slope_per_min"] is None else f"{t['slope_per_min']:+g}"
        cells += f'<td data-key="{key}" data-period="slope">{slope}</td><td data-key="{key}" data-period="trend">{esc(t["trend"])}</td>'
        rows.append(f"<tr><td>{esc(label)}</td>{cells}</tr>")
    return f'<table class="fatigue" data-athlete="{athlete["person_id"]}"><tr><th></th>{heads}</tr>{"".join(rows)}</table>'


def _meta(data: ReportData) -> str:
    dur = data.duration_s
    who = " vs ".join(_athlete_head(data, p) for p in data.person_ids) or "no athletes"
    parts = [f"<b>Athletes:</b> {who}"]
    if data.date:
        parts.append(f"<b>Date:</b> {esc(data.date)}")
    parts.append(f"<b>Duration:</b> {dur:.1f} s ({int(dur // 60)}:{int(dur % 60):02d}), {data.series.n_frames} frames at "
                 f"{data.series.fps:g} fps")  # fmt: skip
    parts.append(f"<b>3D result analysed:</b> {esc(data.source or 'unknown')}")
    if data.analysed_unix_s > 0:
        when = dt.datetime.fromtimestamp(data.analysed_unix_s, dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
        parts.append(f"<b>Analysed:</b> {when}")
    parts.append(f"<b>Punches:</b> {data.events.n_punches} · <b>defence (slips, ducks, blocks, parries):</b> "
                 f"{data.events.n_evades} · <b>clinches:</b> {data.events.n_clinches}")  # fmt: skip
    layout = f'<p class="note layout">⚠ Camera layout: {esc(data.layout_advice)}</p>' if data.layout_advice else ""
    return '<div class="meta">' + " · ".join(parts[:3]) + "<br>" + " · ".join(parts[3:]) + "</div>" + layout


def _figures(items: list[tuple[str, str]]) -> str:
    return (
        '<div class="charts">'
        + "".join(f"<figure><figcaption>{esc(c)}</figcaption>{s}</figure>" for c, s in items)
        + "</div>"
    )


def render_report(data: ReportData, options: ReportOptions | None = None) -> str:
    """The bout report as one HTML document (UTF-8 text): title and facts, the summary per
    athlete (with blocks, parries and ring zones), punches by type, the summary per round (or
    per ``period_s``), the fatigue indicators (table and chart), punch maps, ring-position
    heatmaps, peak-speed histograms and the work-rate timeline."""
    options = options or ReportOptions()
    summary = summarize(data.events, data.series, data.names, ring_xy_m=data.ring_xy_m, rounds_s=data.rounds_s,
                        period_s=options.period_s)  # fmt: skip
    pids = data.person_ids
    spans, spans_note = periods(data, options)
    per: dict[int, list[tuple[Period, dict[str, Any]]]] = {p: [] for p in pids}
    for span in spans:
        ev, se = slice_bout(data.events, data.series, span.start_s, span.end_s)
        for p in pids:
            per[p].append((span, athlete_summary(ev, se, p, data.ring_xy_m)))
    whole = {a["person_id"]: a for a in summary["athletes"]}
    ring_note = ("The ring outline comes from the session." if data.ring_xy_m is not None else
                 "The session does not give the ring: the dashed box is the extent of both athletes' positions.")  # fmt: skip
    sections = [
        ("summary", "Summary", _summary_table(data, summary)
         + "".join(f"<h3>{_athlete_head(data, p)}: punches by type</h3>{_type_table(data, p)}" for p in pids)
         + '<p class="note">Accuracy = landed / thrown. Landed: the glove reaches the head or trunk; blocked: it stops on '
           "the gloves or arms; missed: neither. Peak glove speed is the wrist's, in the world frame. Clinch time is "
           "shared by both athletes. Blocks and parries are the defender's: a block = the punch's glove stops on his "
           "glove or forearm; a parry = his glove, moving across the punch's line, meets the punching arm and deflects "
           "the glove sideways.</p>"),
        ("rounds", "By round", f'<p class="note">{esc(spans_note)}</p>'
         + "".join(f"<h3>{_athlete_head(data, p)}</h3>{_period_table(data, p, per[p], whole[p])}" for p in pids)),
        ("fatigue", "Fatigue indicators", f'<p class="note">{esc(spans_note)}</p>'
         + "".join(f"<h3>{_athlete_head(data, p)}</h3>{_fatigue_table(whole[p])}" + _figures([(
             "per period, with the least-squares trend", fatigue_chart(whole[p], data.name_of(p), data.color_of(p), p))])
             for p in pids)
         + '<p class="note">Per period: the median of the punches&#39; peak glove speeds, the median height of the gloves '
           "above the chin (mean of both gloves per frame), and punches per minute. Trend: the least-squares slope of "
           "the period values against the periods' middles, per minute; rising, falling, or flat when it rounds to 0 "
           "(unknown with fewer than two periods holding a value).</p>"),
        ("punch-maps", "Punch maps", _figures([(f"{data.name_of(p)} → {charts.opponent_name(data, p)}", charts.punch_map(data, p)) for p in pids])
         + '<p class="note">Front view of the opponent as the puncher sees him. One dot per punch that ended near a region '
           "(head, body, or guard = gloves and forearms), coloured by outcome. The region is measured; the dot's place "
           "inside it is schematic: the side is the punching hand's (left hand on the figure's left).</p>"),
        ("ring", "Ring position", _figures([(data.name_of(p), charts.ring_heatmap(data, p, options)) for p in pids])
         + f'<p class="note">Top view, world frame (metres), mid-hip position; darker = more time. {esc(ring_note)} '
           f"Ring zones (summary rows, mid-hip position, first match wins): corners = within {CORNER_RADIUS_M:g} m of a "
           f"corner; ropes = within {ROPES_BAND_M:g} m of a side; centre = inside the ring scaled by {CENTRE_SCALE:g} about "
           "its middle (for a square ring: the square of half its half-width); midring = the rest of the ring; outside = "
           "beyond the ropes and those bands. Boundaries belong to the zone they bound. Without the ring in the session "
           "the zones are not measured (—).</p>"),
        ("speeds", "Speed distributions", _figures([(data.name_of(p), charts.speed_histogram(data, p, options)) for p in pids])
         + f'<p class="note">Punches per {options.speed_bin_mps:g} m/s of peak glove speed, stacked by outcome; dashed: the mean.</p>'),
        ("work-rate", "Work rate", _figures([("punches over time", charts.work_rate_timeline(data, options))])
         + f'<p class="note">Punches thrown per {options.bin_s:g} s, by the time of the strike; a last, shorter bin has '
           "narrower bars. Grey bands behind the bars: clinches.</p>"),
    ]  # fmt: skip
    body = "".join(
        f'<section id="{sid}" class="{"first" if k == 0 else ""}"><h2>{esc(title)}</h2>{html}</section>'
        for k, (sid, title, html) in enumerate(sections)
    )
    return (
        '<!doctype html><html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{esc(data.title)} — bout report</title><style>{CSS}</style></head><body>"
        '<button class="print screen-only" onclick="window.print()">Print / save as PDF</button>'
        f"<header><h1>{esc(data.title)} — bout report</h1>{_meta(data)}</header>{body}</body></html>"
    )
