"""The ``cornerman analyze`` summary tables: the bout per athlete, then the fatigue
indicators per period with their trends."""

from __future__ import annotations

from typing import Any

from rich.table import Table

from pipeline.stages.analyze.fatigue import FATIGUE_INDICATORS
from pipeline.stages.analyze.zones import RING_ZONES

ROWS: tuple[tuple[str, str], ...] = (
    ("punches", "punches thrown"),
    ("punches_landed", "landed"),
    ("punches_blocked", "blocked"),
    ("punches_missed", "missed"),
    ("landed_pct", "landed %"),
    ("peak_speed_mean_mps", "peak speed mean (m/s)"),
    ("peak_speed_median_mps", "peak speed median (m/s)"),
    ("peak_speed_max_mps", "peak speed max (m/s)"),
    ("punches_per_min", "punches / min"),
    ("punches_per_min_first_half", "punches / min, 1st half"),
    ("punches_per_min_second_half", "punches / min, 2nd half"),
    ("slips", "slips"),
    ("ducks", "ducks"),
    ("blocks", "blocks"),
    ("parries", "parries"),
    ("clinch_s", "clinch time (s)"),
    ("stance", "stance"),
    ("orthodox_pct", "orthodox %"),
    ("stance_width_mean_m", "stance width (m)"),
    ("guard_height_mean_m", "gloves above chin (m)"),
    ("guard_height_median_m", "gloves above chin, median (m)"),
    ("distance_mean_m", "distance to opponent (m)"),
    *((f"ring_{z}_pct", f"ring {z} % (of time)") for z in RING_ZONES),
)
"""Summary keys (``pipeline.stages.analyze.summary``) and their labels, in table order."""


def summary_table(summary: dict[str, Any], title: str) -> Table:
    """Rows = measures (then one per punch type), columns = athletes."""
    athletes = summary["athletes"]
    table = Table(title=title, caption=f"{summary['duration_s']} s at {summary['fps']:g} fps")
    table.add_column("")
    for a in athletes:
        table.add_column(str(a["name"]), justify="right")

    def cell(v: Any) -> str:
        return "–" if v is None else str(v)

    for key, label in ROWS:
        table.add_row(label, *[cell(a.get(key)) for a in athletes])
    types = list(athletes[0]["types"]) if athletes else []
    for t in types:
        table.add_row(t.replace("_", " "), *[cell(a["types"].get(t)) for a in athletes])
    return table


FATIGUE_LABELS: dict[str, str] = {
    "peak_speed_median_mps": "peak speed median (m/s)",
    "guard_height_median_m": "gloves above chin, median (m)",
    "punches_per_min": "punches / min",
}
"""Fatigue indicators (``FATIGUE_INDICATORS``) and their row labels."""


def fatigue_table(summary: dict[str, Any], title: str) -> Table:
    """Rows = athlete x indicator, columns = the periods (rounds, else minutes), then the
    least-squares trend per minute and its sign."""
    periods = summary["periods"]
    table = Table(title=title, caption="trend: least-squares slope of the period values per minute")
    table.add_column("")
    for p in periods:
        table.add_column(str(p["label"]), justify="right")
    table.add_column("trend / min", justify="right")
    table.add_column("trend")

    def cell(v: Any) -> str:
        return "–" if v is None else str(v)

    for a in summary["athletes"]:
        for key in FATIGUE_INDICATORS:
            t = a["fatigue"][key]
            slope = "–" if t["slope_per_min"] is None else f"{t['slope_per_min']:+g} {t['unit']}"
            table.add_row(f"{a['name']}: {FATIGUE_LABELS[key]}", *[cell(p.get(key)) for p in a["by_period"]], slope,
                          t["trend"])  # fmt: skip
    return table
