"""Punch type from the fist's path, in the thrower's facing frame.

The path's shape is measured against its chord (the straight line from the start to the
strike) in shares of the chord's length, so that a path the 3D estimate shrinks (a two-view
fit moves the fist a fraction of the way) keeps its shape. Rules, in order (thresholds in
``TypeConfig``):

1. **uppercut** when the path scoops: it sags below the chord by ``uppercut_min_sag`` and
   the fist climbs from its lowest point to the strike by ``uppercut_min_climb`` (the fist
   drops from the guard and comes up into the target; a straight punch to the body sinks
   without coming back up);
2. **hook** when its path bulges outwards (to the punching side) from the chord by
   ``hook_min_bulge`` and swings out first: the way from the start to the bulge's apex heads
   ``hook_min_swing_deg`` or more outwards of the straight line from the start to the opponent
   (his centreline ``aim_ahead_m`` ahead of the neck). A straight punch turned aside by a parry
   bulges from its chord as much, because its end turns inwards; until the contact it heads at
   the opponent, and it stays a straight punch;
3. **uppercut** when the fist arrives rising: the upward share of its displacement from
   the fastest frame of the way out to the strike (the arrival) is at least
   ``uppercut_min_rise`` (a hook arrives rising too when the guard is low, hence 2 first), after
   a shallower scoop: its path dips below the chord by ``uppercut_rise_min_sag`` (a fist going
   straight up from the guard is a straight punch the 3D estimate tilted);
4. otherwise a straight punch: a **body shot** when the fist at the strike is below
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
    bulge: largest outward distance of the path from its chord, sag: largest distance below
    the chord, climb: rise of the fist from the path's lowest point to the strike, all three
    over the chord's length (>= 0; 0 for a chord shorter than 1 mm); level: fist height at the
    strike as a fraction of the opponent's hip-to-shoulder height (NaN without one).
    """

    rise: float
    across: float
    bulge: float
    sag: float
    climb: float
    level: float
    apex_deg: float = float("nan")
    """Horizontal heading of the way from the start to the bulge's apex (the path's point
    farthest outwards from the chord), degrees outwards of straight ahead, in (-180, 180];
    NaN without an outward bulge (then the bulge alone decides a hook)."""
    start_fwd_m: float = 0.0
    """Fist's forward distance from the neck at the start, m."""
    start_out_m: float = 0.0
    """Fist's outward (punching side) distance from the neck at the start, m."""


def path_features(
    r: np.ndarray, start: int, fastest: int, peak: int, hand: str, fist_z: float, opp_hip_z: float, opp_shoulder_z: float
) -> PathFeatures:
    """Features of the path ``r`` (frames, 3; facing frame, metres) from ``start`` to ``peak``
    (row indices), arriving from ``fastest``."""
    out = 1.0 if hand == "left" else -1.0
    k0 = min(max(start, fastest), peak - 1) if peak > start else start
    a = r[peak] - r[k0]
    n = float(np.linalg.norm(a))
    u = a / n if n > 1e-9 else np.zeros(3)
    seg = r[start : peak + 1] - r[start]
    chord = r[peak] - r[start]
    cn = float(np.linalg.norm(chord))
    bulge = sag = climb = 0.0
    apex_deg = float("nan")
    if cn > 1e-3:
        c = chord / cn
        dev = seg - np.outer(seg @ c, c)
        apex = int(np.argmax(out * dev[:, 1]))
        bulge = max(0.0, float(out * dev[apex, 1])) / cn
        sag = max(0.0, float(np.max(-dev[:, 2]))) / cn
        climb = float(seg[-1, 2] - np.min(seg[:, 2])) / cn
        if bulge > 0.0:
            apex_deg = float(np.degrees(np.arctan2(out * seg[apex, 1], seg[apex, 0])))
    span = opp_shoulder_z - opp_hip_z
    level = (fist_z - opp_hip_z) / span if np.isfinite(span) and span > 0.1 else float("nan")
    return PathFeatures(rise=float(u[2]), across=float(-out * u[1]), bulge=bulge, sag=sag, climb=climb, level=level,
                        apex_deg=apex_deg, start_fwd_m=float(r[start, 0]), start_out_m=float(out * r[start, 1]))  # fmt: skip


def swing_deg(f: PathFeatures, cfg: TypeConfig) -> float:
    """How far outwards (degrees) of the straight line from the start to the opponent (his
    centreline ``cfg.aim_ahead_m`` ahead of the neck) the way to the bulge's apex heads, in
    [-180, 180); NaN without an apex."""
    aim_deg = float(np.degrees(np.arctan2(-f.start_out_m, cfg.aim_ahead_m - f.start_fwd_m)))
    return (f.apex_deg - aim_deg + 180.0) % 360.0 - 180.0


def punch_type(f: PathFeatures, lead: bool, cfg: TypeConfig) -> str:
    """The ``PUNCH_TYPES`` value of a punch with features ``f`` thrown with the lead (or rear) hand."""
    side = "lead" if lead else "rear"
    if f.sag >= cfg.uppercut_min_sag and f.climb >= cfg.uppercut_min_climb:
        return f"{side}_uppercut"
    if f.bulge >= cfg.hook_min_bulge and not swing_deg(f, cfg) < cfg.hook_min_swing_deg:
        return f"{side}_hook"
    if f.rise >= cfg.uppercut_min_rise and f.sag >= cfg.uppercut_rise_min_sag:
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
