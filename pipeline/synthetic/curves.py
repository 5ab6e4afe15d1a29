"""Smooth scalar profiles and batched rotations used to script the synthetic motion.

Every profile here is at least C1 in time, so joint trajectories built from them are
C1-continuous (the requirement for a physically sensible reference motion).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator


def minjerk(tau: np.ndarray) -> np.ndarray:
    """Minimum-jerk ramp 0 -> 1 on ``tau`` in [0, 1] (clamped outside); zero velocity and
    acceleration at both ends (C2 when glued to constants)."""
    x = np.clip(tau, 0.0, 1.0)
    return x**3 * (10.0 - 15.0 * x + 6.0 * x * x)


def bump(t_s: np.ndarray, t0_s: float, duration_s: float) -> np.ndarray:
    """Smooth bump 0 -> 1 -> 0 (``sin^2``) over ``[t0, t0 + duration]``, zero outside (C1)."""
    x = np.clip((t_s - t0_s) / duration_s, 0.0, 1.0)
    return np.sin(np.pi * x) ** 2


def keyframes(t_s: np.ndarray, key_t_s: list[float], key_values: list[float]) -> np.ndarray:
    """Shape-preserving (PCHIP, C1, no overshoot) interpolation through keys, held constant
    outside the key range (with zero slope at the first and last key, so the hold is C1
    too). Keys closer than 1 ms are merged (the later one wins)."""
    kt = np.asarray(key_t_s, dtype=np.float64)
    kv = np.asarray(key_values, dtype=np.float64)
    order = np.argsort(kt, kind="stable")
    kt, kv = kt[order], kv[order]
    keep = np.append(np.diff(kt) > 1e-3, True)
    kt, kv = kt[keep], kv[keep]
    if kt.size == 1:
        return np.full_like(t_s, kv[0], dtype=np.float64)
    # Flat padding keys: PCHIP gives zero slope next to a flat secant.
    kt = np.concatenate([[kt[0] - 1.0], kt, [kt[-1] + 1.0]])
    kv = np.concatenate([[kv[0]], kv, [kv[-1]]])
    return PchipInterpolator(kt, kv, extrapolate=False)(np.clip(t_s, kt[0], kt[-1]))


def soft_clamp_max(x: np.ndarray, knee: float, limit: float) -> np.ndarray:
    """Identity below ``knee``, smoothly saturating to ``limit`` above it (C2 at the knee)."""
    span = limit - knee
    return np.where(x <= knee, x, knee + span * np.tanh((x - knee) / span))


def soft_clamp_min(x: np.ndarray, knee: float, limit: float) -> np.ndarray:
    """Identity above ``knee``, smoothly saturating to ``limit`` below it (C2 at the knee)."""
    span = knee - limit
    return np.where(x >= knee, x, knee - span * np.tanh((knee - x) / span))


def softmin(values: list[np.ndarray], temperature: float) -> np.ndarray:
    """Smooth minimum (never above the true minimum): ``-T log sum exp(-v / T)``."""
    v = np.stack(values, axis=0)
    m = v.min(axis=0)
    return m - temperature * np.log(np.exp(-(v - m) / temperature).sum(axis=0))


def rot_z(yaw: np.ndarray) -> np.ndarray:
    """(...,) yaw -> (..., 3, 3) rotation about world z (counter-clockwise seen from above)."""
    c, s = np.cos(yaw), np.sin(yaw)
    o, z = np.ones_like(yaw), np.zeros_like(yaw)
    return np.stack([c, -s, z, s, c, z, z, z, o], axis=-1).reshape(np.shape(yaw) + (3, 3))


def rot_y(pitch: np.ndarray) -> np.ndarray:
    """(...,) -> (..., 3, 3) rotation about y; positive tips +z towards +x (leaning forward)."""
    c, s = np.cos(pitch), np.sin(pitch)
    o, z = np.ones_like(pitch), np.zeros_like(pitch)
    return np.stack([c, z, s, z, o, z, -s, z, c], axis=-1).reshape(np.shape(pitch) + (3, 3))


def rot_x(roll: np.ndarray) -> np.ndarray:
    """(...,) -> (..., 3, 3) rotation about x; positive tips +z towards -y (leaning right)."""
    c, s = np.cos(roll), np.sin(roll)
    o, z = np.ones_like(roll), np.zeros_like(roll)
    return np.stack([o, z, z, z, c, -s, z, s, c], axis=-1).reshape(np.shape(roll) + (3, 3))


def rot_zyx(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Body orientation ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (x forward, y left, z up)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def apply(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate local vectors: R (F, 3, 3), v (3,) or (F, 3) -> (F, 3)."""
    if v.ndim == 1:
        return R @ v
    return np.einsum("fij,fj->fi", R, v)


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Wrap angles to (-pi, pi]."""
    return np.asarray((np.asarray(a) + np.pi) % (2 * np.pi) - np.pi)
