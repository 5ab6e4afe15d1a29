"""Camera layout advice: do any two cameras see depth well?

Two cameras measure a point's depth poorly when their rays to it nearly line up: when they
face each other, or look the same way from close by. On the synthetic bouts,
two cameras facing each other (viewing directions 145-162 deg apart) missed more punches and
measured glove speeds worse than two a quarter turn apart (76-97 deg):
docs/design/analytics.md, "Two cameras facing each other".
"""

from __future__ import annotations

import numpy as np

from pipeline.schema.camera import CameraRig

GOOD_PAIR_DEG: tuple[float, float] = (45.0, 135.0)
"""Angles (deg) between two cameras' viewing directions that see depth well: a quarter turn
(90) is best; outside this range a pair faces each other or looks the same way."""


def viewing_angles_deg(rig: CameraRig) -> np.ndarray:
    """(views, views) angle in degrees, in [0, 180], between each pair of optical axes."""
    z = rig.T_world_cam[:, :3, 2]
    z = z / np.linalg.norm(z, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(z @ z.T, -1.0, 1.0)))


def layout_advice(rig: CameraRig) -> str | None:
    """A sentence when no two cameras of ``rig`` are ``GOOD_PAIR_DEG`` apart, else None
    (also None for a single camera, which triangulates nothing)."""
    n = rig.n_views
    if n < 2:
        return None
    ang = viewing_angles_deg(rig)
    iu = np.triu_indices(n, 1)
    lo, hi = GOOD_PAIR_DEG
    pairs = ang[iu]
    if np.any((pairs >= lo) & (pairs <= hi)):
        return None
    k = int(np.argmin(np.minimum(np.abs(pairs - lo), np.abs(pairs - hi))))  # the pair closest to good
    a, b, deg = rig.names[iu[0][k]], rig.names[iu[1][k]], float(pairs[k])
    how = "facing each other" if deg > hi else "looking the same way"
    if n == 2:
        what = f"{a} and {b} look {deg:.0f} deg apart ({how})"
    else:
        what = f"no two of the {n} cameras are {lo:g}-{hi:g} deg apart (the nearest, {a} and {b}, look {deg:.0f} deg apart, {how})"
    return (
        f"{what}: their rays to a fist nearly line up, so its depth is poorly measured, glove "
        f"speeds are measured worse and punches can be missed. Put two cameras {lo:g}-{hi:g} deg apart, about a "
        f"quarter turn (docs/design/analytics.md, \"Two cameras facing each other\")."
    )
