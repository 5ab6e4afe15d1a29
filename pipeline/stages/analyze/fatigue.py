"""Fatigue indicators: how an athlete's peak glove speed, guard height and work rate change
over the bout (pure numpy).

Per period (round, or minute when the rounds are not known; ``periods.bout_periods``) three
values: the median of his punches' peak glove speeds (m/s), the median over the frames where
he is known of his gloves' mean height above the chin (m), and his work rate (punches per
minute). The trend of each is the least-squares slope of its period values against the
periods' middles, in units per minute, with its sign spelled out: ``rising`` (> 0),
``falling`` (< 0) or ``flat`` (0 at the reported precision); ``unknown`` with fewer than two
periods holding a value.
"""

from __future__ import annotations

from typing import Any

import numpy as np

FATIGUE_INDICATORS: dict[str, str] = {
    "peak_speed_median_mps": "m/s per min",
    "guard_height_median_m": "m per min",
    "punches_per_min": "punches/min per min",
}
"""Per-period summary keys whose trend is reported -> the unit of their slope."""
SLOPE_DECIMALS = 3
"""Slopes are rounded to this many decimals; a slope that rounds to 0 is ``flat``."""


def slope_per_min(t_min: np.ndarray, values: np.ndarray) -> float | None:
    """Least-squares slope of ``values`` against ``t_min`` (minutes), per minute; None with
    fewer than two points or when every point has the same time."""
    t = np.asarray(t_min, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    if t.shape != y.shape or t.ndim != 1:
        raise ValueError(f"slope_per_min: t_min and values must be (n,) alike, got {t.shape} and {y.shape}")
    if t.size < 2 or np.ptp(t) == 0:
        return None
    dt = t - t.mean()
    return float(np.sum(dt * (y - y.mean())) / np.sum(dt * dt))


def direction(slope: float | None) -> str:
    """``rising``, ``falling``, ``flat`` (rounds to 0 at ``SLOPE_DECIMALS``) or ``unknown`` (None)."""
    if slope is None:
        return "unknown"
    r = round(slope, SLOPE_DECIMALS)
    return "rising" if r > 0 else "falling" if r < 0 else "flat"


def trends(mid_min: list[float], per_period: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Indicator -> ``{"slope_per_min", "unit", "trend", "periods"}`` over the periods whose
    summary (``per_period``, one dict per period, middles ``mid_min`` in minutes) holds a value."""
    out: dict[str, dict[str, Any]] = {}
    for key, unit in FATIGUE_INDICATORS.items():
        pts = [(t, p[key]) for t, p in zip(mid_min, per_period, strict=True) if p.get(key) is not None]
        s = slope_per_min(np.array([t for t, _ in pts]), np.array([v for _, v in pts])) if pts else None
        out[key] = {
            "slope_per_min": round(s, SLOPE_DECIMALS) if s is not None else None,
            "unit": unit,
            "trend": direction(s),
            "periods": len(pts),
        }
    return out
