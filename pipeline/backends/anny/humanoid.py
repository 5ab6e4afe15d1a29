"""Physics humanoid from a fitted anny body: anny's main skeleton, convex-hull (or capsule)
collision geoms cut from the body mesh by skinning weights, mass from volume at 985 kg/m³.

The 36-bone anny rig is merged into 19 rigid bodies (``BODY_BONES``): pelvis (root,
pelvis.L/R, spine05), spine (spine04-03), torso (spine02-01), neck (neck01-03), head, and
per side clavicle (+shoulder01), upper arm, forearm, hand, thigh, shin, foot (the "02" twist
bones are merged with their "01" parent). A body's frame follows its first bone. Hinges:
3 per ball joint (spine, chest, neck, head, shoulders, hips), 2 for clavicles (elevation,
protraction), wrists and ankles, 2 for elbows and knees (flexion about the anatomical axis,
then twist about the forearm / shin) — 44 hinges, nv = 50 per person.

Frames follow ``mujoco.skeleton``: the rest pose (anny's A-pose) faces +x with the left
on +y (anny's rest faces -y with the left on +x: rotated by Rz(+90°)), world z-up, soles at
z = 0, pelvis origin (anny's root head) at the body origin, body frames world-aligned at
rest. Geometry is expressed in each body frame.

Collision geometry (``geometry``):
  ``mesh``: per body the convex hull of its vertices (dominant skinning bone). Hulls fill
  concavities; a hull larger than ``1 + HULL_SLACK`` times its segment's closed volume
  (the mesh faces of the segment, open boundaries capped by fans) is shrunk radially toward
  the body's bone axis (volume ∝ s²) down to that bound (not feet — soles — nor hands).
  ``capsule``: per body one capsule along the principal axis of the hull points (pelvis,
  spine, torso: two vertical ones, left and right half), its radius solved so that its
  volume equals the hull's (same masses as ``mesh``); feet get a box sole with the foot
  hull's volume. Light bodies (the clavicles own 2 decimated vertices) get a
  capsule along the bone with ``MIN_BODY_MASS_KG``.

Keypoint sites: each ``COCO17_FEET`` keypoint hangs on the body of its anatomical bone
(``SITE_BODY``) at the median over valid frames of ``G_b^T (kp_f - x_b,f)`` (BodyFit pose
FK; the fit's keypoints carry per-person landmark offsets the mesh lacks), or at the rest
regressor keypoint when no keypoints are given.
"""

from __future__ import annotations

import logging
from typing import Literal

import numpy as np
import torch
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from pipeline.backends.anny.body import RestMesh, rest_mesh
from pipeline.backends.anny.fk import forward_kinematics, keypoints_from_bones
from pipeline.backends.anny.model import anny_body
from pipeline.backends.mujoco.skeleton import BodyDef, GeomDef, JointDef, Skeleton, hull_volume_m3
from pipeline.schema.joints import COCO17_FEET
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit

log = logging.getLogger(__name__)

DENSITY_KG_M3 = 985.0
MIN_BODY_MASS_KG = 0.3
"""Lightest body (a 0.07 kg collar destabilised the video-rate step in a probe)."""
GLOVE_RADIUS_M = 0.065
"""Radius of the gloved fist (a 12-16 oz boxing glove is ~13 cm across); its mass is the
sphere's volume at the body density (~1.1 kg: hand and glove)."""
HULL_SLACK = 0.10
"""A hull may exceed its segment's closed volume by this fraction before it is shrunk."""

R_ANNY_TO_PHYS = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
"""Rz(+90°): anny rest (facing -y, left +x) -> physics rest (facing +x, left +y)."""

_SIDES = (("left", "L", 1.0), ("right", "R", -1.0))


def _body_bones() -> dict[str, tuple[str, tuple[str, ...]]]:
    out: dict[str, tuple[str, tuple[str, ...]]] = {
        "pelvis": ("", ("pelvis.L", "pelvis.R", "spine05", "root")),  # one shared head; frame: root
        "spine": ("pelvis", ("spine04", "spine03")),
        "torso": ("spine", ("spine02", "spine01")),
        "neck": ("torso", ("neck01", "neck02", "neck03")),
        "head": ("neck", ("head",)),
    }
    for side, S, _ in _SIDES:
        out[f"{side}_clavicle"] = ("torso", (f"clavicle.{S}", f"shoulder01.{S}"))
        out[f"{side}_upper_arm"] = (f"{side}_clavicle", (f"upperarm01.{S}", f"upperarm02.{S}"))
        out[f"{side}_forearm"] = (f"{side}_upper_arm", (f"lowerarm01.{S}", f"lowerarm02.{S}"))
        out[f"{side}_hand"] = (f"{side}_forearm", (f"wrist.{S}",))
    for side, S, _ in _SIDES:
        out[f"{side}_thigh"] = ("pelvis", (f"upperleg01.{S}", f"upperleg02.{S}"))
        out[f"{side}_shin"] = (f"{side}_thigh", (f"lowerleg01.{S}", f"lowerleg02.{S}"))
        out[f"{side}_foot"] = (f"{side}_shin", (f"foot.{S}",))
    return out


BODY_BONES: dict[str, tuple[str, tuple[str, ...]]] = _body_bones()
"""Body name -> (parent body, anny bones merged into it). The first bone's rest head is the
body origin; the last bone's world rotation is the body's orientation, so the proximal
joint's hinges absorb the twist bones ("02") of the group (shoulder/hip: exactly)."""

SITE_BODY: dict[str, str] = {
    **{n: "head" for n in ("nose", "left_eye", "right_eye", "left_ear", "right_ear")},
    **{
        f"{side}_{kp}": f"{side}_{body}"
        for side, _, _ in _SIDES
        for kp, body in (
            ("shoulder", "upper_arm"), ("elbow", "forearm"), ("wrist", "forearm"), ("hip", "thigh"),
            ("knee", "shin"), ("ankle", "shin"), ("big_toe", "foot"), ("small_toe", "foot"), ("heel", "foot"),
        )
    },
}
"""Keypoint (site) name -> body it is attached to."""


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if n < 1e-9:
        raise ValueError(f"degenerate axis {v.tolist()}")
    return v / n


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.arccos(np.clip(_unit(a) @ _unit(b), -1.0, 1.0)))


def _joints(name: str, head: dict[str, np.ndarray]) -> tuple[JointDef, ...]:
    """Hinges of body ``name`` (physics frame axes, ranges relative to the A-pose rest).

    ``head``: rest joint centres (physics frame) by key (``shoulder_L``, ``elbow_L``, ...).
    """
    J = JointDef
    X, Y, Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
    if name == "spine":
        # Extension to -0.6: the body merges two anny spine bones, each allowed -0.3 by
        # the fit's prior (``anny.priors._LIMITS``); -0.4 held the bench's boxers up.
        return (J("spine_x", X, (-0.4, 0.4), 1.0), J("spine_y", Y, (-0.6, 0.8), 1.0), J("spine_z", Z, (-0.5, 0.5), 0.8))
    if name == "torso":
        return (J("chest_x", X, (-0.4, 0.4), 1.0), J("chest_y", Y, (-0.6, 0.6), 1.0), J("chest_z", Z, (-0.5, 0.5), 0.8))
    if name == "neck":
        return (J("neck_x", X, (-0.7, 0.7), 0.3), J("neck_y", Y, (-0.8, 1.0), 0.3), J("neck_z", Z, (-1.3, 1.3), 0.3))
    if name == "head":
        return (J("head_x", X, (-0.6, 0.6), 0.2), J("head_y", Y, (-0.7, 0.7), 0.2), J("head_z", Z, (-0.8, 0.8), 0.2))
    side = name.split("_")[0]
    S, s = ("L", 1.0) if side == "left" else ("R", -1.0)

    def lr(lo: float, hi: float) -> tuple[float, float]:  # a left range, mirrored for the right
        return (lo, hi) if s > 0 else (-hi, -lo)

    if name.endswith("_clavicle"):  # x: elevation, z: pro/retraction
        # z to ±0.9: the clavicle and shoulder01 bones it merges, ±0.4 and ±0.5 in the
        # fit's prior; at ±0.6 the girdles of the bench's boxers sat at the limit.
        return (J(f"{side}_clavicle_x", X, lr(-0.6, 0.8), 0.3), J(f"{side}_clavicle_z", Z, (-0.9, 0.9), 0.3))
    if name.endswith("_upper_arm"):
        # Flexion first (as mujoco.skeleton: y-x-z is singular only at 90° abduction).
        # x ranges: the rest arm is already abducted ~0.7 rad (A-pose).
        return (
            J(f"{side}_shoulder_y", Y, (-3.1, 1.2), 0.5),
            J(f"{side}_shoulder_x", X, lr(-1.5, 2.4), 0.5),
            J(f"{side}_shoulder_z", Z, (-1.6, 1.6), 0.35),
        )
    if name.endswith("_forearm"):  # flexion about the anatomical axis (+ = flexion), then pronation
        ua = head[f"elbow_{S}"] - head[f"shoulder_{S}"]
        fa = head[f"wrist_{S}"] - head[f"elbow_{S}"]
        rest = _angle(ua, fa)
        return (
            J(f"{side}_elbow", tuple(_unit(np.cross(ua, fa))), (-rest - 0.05, 2.6 - rest), 0.35),
            J(f"{side}_elbow_twist", tuple(_unit(fa)), (-1.4, 1.4), 0.15),
        )
    if name.endswith("_hand"):
        fa = _unit(head[f"wrist_{S}"] - head[f"elbow_{S}"])
        flex = _unit(np.cross(head[f"elbow_{S}"] - head[f"shoulder_{S}"], fa))
        dev = _unit(np.cross(fa, flex))
        return (J(f"{side}_wrist_flex", tuple(flex), (-1.2, 1.2), 0.1), J(f"{side}_wrist_dev", tuple(dev), (-0.7, 0.7), 0.1))
    if name.endswith("_thigh"):
        return (
            J(f"{side}_hip_x", X, lr(-0.5, 1.1), 1.0),
            J(f"{side}_hip_y", Y, (-2.3, 0.6), 1.0),
            J(f"{side}_hip_z", Z, (-1.1, 1.1), 0.6),  # a boxer pivots on the lead foot: ±0.9 was hit
        )
    if name.endswith("_shin"):  # + = flexion (shank backwards): +y made orthogonal to the shin
        sh = _unit(head[f"ankle_{S}"] - head[f"knee_{S}"])
        axis = _unit(np.array(Y) - sh * sh[1])
        th = head[f"knee_{S}"] - head[f"hip_{S}"]
        rest = float(np.arctan2(np.cross(th, sh) @ axis, th @ sh / np.linalg.norm(th)))
        return (J(f"{side}_knee", tuple(axis), (-0.05 - rest, 2.7 - rest), 1.0), J(f"{side}_knee_twist", tuple(sh), (-0.6, 0.6), 0.3))
    if name.endswith("_foot"):
        return (J(f"{side}_ankle_y", Y, (-0.9, 0.8), 0.6), J(f"{side}_ankle_x", X, (-0.5, 0.5), 0.4))
    raise ValueError(f"no joints defined for body {name!r}")


def _segment_volumes(verts: np.ndarray, faces: np.ndarray, vbody: np.ndarray, n_bodies: int) -> np.ndarray:
    """Closed volume (m³) of each body's mesh segment: its faces (a face goes to the body of
    two of its vertices, else of its first) plus fans from each open boundary loop's centroid."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    fb = np.where(vbody[faces[:, 1]] == vbody[faces[:, 2]], vbody[faces[:, 1]], vbody[faces[:, 0]])
    out = np.zeros(n_bodies)
    nv = len(verts)
    for b in range(n_bodies):
        f = faces[fb == b]
        if len(f) == 0:
            continue
        vol = np.einsum("ij,ij->i", verts[f[:, 0]], np.cross(verts[f[:, 1]], verts[f[:, 2]])).sum() / 6.0
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        code = e[:, 0] * nv + e[:, 1]
        bnd = e[~np.isin(code, e[:, 1] * nv + e[:, 0])]
        if len(bnd):
            adj = coo_matrix((np.ones(len(bnd)), (bnd[:, 0], bnd[:, 1])), shape=(nv, nv))
            _, lab = connected_components(adj, directed=False)
            loop = lab[bnd[:, 0]]
            cent = np.zeros((lab.max() + 1, 3))
            cnt = np.zeros(lab.max() + 1)
            np.add.at(cent, loop, verts[bnd[:, 0]])
            np.add.at(cnt, loop, 1.0)
            p = cent[loop] / cnt[loop, None]
            vol += np.einsum("ij,ij->i", p, np.cross(verts[bnd[:, 1]], verts[bnd[:, 0]])).sum() / 6.0
        out[b] = vol
    return out


def _capsule_of_volume(pts: np.ndarray, volume: float, axis: np.ndarray | None = None) -> GeomDef:
    """Capsule along ``axis`` (default: the principal axis of ``pts``) through their mean,
    spanning their 2-98 % extent, with the radius that gives ``volume`` (a sphere if the
    extent is too short)."""
    c = pts.mean(axis=0)
    if axis is None:
        _, _, vt = np.linalg.svd(pts - c, full_matrices=False)
        ax = vt[0]
    else:
        ax = _unit(axis)
    t = (pts - c) @ ax
    lo, hi = np.percentile(t, [2.0, 98.0])
    ext = float(hi - lo)
    # pi r² ext - 2/3 pi r³ = volume, for r <= ext / 2 (monotone there)
    if volume >= np.pi * ext**3 / 6.0:
        r = float(np.cbrt(3.0 * volume / (4.0 * np.pi)))
        mid = c + ax * (0.5 * (lo + hi))
        return GeomDef("sphere", _t(mid), (0.0, 0.0, 0.0), r)
    a_, b_ = 0.0, ext / 2.0
    for _ in range(60):
        r = 0.5 * (a_ + b_)
        if np.pi * r**2 * ext - 2.0 / 3.0 * np.pi * r**3 < volume:
            a_ = r
        else:
            b_ = r
    r = 0.5 * (a_ + b_)
    return GeomDef("capsule", _t(c + ax * (lo + r)), _t(c + ax * (hi - r)), r)


def _t(v: np.ndarray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _capsule_for_mass(a: np.ndarray, b: np.ndarray, mass_kg: float) -> GeomDef:
    """Capsule from ``a`` to ``b`` whose volume × density is ``mass_kg``."""
    length = float(np.linalg.norm(b - a))
    target = mass_kg / DENSITY_KG_M3
    lo, hi = 1e-4, 0.5
    for _ in range(60):
        r = 0.5 * (lo + hi)
        if np.pi * r**2 * length + 4.0 / 3.0 * np.pi * r**3 < target:
            lo = r
        else:
            hi = r
    return GeomDef("capsule", _t(a), _t(b), 0.5 * (lo + hi))


def _shrunk_hull(pts: np.ndarray, axis_a: np.ndarray, axis_b: np.ndarray, target_m3: float) -> np.ndarray:
    """Hull vertices of ``pts`` scaled radially toward the line a-b so the hull has ``target_m3``."""
    hull = ConvexHull(pts)
    v = pts[hull.vertices]
    if hull.volume <= target_m3:
        return v
    u = _unit(axis_b - axis_a)
    d = v - axis_a
    along = np.outer(d @ u, u)
    s = float(np.sqrt(target_m3 / hull.volume))
    return axis_a + along + s * (d - along)


def pose_fk(rig: str, shape: np.ndarray, pose: np.ndarray, root_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World rotations (n, bones, 3, 3), posed heads (n, bones, 3) and regressor keypoints
    (n, 23, 3) of one shape at poses (n, bones, 3) and root positions (n, 3)."""
    body = anny_body(rig)
    with torch.no_grad():
        coeffs = body.shape_coeffs(torch.as_tensor(shape, dtype=torch.float64)[None])
        heads = body.rest_heads(coeffs)
        G, x = forward_kinematics(
            body, torch.as_tensor(pose, dtype=torch.float64), torch.as_tensor(root_m, dtype=torch.float64), heads
        )
        kp = keypoints_from_bones(body, G, x, heads, body.rest_kp_points(coeffs))
    return G.numpy(), x.numpy(), kp.numpy()


def _site_offsets(
    bodyfit: BodyFit, p: int, keypoints: Keypoints3D | None, anchor: dict[str, int], frame: dict[str, int]
) -> dict[str, np.ndarray]:
    """Keypoint site offsets in their bodies' frames (physics axes): median of
    ``G_frame^T (kp - x_origin)`` over the frames where both the fit and the keypoint are
    valid; the rest-pose regressor keypoint for keypoints never observed (or no ``keypoints``)."""

    def offsets(G: np.ndarray, x: np.ndarray, xyz: np.ndarray, ok: np.ndarray, names: tuple[str, ...]) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        for name, bname in SITE_BODY.items():
            if name not in names or not ok[:, names.index(name)].any():
                continue
            j, b, fb = names.index(name), anchor[bname], frame[bname]
            good = ok[:, j]
            local = np.einsum("nji,nj->ni", G[good, fb], xyz[good, j] - x[good, b])  # G^T (kp - x)
            out[name] = R_ANNY_TO_PHYS @ np.median(local, axis=0)
        return out

    nb = len(bodyfit.bone_names)
    G0, x0, kp0 = pose_fk(bodyfit.rig, bodyfit.shape[p], np.zeros((1, nb, 3)), np.zeros((1, 3)))
    out = offsets(G0, x0, kp0, np.ones(kp0.shape[:2], dtype=bool), COCO17_FEET)
    if keypoints is None:
        return out
    pid = int(bodyfit.person_ids[p])
    prow = np.flatnonzero(keypoints.person_ids == pid)
    rows = np.flatnonzero(bodyfit.valid[:, p])
    _, i_fit, i_kp = np.intersect1d(bodyfit.frame_indices[rows], keypoints.frame_indices, return_indices=True)
    if prow.size == 0 or i_fit.size == 0:
        log.info("anny humanoid: person %d has no keypoints in the fit's frames; sites from the rest regressor", pid)
        return out
    rows = rows[i_fit]
    G, x, _ = pose_fk(bodyfit.rig, bodyfit.shape[p], bodyfit.pose[rows, p], bodyfit.root_translation_m[rows, p])
    observed = offsets(G, x, keypoints.xyz_m[i_kp, prow[0]], keypoints.valid[i_kp, prow[0]], keypoints.joint_names)
    return {**out, **observed}


def skeleton_from_bodyfit(
    bodyfit: BodyFit,
    person_index: int,
    keypoints: Keypoints3D | None = None,
    geometry: Literal["mesh", "capsule"] = "mesh",
    decimate: bool = True,
    glove_radius_m: float = GLOVE_RADIUS_M,
) -> Skeleton:
    """Rest-pose physics skeleton of one person of an anny ``BodyFit`` (see module docstring).

    ``person_index`` indexes ``bodyfit.person_ids``; ``keypoints`` (the fit's ``Keypoints3D``)
    places the sites; ``decimate`` uses the 1,229-vertex mesh for the hulls (full mesh: 13,718).
    ``glove_radius_m`` > 0 gives each hand a boxing glove instead of its mesh (``_glove``);
    0 keeps anny's open hand.
    Raises ``ValueError`` for a non-anny fit, a bad index or an unknown geometry.
    """
    if bodyfit.body_model != "anny":
        raise ValueError(f"skeleton_from_bodyfit needs an anny BodyFit, got body_model={bodyfit.body_model!r}")
    if not 0 <= person_index < bodyfit.person_ids.shape[0]:
        raise ValueError(f"skeleton_from_bodyfit: person_index {person_index} out of range {bodyfit.person_ids.shape[0]}")
    if geometry not in ("mesh", "capsule"):
        raise ValueError(f"skeleton_from_bodyfit: unknown geometry {geometry!r} (mesh, capsule)")
    rm = rest_mesh(bodyfit.shape[person_index], bodyfit.rig, decimate)
    bone = {n: i for i, n in enumerate(rm.bone_names)}
    missing = [b for _, bones in BODY_BONES.values() for b in bones if b not in bone]
    if missing:
        raise ValueError(f"anny rig {bodyfit.rig!r} lacks bones {missing}")
    names = list(BODY_BONES)
    anchor = {n: bone[bones[0]] for n, (_, bones) in BODY_BONES.items()}  # origin bone
    frame = {n: bone[bones[-1]] for n, (_, bones) in BODY_BONES.items()}  # orientation bone
    R = R_ANNY_TO_PHYS
    verts = rm.verts_m @ R.T
    heads = rm.bone_head_m @ R.T
    tails = rm.bone_tail_m @ R.T
    origin = {n: heads[anchor[n]] for n in names}
    pelvis0 = origin["pelvis"]
    key_heads = {"hip": "upperleg01", "knee": "lowerleg01", "ankle": "foot", "shoulder": "upperarm01",
                 "elbow": "lowerarm01", "wrist": "wrist"}
    jh = {f"{k}_{S}": heads[bone[f"{b}.{S}"]] for k, b in key_heads.items() for _, S, _ in _SIDES}

    bone_body = np.full(len(rm.bone_names), -1)
    for i, n in enumerate(names):
        for b in BODY_BONES[n][1]:
            bone_body[bone[b]] = i
    vbody = bone_body[rm.vertex_bone]
    seg_vol = _segment_volumes(verts, rm.faces, vbody, len(names))

    sites = _site_offsets(bodyfit, person_index, keypoints, anchor, frame)
    bodies: list[BodyDef] = []
    for i, n in enumerate(names):
        parent, bones = BODY_BONES[n]
        o = origin[n]
        a_ax = heads[bone[bones[0]]] - o
        b_ax = tails[bone[bones[-1]]] - o
        pts = verts[vbody == i] - o
        if n.endswith("_foot") and len(pts) >= 4:
            # The fit's landmark offsets may put the heel/toe keypoints below anny's sole
            # (the detector's "toe" is not anny's); in the simulation the sole is what meets
            # the floor, so foot points are lifted onto the sole right under them (the lowest
            # foot vertices within 3 cm in x-y: the sole curves up at the toes and the heel,
            # and a foot rolled onto its toes must not push the toe points into the floor).
            # They may still lie a few mm beyond the mesh's outline (in front of the toes, out
            # at the little toe), so the foot's hull is taken around them too: no foot point
            # can then pass below the part of the body that stands on the floor.
            foot_keys = [k for k in (f"{n[: -len('_foot')]}_{p}" for p in ("heel", "big_toe", "small_toe")) if k in sites]
            for k in foot_keys:
                sites[k] = np.array([sites[k][0], sites[k][1], max(float(sites[k][2]), _sole_under(pts, sites[k]))])
            pts = np.vstack([pts, *(sites[k][None] for k in foot_keys)])
        geoms: list[GeomDef] = []
        vol = 0.0
        if len(pts) >= 4:
            try:
                vol = hull_volume_m3(pts)
            except ValueError:
                vol = 0.0
        if n.endswith("_hand") and glove_radius_m > 0:
            geoms.append(_glove(heads[bone[bones[0]]] - o, tails[bone[bones[-1]]] - o, glove_radius_m))
        elif vol * DENSITY_KG_M3 < MIN_BODY_MASS_KG:
            # Too light (clavicles): a capsule along the body's bones with the minimum mass.
            geoms.append(_capsule_for_mass(a_ax, b_ax, MIN_BODY_MASS_KG))
        else:
            # Feet (soles) and hands (gloves) keep their full hull.
            target = max(seg_vol[i] * (1.0 + HULL_SLACK), MIN_BODY_MASS_KG / DENSITY_KG_M3)
            hull_v = _shrunk_hull(pts, a_ax, b_ax, np.inf if n.endswith(("_foot", "_hand")) else target)
            hv = hull_volume_m3(hull_v)
            if geometry == "mesh":
                geoms.append(GeomDef("mesh", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, tuple(_t(v) for v in hull_v)))
            elif n.endswith("_foot"):
                geoms.append(_sole_box(hull_v, hv))
            elif n in ("pelvis", "spine", "torso"):
                # Wide, shallow trunk: two vertical capsules (left / right half), not one ball.
                for half in (hull_v[hull_v[:, 1] >= 0.0], hull_v[hull_v[:, 1] < 0.0]):
                    geoms.append(_capsule_of_volume(half, 0.5 * hv, np.array([0.0, 0.0, 1.0])))
            else:
                geoms.append(_capsule_of_volume(hull_v, hv))
        bsites = tuple((k, _t(v)) for k, v in sites.items() if SITE_BODY[k] == n)
        rel = o - (origin[parent] if parent else o)
        bodies.append(BodyDef(n, parent, _t(rel), () if not parent else _joints(n, jh), tuple(geoms), bsites))

    def dist(a: str, b: str) -> float:
        return float(np.linalg.norm(jh[a] - jh[b]))

    lengths = {
        "height": float(verts[:, 2].max()),
        "upper_arm": dist("shoulder_L", "elbow_L"),
        "forearm": dist("elbow_L", "wrist_L"),
        "thigh": dist("hip_L", "knee_L"),
        "shin": dist("knee_L", "ankle_L"),
        "hip_width": dist("hip_L", "hip_R"),
        "shoulder_width": dist("shoulder_L", "shoulder_R"),
        "sole_offset": 0.0,
    }
    return Skeleton(bodies=tuple(bodies), lengths_m=lengths, pelvis_height_m=float(pelvis0[2]))


def _glove(wrist: np.ndarray, hand_tip: np.ndarray, radius_m: float) -> GeomDef:
    """A boxing glove: a sphere of ``radius_m`` around the fist, its centre one radius past
    the wrist along the hand (body frame). anny's rest hand is open and flat, reaching
    12-20 cm past the wrist; a gloved fist is a ball."""
    return GeomDef("sphere", _t(wrist + _unit(hand_tip - wrist) * radius_m), (0.0, 0.0, 0.0), radius_m)


def _sole_under(foot_pts: np.ndarray, site: np.ndarray, radius_m: float = 0.03) -> float:
    """Height of the foot's underside below ``site`` (body frame): the lowest vertex within
    ``radius_m`` in x-y, or the nearest vertex's height when none is that close."""
    d = np.linalg.norm(foot_pts[:, :2] - site[:2], axis=1)
    near = d <= radius_m
    return float(foot_pts[near, 2].min()) if near.any() else float(foot_pts[np.argmin(d), 2])


def _sole_box(hull_v: np.ndarray, volume: float) -> GeomDef:
    """Box sole under the foot: the foot's 1-99 % extent in x and y, resting on its lowest
    point, as tall as gives the foot hull's volume."""
    lo = np.percentile(hull_v, 1.0, axis=0)
    hi = np.percentile(hull_v, 99.0, axis=0)
    zmin = float(hull_v[:, 2].min())
    lx, ly = float(hi[0] - lo[0]), float(hi[1] - lo[1])
    h = float(np.clip(volume / (lx * ly), 0.02, float(hull_v[:, 2].max()) - zmin))
    c = (0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), zmin + 0.5 * h)
    return GeomDef("box", _t(np.array(c)), (0.5 * lx, 0.5 * ly, 0.5 * h), 0.0)


def closed_mesh_volume_m3(rm: RestMesh) -> float:
    """Signed volume (m³) of the closed rest mesh (faces CCW from outside)."""
    v, f = rm.verts_m, rm.faces
    return float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0)


def qpos_from_bodyfit(skel: Skeleton, bodyfit: BodyFit, person_index: int, rows: np.ndarray) -> np.ndarray:
    """Physics coordinates (n, 7 + hinges) of one person at fit rows ``rows``: root position,
    root quat (w, x, y, z), then the hinge angles in skeleton order.

    Each body's rotation relative to its parent (from the BodyFit pose, its last bone's
    world rotation) is decomposed on its hinges: 3 hinges as intrinsic Euler angles about
    their axes, 2 as the first two of such angles, 1 as the twist about its axis. Angles are
    not clipped to the joint ranges.
    """
    rows = np.asarray(rows, dtype=np.int64).reshape(-1)
    bone = {n: i for i, n in enumerate(bodyfit.bone_names)}
    p = person_index
    G, x, _ = pose_fk(bodyfit.rig, bodyfit.shape[p], bodyfit.pose[rows, p], bodyfit.root_translation_m[rows, p])
    Rp = R_ANNY_TO_PHYS
    n = len(rows)
    Q = {b.name: G[:, bone[BODY_BONES[b.name][1][-1]]] @ Rp.T for b in skel.bodies}  # body world rotation
    out = np.zeros((n, 7 + skel.n_hinges))
    out[:, :3] = x[:, bone["root"]]
    q_root = Rotation.from_matrix(Q["pelvis"]).as_quat()  # x, y, z, w
    out[:, 3] = q_root[:, 3]
    out[:, 4:7] = q_root[:, :3]
    # Down the tree, relative to the parent's *reconstructed* orientation: a 3-hinge body
    # absorbs what its parent's fewer hinges could not represent.
    Qhat: dict[str, np.ndarray] = {}
    k = 7
    for b in skel.bodies:
        if not b.parent:
            Qhat[b.name] = Q[b.name]
            continue
        axes = [np.asarray(j.axis, dtype=float) for j in b.joints]
        rel = np.einsum("nji,njk->nik", Qhat[b.parent], Q[b.name])
        ang = _hinge_angles(rel, axes)
        out[:, k : k + len(axes)] = ang
        k += len(axes)
        R = Qhat[b.parent]
        for a, q in zip(axes, ang.T, strict=True):
            R = R @ Rotation.from_rotvec(q[:, None] * _unit(a)[None]).as_matrix()
        Qhat[b.name] = R
    return out


def _hinge_angles(rel: np.ndarray, axes: list[np.ndarray]) -> np.ndarray:
    """(n, len(axes)) angles approximating rotations ``rel`` (n, 3, 3) by R(a1) R(a2) R(a3)."""
    rot = Rotation.from_matrix(rel)
    if len(axes) == 1:
        q = rot.as_quat()  # twist about the axis
        a = _unit(axes[0])
        return (2.0 * np.arctan2(q[:, :3] @ a, q[:, 3]))[:, None]
    a1, a2 = _unit(axes[0]), _unit(axes[1])
    a3 = np.cross(a1, a2)
    B = np.column_stack([a1, a2, a3])  # proper rotation for orthogonal a1, a2
    local = Rotation.from_matrix(np.einsum("ji,njk,kl->nil", B, rel, B))
    ang = local.as_euler("XYZ")  # intrinsic about a1, a2, a3
    if len(axes) == 3:
        ang[:, 2] *= float(np.sign(_unit(axes[2]) @ a3))
        return ang
    return ang[:, :2]
