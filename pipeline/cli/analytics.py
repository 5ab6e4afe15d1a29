"""The ``cornerman analyze`` summary table."""

from __future__ import annotations

from typing import Any

from rich.table import Table

ROWS: tuple[tuple[str, str], ...] = (
    ("punches", "punches thrown"),
    ("punches_landed", "landed"),
    ("punches_blocked", "blocked"),
    ("punches_missed", "missed"),
    ("landed_pct", "landed %"),
    ("peak_speed_mean_mps", "peak speed mean (m/s)"),
    ("peak_speed_max_mps", "peak speed max (m/s)"),
    ("punches_per_min", "punches / min"),
    ("punches_per_min_first_half", "punches / min, 1st half"),
    ("punches_per_min_second_half", "punches / min, 2nd half"),
    ("slips", "slips"),
    ("ducks", "ducks"),
    ("clinch_s", "clinch time (s)"),
    ("stance", "stance"),
    ("orthodox_pct", "orthodox %"),
    ("stance_width_mean_m", "stance width (m)"),
    ("guard_height_mean_m", "gloves above chin (m)"),
    ("distance_mean_m", "distance to opponent (m)"),
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
