"""Foot keypoint sites that agree with a level, planted sole.

The physics stage stands planted feet flat on the floor (``PhysicsConfig.flat_feet``): the
foot's collision sole is level. Where a foot's keypoints sit relative to that sole is a
matter of landmark convention, and the body model's and the detector's differ: on the
synthetic bench anny's toe sites sit 3-6 mm above its sole and its heel sites 14-21 mm, while
the observed planted heel and toes are level with each other. With the sole flat, the sites
then miss their planted keypoints by 8-9 mm (toes low, heel high), and the ankle by 12-14 mm.

``planted_site_offsets`` measures that disagreement on the data: it solves the reference's
inverse kinematics with flat planted feet and takes, per person and foot point, the median
miss over the frames the foot is planted, in the frame of the body holding the site;
``move_sites`` moves the skeleton's sites by it. The collision geometry is untouched, so
the simulated foot still stands on its sole, and its keypoints land where the observed
ones are (the same idea as the fit's ``calibrate_landmarks``). Pure functions.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from pipeline.backends.mujoco.scene import Scene
from pipeline.backends.mujoco.skeleton import Skeleton
from pipeline.backends.mujoco.tracking import FOOT_SITES
from pipeline.schema.keypoints3d import Keypoints3D

FOOT_POINTS: tuple[str, ...] = ("ankle", *FOOT_SITES)
"""Keypoints of a foot whose sites are calibrated (per side: ``left_ankle``, ...)."""


def planted_site_offsets(
    scene: Scene,
    kp: Keypoints3D,
    person_rows: list[int],
    sole_lift_m: float = 0.0,
    min_frames: int = 5,
    max_offset_m: float = 0.03,
) -> list[dict[str, np.ndarray]]:
    """Per person of ``scene``: site name -> offset (3,) in its body's frame that moves the
    site onto the median of where its keypoint is while the foot is planted.

    Feet planted for fewer than ``min_frames`` frames get no offset; offsets are clipped to
    ``max_offset_m`` in length (a larger miss is a bad solve, not a landmark convention).
    """
    from pipeline.backends.mujoco.reference import inverse_kinematics, planted_site_targets

    m = scene.model
    targets, weight, contact = planted_site_targets(scene, kp, person_rows)
    q = inverse_kinematics(scene, targets, weight, flat=contact, sole_lift_m=sole_lift_m)
    d = mujoco.MjData(m)
    F = q.shape[0]
    out: list[dict[str, np.ndarray]] = [{} for _ in person_rows]
    # (side k, site index s) of every calibrated foot point the scene has
    feet = [
        (k, scene.site_names.index(f"{side}_{n}"))
        for k, side in enumerate(("left", "right"))
        for n in FOOT_POINTS
        if f"{side}_{n}" in scene.site_names
    ]
    misses: dict[tuple[int, int], list[np.ndarray]] = {}
    for f in range(F):
        if not contact[f].any():
            continue
        d.qpos[:] = q[f]
        mujoco.mj_kinematics(m, d)
        for i in range(len(person_rows)):
            for k, s in feet:
                if not contact[f, i, k] or weight[f, i, s] <= 0:
                    continue
                sid = int(scene.site_ids[i, s])
                R = d.xmat[m.site_bodyid[sid]].reshape(3, 3)
                misses.setdefault((i, s), []).append(R.T @ (targets[f, i, s] - d.site_xpos[sid]))
    for (i, s), v in misses.items():
        if len(v) < min_frames:
            continue
        off = np.median(np.asarray(v), axis=0)
        norm = float(np.linalg.norm(off))
        out[i][scene.site_names[s]] = off * min(1.0, max_offset_m / norm) if norm > 0 else off
    return out


def move_sites(skel: Skeleton, offsets: dict[str, np.ndarray]) -> Skeleton:
    """``skel`` with the named sites moved by ``offsets`` (body frame; every body frame of a
    rest skeleton is world-aligned, so the offset adds to the site's position)."""
    if not offsets:
        return skel
    known = {s for b in skel.bodies for s, _ in b.sites}
    unknown = sorted(set(offsets) - known)
    if unknown:
        raise ValueError(f"move_sites: skeleton has no sites {unknown}")
    def moved(name: str, pos: tuple[float, float, float]) -> tuple[float, float, float]:
        if name not in offsets:
            return pos
        x, y, z = (float(v) for v in np.asarray(pos, dtype=float) + offsets[name])
        return (x, y, z)

    bodies = [dataclasses.replace(b, sites=tuple((s, moved(s, p)) for s, p in b.sites)) for b in skel.bodies]
    return dataclasses.replace(skel, bodies=tuple(bodies))
