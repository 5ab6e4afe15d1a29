"""Footwork: turn a desired (ideal) foot placement over time into planted steps.

A foot is either planted (its pose is *exactly* constant: no sliding) or swinging along a
minimum-jerk path to the place where the ideal placement will be when it lands
(look-ahead), lifted by a ``sin^2`` bump. Only one foot swings at a time and a short
double-support phase separates steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.synthetic.curves import minjerk, wrap_angle


@dataclass(frozen=True)
class StepParams:
    """Step scheduler settings."""

    swing_s: float = 0.2
    """Duration of one swing."""
    double_support_s: float = 0.06
    """Minimum time both feet stay planted between two swings."""
    trigger_m: float = 0.06
    """A foot steps when its placement error exceeds this (metres, yaw error included)."""
    yaw_weight_m_per_rad: float = 0.25
    """Metres of placement error counted per radian of foot-yaw error."""
    lift_m: float = 0.06
    """Peak lift of the foot during a swing."""
    land_ahead_s: float = 0.0
    """Land where the ideal placement will be this much later (> 0 gives a walking stride)."""


@dataclass(frozen=True)
class FeetTrack:
    """Foot poses of one person over frames (index 0 = left, 1 = right).

    Fields:
        origin_m: (F, 2, 3) foot-frame origin (on the ground under the ankle when planted).
        yaw: (F, 2) foot heading (radians, world z).
        contact: (F, 2) bool, True while the foot is planted.
    """

    origin_m: np.ndarray
    yaw: np.ndarray
    contact: np.ndarray


def plan_feet(ideal_xy: np.ndarray, ideal_yaw: np.ndarray, fps: float, p: StepParams) -> FeetTrack:
    """Schedule steps so that both feet follow ``ideal_xy`` (F, 2, 2) / ``ideal_yaw`` (F, 2).

    Planted frames copy the plant pose verbatim, so consecutive contact frames of a foot are
    bit-identical. Swings occupy the open interval between lift-off and landing frames.
    """
    n = ideal_xy.shape[0]
    n_sw = max(3, int(round(p.swing_s * fps)))
    n_ds = max(1, int(round(p.double_support_s * fps)))
    n_ahead = int(round(p.land_ahead_s * fps))
    plant_xy = ideal_xy[0].copy()
    plant_yaw = ideal_yaw[0].copy()
    swings: list[tuple[int, int, int, np.ndarray, float, np.ndarray, float]] = []
    busy_until = -1  # last frame of the current swing (landing frame)
    last_land = -n_ds
    for f in range(n):
        if f < busy_until or f - last_land < n_ds or f + n_sw > n - 1:
            continue
        err = np.linalg.norm(plant_xy - ideal_xy[f], axis=1) + p.yaw_weight_m_per_rad * np.abs(
            wrap_angle(plant_yaw - ideal_yaw[f])
        )
        k = int(np.argmax(err))
        if err[k] <= p.trigger_m:
            continue
        f1 = f + n_sw
        fa = min(f1 + n_ahead, n - 1)
        to_xy = ideal_xy[fa, k].copy()
        to_yaw = float(plant_yaw[k] + wrap_angle(ideal_yaw[fa, k] - plant_yaw[k]))
        swings.append((k, f, f1, plant_xy[k].copy(), float(plant_yaw[k]), to_xy, to_yaw))
        plant_xy[k] = to_xy
        plant_yaw[k] = to_yaw
        busy_until = f1
        last_land = f1

    origin = np.zeros((n, 2, 3))
    yaw = np.zeros((n, 2))
    contact = np.ones((n, 2), dtype=bool)
    # Fill planted poses foot by foot, segment by segment (exact copies of the plant).
    cur_xy = ideal_xy[0].copy()
    cur_yaw = ideal_yaw[0].copy()
    start = np.zeros(2, dtype=int)
    for k_sw, f0, f1, from_xy, from_yaw, to_xy, to_yaw in swings:
        k = k_sw
        origin[start[k] : f0 + 1, k, :2] = cur_xy[k]
        yaw[start[k] : f0 + 1, k] = cur_yaw[k]
        fr = np.arange(f0 + 1, f1)
        s = minjerk((fr - f0) / (f1 - f0))
        origin[fr, k, :2] = from_xy + s[:, None] * (to_xy - from_xy)
        origin[fr, k, 2] = p.lift_m * np.sin(np.pi * (fr - f0) / (f1 - f0)) ** 2
        yaw[fr, k] = from_yaw + s * (to_yaw - from_yaw)
        contact[fr, k] = False
        cur_xy[k] = to_xy
        cur_yaw[k] = to_yaw
        start[k] = f1
    for k in range(2):
        origin[start[k] :, k, :2] = cur_xy[k]
        yaw[start[k] :, k] = cur_yaw[k]
    return FeetTrack(origin_m=origin, yaw=yaw, contact=contact)
