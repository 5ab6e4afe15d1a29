"""Punch type from the fist's path, in the thrower's facing frame.

Rules, in order (thresholds in ``TypeConfig``):

1. **hook** when its path bulges outwards (to the punching side) from the straight line
   between start and strike by ``hook_min_bulge_m``;
2. **uppercut** when the fist arrives rising: the upward share of its displacement from
   the fastest frame of the way out to the strike (the arrival) is at least
   ``uppercut_min_rise`` (a hook arrives rising too when the guard is low, hence 1 first);
3. otherwise a straight punch: a **body shot** when the fist at the strike is below
   ``body_level_frac`` of the way from the opponent's hips to his shoulders, else a
   **jab** (lead hand) or a **cross** (rear hand).

Lead and rear come from the stance at the strike (orthodox: left lead; southpaw: right
lead; a square stance takes the nearest decided one, else orthodox).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.stages.analyze.config import TypeConfig


@dataclass(frozen=True)
class PathFeatures:
    """Shape of a punch's way out (facing frame: x forward, y left, z up).

    Fields: rise, across: upward and inward shares of the arrival direction, in [-1, 1];
    bulge_m: largest outward distance of the path from its chord; level: fist height at
    the strike as a fraction of the opponent's hip-to-shoulder height (NaN without one).
    """

    rise: float
    across: float
    bulge_m: float
    level: float


def path_features(
    r: np.ndarray, start: int, fastest: int, peak: int, hand: str, fist_z: float, opp_hip_z: float, opp_shoulder_z: float
) -> PathFeatures:
    """Features of the path ``r`` (frames, 3) from ``start`` to ``peak`` (row indices),
    arriving from ``fastest``."""
    out = 1.0 if hand == "left" else -1.0
    k0 = min(max(start, fastest), peak - 1) if peak > start else start
    a = r[peak] - r[k0]
    n = float(np.linalg.norm(a))
    u = a / n if n > 1e-9 else np.zeros(3)
    seg = r[start : peak + 1] - r[start]
    chord = r[peak] - r[start]
    cn = float(np.linalg.norm(chord))
    if cn > 1e-9:
        c = chord / cn
        dev = seg - np.outer(seg @ c, c)
        bulge = float(np.max(out * dev[:, 1]))
    else:
        bulge = 0.0
    span = opp_shoulder_z - opp_hip_z
    level = (fist_z - opp_hip_z) / span if np.isfinite(span) and span > 0.1 else float("nan")
    return PathFeatures(rise=float(u[2]), across=float(-out * u[1]), bulge_m=bulge, level=level)


def punch_type(f: PathFeatures, lead: bool, cfg: TypeConfig) -> str:
    """The ``PUNCH_TYPES`` value of a punch with features ``f`` thrown with the lead (or rear) hand."""
    side = "lead" if lead else "rear"
    if f.bulge_m >= cfg.hook_min_bulge_m:
        return f"{side}_hook"
    if f.rise >= cfg.uppercut_min_rise:
        return f"{side}_uppercut"
    if np.isfinite(f.level) and f.level < cfg.body_level_frac:
        return "body_shot"
    return "jab" if lead else "cross"


def is_lead(hand: str, stance: np.ndarray, row: int) -> bool:
    """Whether ``hand`` is the lead hand at ``row`` given the stance codes (frames,) (+1
    orthodox, -1 southpaw, 0 square): the nearest decided stance counts."""
    decided = np.flatnonzero(stance != 0)
    code = int(stance[decided[np.argmin(np.abs(decided - row))]]) if decided.size else 1
    return (hand == "left") == (code > 0)
