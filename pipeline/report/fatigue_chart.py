"""The report's fatigue chart: per athlete, the per-period peak glove speed, guard height and
work rate (``pipeline.stages.analyze.fatigue``) with their least-squares trend lines."""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.report.svg import Marks, figure, inline_svg
from pipeline.stages.analyze.fatigue import slope_per_min

PANELS: dict[str, str] = {
    "peak_speed_median_mps": "peak glove speed, median (m/s)",
    "guard_height_median_m": "gloves above chin, median (m)",
    "punches_per_min": "work rate (punches / min)",
}
"""Fatigue indicator (``FATIGUE_INDICATORS``) -> its panel's y label (with unit), in panel order."""


def fatigue_chart(athlete: dict[str, Any], name: str, color: str, pid: int) -> str:
    """Three panels side by side (``PANELS``): one dot per period holding a value, at the
    period's middle (minutes from the first analysed frame), and the dashed trend line with
    its slope per minute and sign in the panel title. ``athlete``: a ``summarize`` athlete."""
    per = athlete["by_period"]
    marks = Marks()
    with figure(690, 220) as fig:
        axes = fig.subplots(1, len(PANELS))
        for ax, (key, label) in zip(axes, PANELS.items(), strict=True):
            pts = [((p["start_s"] + p["end_s"]) / 120.0, p[key], k, p["label"]) for k, p in enumerate(per)
                   if p.get(key) is not None]  # fmt: skip
            trend = athlete["fatigue"][key]
            for t, v, k, lab in pts:
                dot = ax.plot([t], [v], "o", color=color, markersize=6)[0]
                marks.tag(dot, f"mark-{key}-{k}", key=key, period=k, value=v, title=f"{lab}: {v:g}")
            if len(pts) >= 2:
                t = np.array([p[0] for p in pts])
                y = np.array([p[1] for p in pts], dtype=np.float64)
                s = slope_per_min(t, y)
                if s is not None:
                    line = ax.plot(t, y.mean() + s * (t - t.mean()), color="#222222", linestyle=(0, (4, 3)),
                                   linewidth=1)[0]  # fmt: skip
                    marks.tag(line, f"trend-{key}", cls="trend", key=key, slope=trend["slope_per_min"],
                              trend=trend["trend"], title=f"{trend['slope_per_min']:+g} {trend['unit']}")  # fmt: skip
            slope = trend["slope_per_min"]
            head = (
                f"{slope:+g} {trend['unit']}, {trend['trend']}"
                if slope is not None
                else "trend unknown (< 2 periods)"
            )
            ax.set_title(head, fontsize=9)
            ax.set_ylabel(label)
            ax.set_xlabel("time (min)")
            ax.grid(color="#e4e4e4")
            ax.set_axisbelow(True)
            if not pts:
                ax.text(
                    0.5, 0.5, "no value", transform=ax.transAxes, ha="center", va="center", color="#777777"
                )
        return inline_svg(fig, "fatigue", f"{name}: fatigue indicators per period", marks, pid)
