"""Rest-pose skeleton of a physics humanoid, sized from one person's 3D joints.

Pure numpy (no mujoco import): the MJCF writer (``humanoid``) and the
evaluation metrics (capsule proxies) both read it.

The rest pose is standing upright, arms hanging, facing +x with the person's left
on +y, world z-up, pelvis origin at the mid-hip point. Every body frame is aligned
with the world in the rest pose, so hinge axes are x (roll / ab-adduction),
y (pitch / flexion) and z (yaw / twist).

Segment lengths are medians over frames of the bone lengths measured in a
``Keypoints3D`` (``COCO17_FEET``); radii follow anthropometric ratios of those
lengths (Dempster-style proportions), so mass scales with the person's size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.schema.joints import COCO17_FEET
from pipeline.schema.keypoints3d import Keypoints3D


@dataclass(frozen=True)
class JointDef:
    """One hinge DOF: ``name`` (without person prefix), ``axis`` in the body frame,
    ``range_rad`` (lo, hi) and ``strength`` (relative PD gain / torque limit)."""

    name: str
    axis: tuple[float, float, float]
    range_rad: tuple[float, float]
    strength: float


@dataclass(frozen=True)
class GeomDef:
    """A collision primitive in its body's frame.

    ``kind`` is ``"capsule"`` (``a_m``, ``b_m`` segment ends, ``radius_m``),
    ``"sphere"`` (centre ``a_m``, ``radius_m``), ``"box"`` (centre ``a_m``,
    half sizes ``b_m``) or ``"mesh"`` (the convex hull of ``vertices_m``, in the
    body frame; ``a_m``, ``b_m`` and ``radius_m`` are unused, conventionally 0).
    """

    kind: str
    a_m: tuple[float, float, float]
    b_m: tuple[float, float, float]
    radius_m: float
    vertices_m: tuple[tuple[float, float, float], ...] | None = None
    """Points whose convex hull is the geom (``kind == "mesh"`` only)."""

    def volume_m3(self) -> float:
        if self.kind == "mesh":
            return hull_volume_m3(self.vertices_m)
        if self.kind == "capsule":
            length = float(np.linalg.norm(np.subtract(self.b_m, self.a_m)))
            return float(np.pi * self.radius_m**2 * length + 4.0 / 3.0 * np.pi * self.radius_m**3)
        if self.kind == "sphere":
            return float(4.0 / 3.0 * np.pi * self.radius_m**3)
        if self.kind == "box":
            return float(8.0 * np.prod(self.b_m))
        raise ValueError(f"unknown geom kind {self.kind!r}")


def hull_volume_m3(vertices_m: tuple[tuple[float, float, float], ...] | np.ndarray | None) -> float:
    """Volume (m³) of the convex hull of ``vertices_m`` (what MuJoCo uses for a mesh geom
    given by its vertices only). Raises ``ValueError`` for fewer than 4 or coplanar points."""
    from scipy.spatial import ConvexHull, QhullError

    pts = np.asarray(vertices_m if vertices_m is not None else (), dtype=float).reshape(-1, 3)
    if pts.shape[0] < 4:
        raise ValueError(f"mesh geom needs >= 4 vertices, got {pts.shape[0]}")
    try:
        return float(ConvexHull(pts).volume)
    except QhullError as e:
        raise ValueError(f"mesh geom vertices span no volume ({pts.shape[0]} points): {e}") from e


@dataclass(frozen=True)
class BodyDef:
    """A rigid body: ``parent`` ("" for the root), ``origin_m`` relative to the
    parent's origin in the rest pose (all frames world-aligned), its hinge joints
    (in order), geoms and keypoint sites (name -> position in the body frame)."""

    name: str
    parent: str
    origin_m: tuple[float, float, float]
    joints: tuple[JointDef, ...]
    geoms: tuple[GeomDef, ...]
    sites: tuple[tuple[str, tuple[float, float, float]], ...]


@dataclass(frozen=True)
class Skeleton:
    """All bodies of one humanoid in its rest pose (pelvis origin at 0)."""

    bodies: tuple[BodyDef, ...]
    lengths_m: dict[str, float]
    pelvis_height_m: float

    def body(self, name: str) -> BodyDef:
        for b in self.bodies:
            if b.name == name:
                return b
        raise ValueError(f"no body {name!r} in skeleton ({[b.name for b in self.bodies]})")

    def geom_volume_m3(self) -> float:
        return float(sum(g.volume_m3() for b in self.bodies for g in b.geoms))

    @property
    def n_hinges(self) -> int:
        return sum(len(b.joints) for b in self.bodies)


# Default lengths (m) of a 1.78 m adult, used when a bone is never observed.
_DEFAULT_LENGTHS: dict[str, float] = {
    "hip_width": 0.20,
    "shoulder_width": 0.36,
    "trunk": 0.50,
    "upper_arm": 0.29,
    "forearm": 0.26,
    "thigh": 0.42,
    "shin": 0.41,
    "heel_ankle": 0.08,
    "toe_ankle": 0.17,
    "foot": 0.22,
    "toe_width": 0.06,
    "small_toe_heel": 0.19,
    "ear_width": 0.15,
    "neck_head": 0.20,
    "nose_ear": 0.11,
    "eye_width": 0.065,
    "eye_ear": 0.09,
    "sole_offset": 0.0,
}


def _median_dist(kp: Keypoints3D, p: int, a: str | tuple[str, str], b: str | tuple[str, str]) -> float | None:
    """Median over frames of |A - B|, where an end may be a midpoint of two joints."""

    def pts(end: str | tuple[str, str]) -> tuple[np.ndarray, np.ndarray]:
        names = (end,) if isinstance(end, str) else end
        idx = [kp.joint_names.index(n) for n in names]
        xyz = kp.xyz_m[:, p, idx].mean(axis=1)
        ok = np.asarray(kp.valid[:, p, idx].all(axis=1))
        return xyz, ok

    xa, oa = pts(a)
    xb, ob = pts(b)
    ok = oa & ob
    if ok.sum() < 1:
        return None
    return float(np.median(np.linalg.norm(xa[ok] - xb[ok], axis=-1)))


def measure_lengths(kp: Keypoints3D, person_index: int) -> dict[str, float]:
    """Median segment lengths (m) of one person; missing ones fall back to defaults
    scaled by the observed leg length. Left and right sides are averaged."""
    missing = [n for n in COCO17_FEET[:17] if n not in kp.joint_names]
    if missing:
        raise ValueError(f"Keypoints3D lacks joints {missing} needed to size the humanoid")
    p = person_index
    has_feet = all(n in kp.joint_names for n in COCO17_FEET[17:])

    def sym(a: str, b: str) -> float | None:
        vals = [v for v in (_median_dist(kp, p, f"{s}_{a}", f"{s}_{b}") for s in ("left", "right")) if v is not None]
        return float(np.mean(vals)) if vals else None

    raw: dict[str, float | None] = {
        "hip_width": _median_dist(kp, p, "left_hip", "right_hip"),
        "shoulder_width": _median_dist(kp, p, "left_shoulder", "right_shoulder"),
        "trunk": _median_dist(kp, p, ("left_hip", "right_hip"), ("left_shoulder", "right_shoulder")),
        "upper_arm": sym("shoulder", "elbow"),
        "forearm": sym("elbow", "wrist"),
        "thigh": sym("hip", "knee"),
        "shin": sym("knee", "ankle"),
        "ear_width": _median_dist(kp, p, "left_ear", "right_ear"),
        "neck_head": _median_dist(kp, p, ("left_ear", "right_ear"), ("left_shoulder", "right_shoulder")),
        "nose_ear": _median_dist(kp, p, "nose", ("left_ear", "right_ear")),
        "eye_width": _median_dist(kp, p, "left_eye", "right_eye"),
        "eye_ear": sym("eye", "ear"),
    }
    if has_feet:
        raw.update(
            heel_ankle=sym("heel", "ankle"),
            toe_ankle=sym("big_toe", "ankle"),
            foot=sym("big_toe", "heel"),
            toe_width=sym("big_toe", "small_toe"),
            small_toe_heel=sym("small_toe", "heel"),
        )
    if has_feet:
        raw["sole_offset"] = sole_height_m(kp, p)
    leg = raw["thigh"] if raw["thigh"] else None
    scale = leg / _DEFAULT_LENGTHS["thigh"] if leg else 1.0
    out = {k: (v if v is not None and (v > 1e-3 or k == "sole_offset") else _DEFAULT_LENGTHS[k] * scale) for k, v in raw.items()}
    for k, v in _DEFAULT_LENGTHS.items():
        out.setdefault(k, v * scale)
    return out


def sole_height_m(kp: Keypoints3D, person_index: int) -> float | None:
    """Height of the foot keypoints above the sole (m): the median over frames of the
    lowest foot point of the person (the data are z-up with the floor at z = 0; one
    foot is almost always planted). None without foot keypoints."""
    if not all(n in kp.joint_names for n in COCO17_FEET[17:]):
        return None
    fi = [kp.joint_names.index(n) for n in COCO17_FEET[17:]]
    v = kp.valid[:, person_index][:, fi]
    ok = v.any(axis=-1)
    if not ok.any():
        return None
    zmin = np.where(v, kp.xyz_m[:, person_index][:, fi, 2], np.inf).min(axis=-1)
    return float(np.clip(np.median(zmin[ok]), 0.0, 0.04))


def _t(v: np.ndarray | list[float]) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=float)
    return (float(a[0]), float(a[1]), float(a[2]))


def build_skeleton(lengths: dict[str, float]) -> Skeleton:
    """Rest-pose skeleton (13 bodies, 26 hinges) from segment lengths in metres.

    Bodies: pelvis (root), torso, head, upper_arm/forearm (glove included), thigh,
    shin, foot per side. Hands are not articulated: the 2D joint set has no hand
    points, and a boxer's gloved fist moves with the forearm.
    """
    L = lengths
    hw, sw, trunk = L["hip_width"] / 2, L["shoulder_width"] / 2, L["trunk"]
    thigh, shin, ua, fa = L["thigh"], L["shin"], L["upper_arm"], L["forearm"]
    # Foot: heel behind and below the ankle, toes ahead (solved from the 3 distances).
    fl, dha, dta = L["foot"], L["heel_ankle"], L["toe_ankle"]
    back = float(np.clip((fl**2 - dta**2 + dha**2) / (2 * fl), 0.02, 0.5 * fl))
    ankle_h = float(np.sqrt(max(dha**2 - back**2, 0.04**2)))
    sole = L.get("sole_offset", 0.0)
    pelvis_h = thigh + shin + ankle_h + sole

    # Radii from anthropometric girths (thigh ~0.19 of its length, chest depth
    # ~0.23 m, head breadth ~0.16 m); at 985 kg/m³ the segment masses come close to
    # Dempster's fractions. Fatter proxies would make touching athletes overlap.
    r_thigh, r_shin = 0.19 * thigh, 0.13 * shin
    r_ua, r_fa = 0.17 * ua, 0.15 * fa
    r_glove = 0.24 * fa
    r_torso, r_pelvis = 0.32 * L["shoulder_width"], 1.0 * hw
    r_head = 0.55 * L["ear_width"]
    spine_z = 0.22 * trunk
    neck_z = trunk + 0.04 * trunk

    bodies: list[BodyDef] = []
    bodies.append(
        BodyDef(
            "pelvis", "", (0.0, 0.0, 0.0), (),
            (
                GeomDef("capsule", (0.0, -hw, 0.0), (0.0, hw, 0.0), r_pelvis),
            ),
            (("left_hip", (0.0, hw, 0.0)), ("right_hip", (0.0, -hw, 0.0))),
        )
    )
    torso_top = trunk - r_torso
    bodies.append(
        BodyDef(
            "torso", "pelvis", (0.0, 0.0, spine_z),
            (
                JointDef("spine_x", (1, 0, 0), (-0.6, 0.6), 1.0),
                JointDef("spine_y", (0, 1, 0), (-0.6, 1.2), 1.0),
                JointDef("spine_z", (0, 0, 1), (-0.9, 0.9), 0.8),
            ),
            (
                GeomDef("capsule", (0.0, 0.0, 0.05 * trunk), (0.0, 0.0, max(torso_top - spine_z, 0.1 * trunk)), r_torso),
                GeomDef(
                    "capsule",
                    (0.0, -(sw - r_ua), trunk - spine_z - 0.6 * r_torso),
                    (0.0, sw - r_ua, trunk - spine_z - 0.6 * r_torso),
                    0.6 * r_torso,
                ),
            ),
            (("left_shoulder", (0.0, sw, trunk - spine_z)), ("right_shoulder", (0.0, -sw, trunk - spine_z))),
        )
    )
    head_c = L["neck_head"]
    ew = L["ear_width"] / 2
    eye_y = L["eye_width"] / 2
    eye_x = float(np.sqrt(max(L["eye_ear"] ** 2 - (ew - eye_y) ** 2, 0.03**2)))
    bodies.append(
        BodyDef(
            "head", "torso", (0.0, 0.0, neck_z - spine_z),
            (
                JointDef("neck_x", (1, 0, 0), (-0.7, 0.7), 0.3),
                JointDef("neck_y", (0, 1, 0), (-0.8, 1.0), 0.3),
                JointDef("neck_z", (0, 0, 1), (-1.3, 1.3), 0.3),
            ),
            (GeomDef("sphere", (0.02, 0.0, head_c - (neck_z - trunk)), (0, 0, 0), r_head),),
            (
                ("nose", (L["nose_ear"], 0.0, head_c - (neck_z - trunk) - 0.02)),
                ("left_eye", (eye_x, eye_y, head_c - (neck_z - trunk) + 0.01)),
                ("right_eye", (eye_x, -eye_y, head_c - (neck_z - trunk) + 0.01)),
                ("left_ear", (0.0, ew, head_c - (neck_z - trunk))),
                ("right_ear", (0.0, -ew, head_c - (neck_z - trunk))),
            ),
        )
    )
    for side, s in (("left", 1.0), ("right", -1.0)):
        sh = np.array([0.0, s * sw, trunk])
        abd = (-0.6, 3.0) if s > 0 else (-3.0, 0.6)
        bodies.append(
            BodyDef(
                f"{side}_upper_arm", "torso", _t(sh - [0, 0, spine_z]),
                # Flexion first: the x-y-z order is singular with the arm straight ahead
                # (a jab); y-x-z is singular only at 90° abduction.
                (
                    JointDef(f"{side}_shoulder_y", (0, 1, 0), (-3.1, 1.2), 0.5),
                    JointDef(f"{side}_shoulder_x", (1, 0, 0), abd, 0.5),
                    JointDef(f"{side}_shoulder_z", (0, 0, 1), (-1.6, 1.6), 0.35),
                ),
                (GeomDef("capsule", (0.0, 0.0, -r_ua), (0.0, 0.0, -ua + r_fa), r_ua),),
                (),
            )
        )
        bodies.append(
            BodyDef(
                f"{side}_forearm", f"{side}_upper_arm", (0.0, 0.0, -ua),
                (JointDef(f"{side}_elbow", (0, 1, 0), (-2.7, 0.05), 0.35),),
                (
                    GeomDef("capsule", (0.0, 0.0, -r_fa), (0.0, 0.0, -fa + 0.5 * r_glove), r_fa),
                    GeomDef("sphere", (0.0, 0.0, -fa - 0.6 * r_glove), (0, 0, 0), r_glove),
                ),
                ((f"{side}_elbow", (0.0, 0.0, 0.0)), (f"{side}_wrist", (0.0, 0.0, -fa))),
            )
        )
        abd_h = (-0.5, 1.1) if s > 0 else (-1.1, 0.5)
        bodies.append(
            BodyDef(
                f"{side}_thigh", "pelvis", (0.0, s * hw, 0.0),
                (
                    JointDef(f"{side}_hip_x", (1, 0, 0), abd_h, 1.0),
                    JointDef(f"{side}_hip_y", (0, 1, 0), (-2.3, 0.6), 1.0),
                    JointDef(f"{side}_hip_z", (0, 0, 1), (-0.9, 0.9), 0.6),
                ),
                (GeomDef("capsule", (0.0, 0.0, -r_thigh * 0.8), (0.0, 0.0, -thigh + r_shin), r_thigh),),
                (),
            )
        )
        bodies.append(
            BodyDef(
                f"{side}_shin", f"{side}_thigh", (0.0, 0.0, -thigh),
                (JointDef(f"{side}_knee", (0, 1, 0), (-0.05, 2.7), 1.0),),
                (GeomDef("capsule", (0.0, 0.0, -r_shin * 0.5), (0.0, 0.0, -shin + r_shin), r_shin),),
                ((f"{side}_knee", (0.0, 0.0, 0.0)), (f"{side}_ankle", (0.0, 0.0, -shin))),
            )
        )
        # The sole is a box: four corner contacts give a stable stance.
        toe_y = s * 0.3 * L["toe_width"]
        small_len = min(L["small_toe_heel"], fl)
        half_h = 0.5 * min(ankle_h + sole, 0.06)
        box_c = (0.5 * fl - back, s * 0.25 * L["toe_width"], -ankle_h - sole + half_h)
        box_half = (0.5 * fl, 0.5 * max(1.4 * L["toe_width"], 0.08), half_h)
        bodies.append(
            BodyDef(
                f"{side}_foot", f"{side}_shin", (0.0, 0.0, -shin),
                (
                    JointDef(f"{side}_ankle_y", (0, 1, 0), (-0.9, 0.8), 0.6),
                    JointDef(f"{side}_ankle_x", (1, 0, 0), (-0.5, 0.5), 0.4),
                ),
                (GeomDef("box", box_c, box_half, 0.0),),
                (
                    (f"{side}_heel", (-back, 0.0, -ankle_h)),
                    (f"{side}_big_toe", (fl - back, -toe_y, -ankle_h)),
                    (f"{side}_small_toe", (small_len - back, s * 0.7 * L["toe_width"], -ankle_h)),
                ),
            )
        )
    return Skeleton(bodies=tuple(bodies), lengths_m=dict(L), pelvis_height_m=pelvis_h)


def skeleton_from_keypoints(kp: Keypoints3D, person_index: int) -> Skeleton:
    """Skeleton sized from one person's observed bone lengths."""
    return build_skeleton(measure_lengths(kp, person_index))


def rest_site_positions(skel: Skeleton) -> dict[str, np.ndarray]:
    """Keypoint site positions (m) in the rest pose, pelvis-centred world frame."""
    origin: dict[str, np.ndarray] = {}
    out: dict[str, np.ndarray] = {}
    for b in skel.bodies:
        base = origin[b.parent] if b.parent else np.zeros(3)
        origin[b.name] = base + np.asarray(b.origin_m)
        for name, pos in b.sites:
            out[name] = origin[b.name] + np.asarray(pos)
    return out
