"""Ring zones: where in the ring an athlete stands (pure numpy).

The ring is the polygon of ``session.json``'s ``ring_xy_m`` (corners in order around the
ring, world frame, metres; the rope line). An athlete's position is his mid-hip, horizontal.
Zones, first match wins (so for a small ring a point near a corner is never "centre"):

1. **corners**: within ``CORNER_RADIUS_M`` (1.5 m) of a corner post;
2. **ropes**: within ``ROPES_BAND_M`` (0.9 m) of a side (the segment between two corners);
3. **centre**: inside the ring scaled by ``CENTRE_SCALE`` (0.5) about its centroid: for a
   square ring of half-width h, the square of half-width 0.5 h around the middle;
4. **midring**: the rest of the ring (between the centre and the ropes);
5. **outside**: outside the polygon and farther than the bands above (off the canvas).

Boundaries belong to the zone they bound (closed, to ``EDGE_TOL_M``): a point exactly 0.9 m
from a side is on the ropes, one exactly on the centre square's edge is in the centre.
"""

from __future__ import annotations

import numpy as np

RING_ZONES: tuple[str, ...] = ("centre", "ropes", "corners", "midring", "outside")
"""Zone names; ``ring_zones`` returns indices into this tuple."""
CENTRE_SCALE = 0.5
"""The centre zone is the ring polygon scaled by this about its centroid (dimensionless, (0, 1))."""
ROPES_BAND_M = 0.9
"""A position within this distance of a side is on the ropes (metres)."""
CORNER_RADIUS_M = 1.5
"""A position within this distance of a corner post is in the corner (metres)."""
EDGE_TOL_M = 1e-9
"""Zone boundaries are closed to this tolerance (metres), against rounding."""


def _check_ring(ring_xy_m: np.ndarray) -> np.ndarray:
    ring = np.asarray(ring_xy_m, dtype=np.float64)
    if ring.ndim != 2 or ring.shape[1] != 2 or ring.shape[0] < 3 or not np.isfinite(ring).all():
        raise ValueError(f"ring_xy_m must be (corners >= 3, 2) finite metres, got shape {ring.shape}")
    area = 0.5 * np.sum(ring[:, 0] * np.roll(ring[:, 1], -1) - np.roll(ring[:, 0], -1) * ring[:, 1])
    if abs(area) < 1e-6:
        raise ValueError(f"ring_xy_m: the corners {ring.tolist()} enclose no area")
    return ring


def centroid(ring_xy_m: np.ndarray) -> np.ndarray:
    """(2,) area centroid of the ring polygon (metres)."""
    r = _check_ring(ring_xy_m)
    x, y = r[:, 0], r[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    a = 0.5 * cross.sum()
    return np.array([np.sum((x + xn) * cross), np.sum((y + yn) * cross)]) / (6.0 * a)


def _side_distance(xy: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """(n,) distance of each point to the nearest side segment."""
    a, b = ring, np.roll(ring, -1, axis=0)
    ab = b - a  # (sides, 2)
    ap = xy[:, None, :] - a[None]  # (n, sides, 2)
    t = np.clip(np.einsum("nsk,sk->ns", ap, ab) / np.einsum("sk,sk->s", ab, ab), 0.0, 1.0)
    d = ap - t[..., None] * ab[None]
    return np.linalg.norm(d, axis=2).min(axis=1)


def _inside(xy: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(n,) inside the polygon or on its boundary (to ``EDGE_TOL_M``)."""
    x, y = xy[:, 0:1], xy[:, 1:2]
    a, b = poly[None], np.roll(poly, -1, axis=0)[None]
    crosses = (a[..., 1] > y) != (b[..., 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = a[..., 0] + (y - a[..., 1]) * (b[..., 0] - a[..., 0]) / (b[..., 1] - a[..., 1])
    odd = np.sum(crosses & (x < x_at), axis=1) % 2 == 1
    return odd | (_side_distance(xy, poly) <= EDGE_TOL_M)


def ring_zones(xy_m: np.ndarray, ring_xy_m: np.ndarray) -> np.ndarray:
    """Zone index (into ``RING_ZONES``) of each horizontal position ``xy_m`` (..., 2), metres,
    in the ring ``ring_xy_m`` (corners, 2); ``ValueError`` on a degenerate ring."""
    ring = _check_ring(ring_xy_m)
    pts = np.asarray(xy_m, dtype=np.float64)
    shape = pts.shape[:-1]
    p = pts.reshape(-1, 2)
    c = centroid(ring)
    corner_d = np.linalg.norm(p[:, None, :] - ring[None], axis=2).min(axis=1)
    side_d = _side_distance(p, ring)
    zone = np.full(p.shape[0], RING_ZONES.index("outside"), dtype=np.int64)
    zone[_inside(p, ring)] = RING_ZONES.index("midring")
    zone[_inside(p, c + CENTRE_SCALE * (ring - c))] = RING_ZONES.index("centre")
    zone[side_d <= ROPES_BAND_M + EDGE_TOL_M] = RING_ZONES.index("ropes")
    zone[corner_d <= CORNER_RADIUS_M + EDGE_TOL_M] = RING_ZONES.index("corners")
    return zone.reshape(shape)


def zone_shares(zones: np.ndarray, valid: np.ndarray) -> dict[str, float] | None:
    """Zone name -> percent of the ``valid`` frames spent there (0-100, summing to 100);
    None when no frame is valid. ``zones``, ``valid``: (frames,)."""
    n = int(np.sum(valid))
    if n == 0:
        return None
    z = zones[valid]
    return {name: 100.0 * float(np.sum(z == k)) / n for k, name in enumerate(RING_ZONES)}
