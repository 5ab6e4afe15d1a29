"""How far a glove is from each region of the opponent's body (pure numpy).

The volumes are ``CapsuleProxy``'s (an average adult in boxing gloves: the same volumes
the penetration metric measures and the synthetic bout separates its boxers with), grouped
into regions: ``head`` (the head sphere), ``body`` (the trunk capsules), ``arms`` (upper
arms, forearms and gloves: what a guard blocks with). Leg capsules are left out. A gap is
the distance between the glove sphere and the nearest volume of a region minus both radii:
negative = overlap, 0 = touching.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from pipeline.evaluate.physics_metrics import CapsuleProxy
from pipeline.geometry.segments import point_weights, segment_distance

REGIONS: tuple[str, ...] = ("head", "body", "arms")
"""Regions of the opponent's body a glove can reach, in this order."""

Volume = tuple[str, str, float]


def _region_of(a: str, b: str) -> str | None:
    names = a + " " + b
    if "ear" in names or "nose" in names or "eye" in names:
        return "head"
    if "knee" in names or "ankle" in names:
        return None
    if "elbow" in names or "wrist" in names:
        return "arms"
    return "body"


@cache
def region_volumes(proxy: CapsuleProxy = CapsuleProxy()) -> dict[str, tuple[Volume, ...]]:
    """Region -> the proxy's capsules ``(a, b, radius_m)`` in it."""
    out: dict[str, list[Volume]] = {r: [] for r in REGIONS}
    for a, b, r in proxy.segments:
        region = _region_of(a, b)
        if region is not None:
            out[region].append((a, b, r))
    return {k: tuple(v) for k, v in out.items()}


@cache
def glove_volume(hand: str, proxy: CapsuleProxy = CapsuleProxy()) -> tuple[str, float]:
    """(point name, radius_m) of the glove sphere of ``hand`` (``"left"``/``"right"``);
    ``ValueError`` when the proxy has none."""
    for a, b, r in proxy.segments:
        if a == b and a.startswith(f"frac:{hand}_elbow,{hand}_wrist"):
            return a, r
    raise ValueError(f"CapsuleProxy has no glove sphere for hand {hand!r}")


def body_point(xyz: np.ndarray, name: str, joint_names: tuple[str, ...]) -> np.ndarray:
    """(..., 3) position of a named body point (``geometry.segments.point_weights``) in
    joints ``xyz`` (..., joints, 3)."""
    idx, w = point_weights(name, joint_names)
    return np.asarray(sum(wk * xyz[..., i, :] for i, wk in zip(idx, w, strict=True)))


def glove_gaps(
    attacker_xyz: np.ndarray,
    hand: str,
    opponent_xyz: np.ndarray,
    joint_names: tuple[str, ...],
    proxy: CapsuleProxy = CapsuleProxy(),
) -> dict[str, np.ndarray]:
    """Region -> (...,) gap in metres between ``hand``'s glove and that region.

    ``attacker_xyz`` and ``opponent_xyz`` are (..., joints, 3) in the same frame; both
    must hold every joint the proxy names (``ValueError`` otherwise).
    """
    point, r_glove = glove_volume(hand, proxy)
    g = body_point(attacker_xyz, point, joint_names)
    out: dict[str, np.ndarray] = {}
    for region, vols in region_volumes(proxy).items():
        gaps = [
            segment_distance(g, g, body_point(opponent_xyz, a, joint_names), body_point(opponent_xyz, b, joint_names))
            - r
            - r_glove
            for a, b, r in vols
        ]
        out[region] = np.min(np.stack(gaps, axis=0), axis=0)
    return out
