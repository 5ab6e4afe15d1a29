"""A balanced reference: the centre of mass moved so the zero-moment point stays over the feet.

Where the fitted motion accelerates the centre of mass (CoM) beyond what the planted feet
can support, the ground reactions the feed-forward puts on those feet cannot produce it and
the residual root force steers it (measurements: docs/design/physics-effort.md).
``balance_reference`` is a
dynamics filter in the spirit of Yamane and Nakamura (2003), simplified to the CoM: per
person it computes the CoM ``c(t)`` of the reference, the support polygon of the planted
feet's sole points and the zero-moment point (ZMP) of a point mass,
``p = c_xy − c_z / (g + c̈_z) · c̈_xy``; where ``p`` leaves the polygon shrunk by a margin, it
solves for a smooth horizontal CoM offset ``d(t)`` (least squares: the ZMP with the offset,
whose own acceleration counts, on the polygon; the offset's velocity, acceleration and size
small) and moves the body above the planted feet by it with the reference's inverse
kinematics, the planted feet held where they are (the legs take the shift). Frames without
a planted foot have no constraint. Two rounds: the legs' own mass makes the CoM move less
than the pelvis, so the second round solves again on the result.

Pure functions of a compiled scene and arrays; no I/O.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np

from pipeline.backends.mujoco.schedule import foot_site_ids
from pipeline.backends.mujoco.tracking import FOOT_SITES

if TYPE_CHECKING:
    from pipeline.backends.mujoco.config import ReferenceConfig
    from pipeline.backends.mujoco.scene import Scene

GRAVITY_M_S2 = 9.81
LOW_FOOT_M = 0.05
"""With ``ReferenceConfig.balance_support`` ``low``: a foot whose lowest sole point is below
this height (m) supports the body, planted or not (a boxer's pivoting or sliding foot)."""


def centre_of_mass(model: mujoco.MjModel, root_bodies: list[int], qpos: np.ndarray) -> np.ndarray:
    """(frames, persons, 3) world CoM of each person's subtree (``subtree_com`` of its root
    body) at every row of ``qpos`` (frames, nq)."""
    d = mujoco.MjData(model)
    out = np.zeros((qpos.shape[0], len(root_bodies), 3))
    for f in range(qpos.shape[0]):
        d.qpos[:] = qpos[f]
        mujoco.mj_kinematics(model, d)
        mujoco.mj_comPos(model, d)
        out[f] = d.subtree_com[root_bodies]
    return out


def zero_moment_point(com: np.ndarray, fps: float, smooth_frames: float) -> tuple[np.ndarray, np.ndarray]:
    """ZMP of a point mass at ``com`` (frames, ..., 3), accelerations by finite differences of
    the Gaussian-smoothed path (sigma ``smooth_frames``, >= 0). Returns (zmp (frames, ..., 2),
    lever (frames, ...) = c_z / (g + c̈_z) in s², what a horizontal acceleration of the CoM
    (m/s²) moves the ZMP by, in m)."""
    from scipy.ndimage import gaussian_filter1d

    c = gaussian_filter1d(com, smooth_frames, axis=0, mode="nearest") if smooth_frames > 0 else com
    dt = 1.0 / fps
    acc = np.gradient(np.gradient(c, dt, axis=0), dt, axis=0) if com.shape[0] > 2 else np.zeros_like(c)
    lever = com[..., 2] / np.maximum(GRAVITY_M_S2 + acc[..., 2], 0.1 * GRAVITY_M_S2)
    return com[..., :2] - lever[..., None] * acc[..., :2], lever


def shrink_polygon(points: np.ndarray, margin_m: float) -> np.ndarray:
    """Convex hull (counter-clockwise vertices, (n, 2)) of ``points`` (k, 2), each vertex moved
    towards the centroid by ``margin_m`` (at most onto it). Fewer than 3 distinct points, or
    collinear ones, give the points themselves (a segment or a point)."""
    from scipy.spatial import ConvexHull, QhullError

    pts = np.unique(np.asarray(points, dtype=float), axis=0)
    try:
        hull = pts[ConvexHull(pts).vertices] if len(pts) >= 3 else pts
    except QhullError:
        hull = pts
    centre = hull.mean(axis=0)
    r = hull - centre
    n = np.linalg.norm(r, axis=1, keepdims=True)
    return centre + r * np.clip(1.0 - margin_m / np.maximum(n, 1e-9), 0.0, 1.0)


def nearest_in_polygon(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """The point of the convex polygon ``poly`` (counter-clockwise, (n, 2)) nearest to ``p``
    (2,): ``p`` itself when inside."""
    n = len(poly)
    if n >= 3:
        e = np.roll(poly, -1, axis=0) - poly
        cross = e[:, 0] * (p[1] - poly[:, 1]) - e[:, 1] * (p[0] - poly[:, 0])
        if np.all(cross >= 0):
            return p.copy()
    best, best_d = poly[0].copy(), np.inf
    for a, b in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        ab = b - a
        t = float(np.clip((p - a) @ ab / max(float(ab @ ab), 1e-18), 0.0, 1.0))
        q = a + t * ab
        dist = float(np.linalg.norm(p - q))
        if dist < best_d:
            best, best_d = q, dist
    return best


def support_polygons(
    model: mujoco.MjModel, feet: list[list[list[int]]], qpos: np.ndarray, planted: np.ndarray, margin_m: float
) -> list[list[np.ndarray | None]]:
    """Per frame and person: the shrunk support polygon (``shrink_polygon``) of the sole points
    ``feet`` (persons, sides, sites) of the feet ``planted`` (frames, persons, 2), or None
    where no foot is planted."""
    d = mujoco.MjData(model)
    out: list[list[np.ndarray | None]] = []
    for f in range(qpos.shape[0]):
        d.qpos[:] = qpos[f]
        mujoco.mj_kinematics(model, d)
        row: list[np.ndarray | None] = []
        for i, sides in enumerate(feet):
            ids = [s for k in (0, 1) if planted[f, i, k] for s in sides[k]]
            row.append(shrink_polygon(d.site_xpos[ids, :2], margin_m) if ids else None)
        out.append(row)
    return out


def solve_offset(
    zmp: np.ndarray,
    lever: np.ndarray,
    polygons: list[np.ndarray | None],
    fps: float,
    w_vel: float,
    w_acc: float,
    w_size: float,
    iters: int = 8,
) -> np.ndarray:
    """(frames, 2) horizontal CoM offset d that brings the ZMP ``zmp + d − lever · d̈``
    (zmp (frames, 2), lever (frames,) s²) into ``polygons`` (per frame, None: free).

    Active-set least squares: the frames whose shifted ZMP is outside their polygon pull it
    onto the polygon's nearest point (weight 1 per m²), plus ``w_vel`` · |ḋ|² (s²),
    ``w_acc`` · |d̈|² (s⁴) and ``w_size`` · |d|² over all frames; the active set is updated
    ``iters`` times."""
    F = zmp.shape[0]
    d = np.zeros((F, 2))
    if F < 3 or all(p is None for p in polygons):
        return d
    D1 = (np.eye(F, k=1) - np.eye(F))[:-1] * fps
    D2 = (np.eye(F, k=-1)[1:-1] - 2 * np.eye(F)[1:-1] + np.eye(F, k=1)[1:-1]) * fps**2
    # The ZMP of frame f with the offset: zmp + M d, M = I − diag(lever) D2 (D2 padded at the ends).
    D2f = np.vstack([np.zeros((1, F)), D2, np.zeros((1, F))])
    M = np.eye(F) - lever[:, None] * D2f
    reg = w_vel * D1.T @ D1 + w_acc * D2.T @ D2 + w_size * np.eye(F)
    active = np.zeros(F, dtype=bool)
    for _ in range(iters):
        p = zmp + M @ d
        target = p.copy()
        new_active = np.zeros(F, dtype=bool)
        for f, poly in enumerate(polygons):
            if poly is None:
                continue
            q = nearest_in_polygon(p[f], poly)
            if np.linalg.norm(q - p[f]) > 1e-6 or active[f]:
                new_active[f] = True
                target[f] = q
        if not new_active.any():
            break
        active |= new_active
        Ma = M[active]
        A = Ma.T @ Ma + reg
        for ax in range(2):
            # Keep the already-satisfied active frames on their current ZMP (a hinge would let
            # them go; holding them keeps the iteration from oscillating).
            d[:, ax] = np.linalg.solve(A, Ma.T @ (target[active, ax] - zmp[active, ax]))
    return d


def balance_reference(
    scene: Scene,
    qref: np.ndarray,
    planted: np.ndarray,
    fps: float,
    cfg: ReferenceConfig,
    posture_weight: float = 0.0,
    sole_lift_m: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """``qref`` (frames, nq) with each person's body above the planted feet moved so that the
    ZMP stays inside the planted feet's support (module docstring), per ``cfg``'s
    ``balance_*`` fields. ``planted`` (frames, persons, 2): the feet planted in the reference
    (held where they are, flat at ``sole_lift_m``). Returns (qpos (frames, nq), offset
    (frames, persons, 2): the CoM offset asked for, m). ``cfg.balance`` ``none`` returns
    ``qref`` unchanged (a copy) and zero offsets."""
    from pipeline.backends.mujoco.reference import inverse_kinematics

    m, lay = scene.model, scene.layout
    F, P = qref.shape[0], len(lay.persons)
    total = np.zeros((F, P, 2))
    if cfg.balance == "none" or F < 3:
        return qref.copy(), total
    if planted.shape != (F, P, 2):
        raise ValueError(
            f"balance_reference: planted must be {(F, P, 2)} (frames, persons, sides), got {planted.shape}"
        )
    feet = foot_site_ids(lay)
    roots = [p.root_body for p in lay.persons]
    names = scene.site_names
    pinned = np.zeros((P, 2, len(names)), dtype=bool)
    for k, side in enumerate(("left", "right")):
        for n in ("ankle", *FOOT_SITES):
            if f"{side}_{n}" in names:
                pinned[:, k, names.index(f"{side}_{n}")] = True
    dd = mujoco.MjData(m)
    support = planted.copy()
    if cfg.balance_support == "low":
        for f in range(F):
            dd.qpos[:] = qref[f]
            mujoco.mj_kinematics(m, dd)
            for i in range(P):
                for k in (0, 1):
                    support[f, i, k] |= bool(dd.site_xpos[feet[i][k], 2].min() < LOW_FOOT_M)
    q = qref
    for _ in range(cfg.balance_rounds):
        com = centre_of_mass(m, roots, q)
        zmp, lever = zero_moment_point(com, fps, cfg.balance_smooth_frames)
        polys = support_polygons(m, feet, q, support, cfg.balance_margin_m)
        offset = np.stack(
            [
                solve_offset(
                    zmp[:, i],
                    lever[:, i],
                    [row[i] for row in polys],
                    fps,
                    cfg.balance_w_vel,
                    cfg.balance_w_acc,
                    cfg.balance_w_size,
                )
                for i in range(P)
            ],
            axis=1,
        )
        if np.abs(offset).max() < 1e-4:
            break
        total += offset
        # Site targets: the reference's own sites, those above the planted feet moved by the
        # offset; the planted feet's (ankle, sole points) stay and carry a high weight.
        targets = np.zeros((F, P, len(names), 3))
        weight = np.ones((F, P, len(names)))
        for f in range(F):
            dd.qpos[:] = q[f]
            mujoco.mj_kinematics(m, dd)
            targets[f] = dd.site_xpos[scene.site_ids]
            for i in range(P):
                held = pinned[i, 0] & support[f, i, 0] | pinned[i, 1] & support[f, i, 1]
                targets[f, i, ~held, :2] += offset[f, i]
                weight[f, i, held] = 10.0
        q = inverse_kinematics(
            scene, targets, weight, flat=planted, sole_lift_m=sole_lift_m, posture_weight=posture_weight
        )
    return q, total
