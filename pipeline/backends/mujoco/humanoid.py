"""MJCF generator: one articulated humanoid per athlete, all in one MuJoCo scene.

Each person ``pid`` becomes a subtree ``p{pid}_pelvis`` with a free root joint
``p{pid}_root``, hinge joints ``p{pid}_<joint>`` (three per ball joint, anatomical
ranges), collision geoms (capsules/spheres/box soles, or convex-hull meshes given
inline as ``<asset><mesh vertex=...>``; density 985 kg/m³; with
``HumanoidConfig.mesh_foot_sole`` ``box`` a mesh foot also gets a massless flat sole box,
``p{pid}_<side>_foot_sole``, see ``sole_box``) and one site per tracked keypoint
``p{pid}_<keypoint>``.

Actuation (chosen by a stability test, see ``tests/backends/test_humanoid.py`` and
the module ``ilqr``): position servos (PD) on every hinge, with gains and
torque limits proportional to body mass. The optimised control is the servo target
angle; the applied torque is ``clip(kp (u - q) - kv q̇, ±limit)``. Pure torque
motors at the video rate (dt = 1/50 s) diverge; implicit PD damping + armature does
not (``tests/backends/test_humanoid.py::test_random_servo_targets_stay_stable``),
with two MuJoCo substeps per video frame (the defaults use four). Between video frames
the optimiser moves the targets along the reference (``schedule``).

Contacts: every geom touches the floor and the other athletes' geoms, except, by
default, arm against arm of two athletes (``HumanoidConfig.arm_contacts``; those overlaps
are removed from the reference instead, see ``HumanoidConfig.arm_contacts``), and foot
against foot (``HumanoidConfig.foot_contacts``). Within a
person, parent/child, sibling and grandparent bodies do not collide.

The root (``p{pid}_root_x/y/z`` slides + ``p{pid}_root`` ball) is kinematically a
free joint with the same qpos/qvel layout (xyz, quat_wxyz / world linear velocity,
local angular velocity). It is not actuated, except by the fallback *residual*:
three force-limited servos ``p{pid}_res_x/y/z`` (actuator group 3, disabled
in the MJCF via ``opt.disableactuator``) that apply the reference's residual root
force plus a PD pull towards the reference root position, with at most
``ResidualConfig.force_frac`` of body weight per axis. The optimiser enables them (in
every window by default, see ``ResidualConfig.mode``) and reports their force.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

import mujoco
import numpy as np

from pipeline.backends.mujoco.absent import PERSON_AFFINITY
from pipeline.backends.mujoco.config import DENSITY_KG_M3, HumanoidConfig, ResidualConfig
from pipeline.backends.mujoco.skeleton import Skeleton
from pipeline.evaluate.effort import HUMAN_PEAK_TORQUE_NM_PER_KG, group_of_joint, joint_of_actuator

GRAVITY = 9.81


@dataclass(frozen=True)
class PersonLayout:
    """Where one person lives in the model's arrays."""

    person_id: int
    qpos_adr: int
    qvel_adr: int
    nq: int
    nv: int
    hinge_qpos: np.ndarray
    hinge_dof: np.ndarray
    servo_ids: np.ndarray
    residual_ids: np.ndarray
    site_ids: dict[str, int]
    root_body: int
    body_ids: np.ndarray
    mass_kg: float


@dataclass(frozen=True)
class SceneLayout:
    """Index maps of a generated scene (built from the compiled model by name)."""

    persons: tuple[PersonLayout, ...]
    geom_person: np.ndarray = field(repr=False)
    """(ngeom,) person index of each geom, -1 for the floor."""
    geom_is_foot: np.ndarray = field(repr=False)
    """(ngeom,) True for sole geoms."""

    @property
    def servo_ids(self) -> np.ndarray:
        return np.concatenate([p.servo_ids for p in self.persons])

    @property
    def residual_ids(self) -> np.ndarray:
        return np.concatenate([p.residual_ids for p in self.persons])


def _f(v: tuple[float, ...] | list[float] | np.ndarray) -> str:
    return " ".join(f"{float(x):.5g}" for x in v)


def _excluded_pairs(skel: Skeleton) -> list[tuple[str, str]]:
    """Sibling and grandparent pairs (MuJoCo already filters parent/child)."""
    parent = {b.name: b.parent for b in skel.bodies}
    pairs: set[tuple[str, str]] = set()
    names = [b.name for b in skel.bodies]
    for a in names:
        for b in names:
            if a >= b:
                continue
            sib = parent[a] and parent[a] == parent[b]
            grand = (parent[a] and parent.get(parent[a]) == b) or (parent[b] and parent.get(parent[b]) == a)
            if sib or grand:
                pairs.add((a, b))
    return sorted(pairs)


SOLE_BAND_M = 0.008
"""Foot hull vertices this close above its lowest one outline the sole (``sole_box``)."""
SOLE_HALF_HEIGHT_M = 0.005
"""Half height (m) of the flat sole box under a mesh foot."""


def sole_box(vertices_m: np.ndarray, band_m: float = SOLE_BAND_M) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat box under a foot's hull (body frame, z up): centre (3,), half sizes (3,) and
    quat_wxyz (4,) of a yaw about z. Its outline is the x-y extent of the vertices within
    ``band_m`` of the lowest one, along their principal horizontal axis; its bottom is at the
    lowest vertex, ``SOLE_HALF_HEIGHT_M`` × 2 tall. Raises ``ValueError`` for fewer than 3
    vertices or a degenerate outline."""
    v = np.asarray(vertices_m, dtype=float).reshape(-1, 3)
    if v.shape[0] < 3:
        raise ValueError(f"sole_box: need >= 3 foot vertices, got {v.shape[0]}")
    zmin = float(v[:, 2].min())
    low = v[v[:, 2] <= zmin + band_m, :2]
    mid = low.mean(axis=0)
    _, _, vt = np.linalg.svd(low - mid, full_matrices=False)
    ax = vt[0] if vt.shape[0] else np.array([1.0, 0.0])
    if ax[0] < 0:  # the foot points along +x at rest: keep the yaw small
        ax = -ax
    yaw = float(np.arctan2(ax[1], ax[0]))
    R2 = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    t = (low - mid) @ R2  # coordinates along (length, width)
    lo, hi = t.min(axis=0), t.max(axis=0)
    half_xy = 0.5 * (hi - lo)
    if not np.all(half_xy > 1e-3):
        raise ValueError(f"sole_box: the sole outline is degenerate (half sizes {half_xy.tolist()} m)")
    c_xy = mid + R2 @ (0.5 * (lo + hi))
    centre = np.array([c_xy[0], c_xy[1], zmin + SOLE_HALF_HEIGHT_M])
    half = np.array([half_xy[0], half_xy[1], SOLE_HALF_HEIGHT_M])
    quat = np.array([np.cos(0.5 * yaw), 0.0, 0.0, np.sin(0.5 * yaw)])
    return centre, half, quat


def person_mass_kg(skel: Skeleton, density_kg_m3: float = DENSITY_KG_M3) -> float:
    """Mass from geom volumes (overlaps between a body's geoms counted twice, as MuJoCo does)."""
    return skel.geom_volume_m3() * density_kg_m3


def _person_xml(
    pid: int,
    skel: Skeleton,
    cfg: HumanoidConfig,
    offset: np.ndarray,
    mass: float,
    assets: list[str] | None = None,
    residual: ResidualConfig | None = None,
) -> tuple[str, list[str]]:
    """Body tree XML and actuator lines of one person; mesh assets are appended to ``assets``."""
    pre = f"p{pid}_"
    if cfg.self_collision == "none":
        # Bit 0 is the floor; person k owns bit k+1 and collides with everyone else's
        # (bit 30 is an absent person's: ``absent.ABSENT_BIT``, which only the floor collides with).
        own = 1 << (pid % 29 + 1)
        ct, ca = own, PERSON_AFFINITY & ~own
    else:
        ct, ca = 1, PERSON_AFFINITY
    children: dict[str, list[str]] = {}
    for b in skel.bodies:
        children.setdefault(b.parent, []).append(b.name)
    by_name = {b.name: b for b in skel.bodies}
    actuators: list[str] = []

    def emit(name: str, depth: int) -> list[str]:
        b = by_name[name]
        ind = "  " * depth
        pos = np.asarray(b.origin_m) + (offset if not b.parent else 0.0)
        lines = [f"{ind}<body name={quoteattr(pre + b.name)} pos={quoteattr(_f(pos))}>"]
        if not b.parent:
            for k, ax in enumerate("xyz"):
                axis = np.eye(3)[k]
                lines.append(
                    f'{ind}  <joint name="{pre}root_{ax}" type="slide" axis="{_f(axis)}" ref="{pos[k]:.5g}" '
                    'limited="false" damping="0" armature="0"/>'
                )
            lines.append(f'{ind}  <joint name="{pre}root" type="ball" limited="false" damping="0" armature="0"/>')
        for j in b.joints:
            arm = cfg.armature * j.strength * mass / 75.0
            lines.append(
                f'{ind}  <joint name="{pre}{j.name}" type="hinge" axis="{_f(j.axis)}" '
                f'range="{_f(j.range_rad)}" armature="{arm:.4g}"/>'
            )
            kp = cfg.kp_per_kg * mass * j.strength
            lim = cfg.torque_per_kg * mass * j.strength
            if cfg.torque_limits == "human":
                joint = joint_of_actuator(j.name)
                hinges = sum(joint_of_actuator(k.name) == joint for k in b.joints)
                lim = min(lim, 0.999 * HUMAN_PEAK_TORQUE_NM_PER_KG[group_of_joint(joint)] * mass / np.sqrt(hinges))
            # Targets may lie beyond the joint range so that the servo can be driven
            # hard (fast punches); the torque limit bounds the effort.
            lo, hi = j.range_rad[0] - cfg.target_slack_rad, j.range_rad[1] + cfg.target_slack_rad
            actuators.append(
                f'    <position name="{pre}{j.name}" joint="{pre}{j.name}" kp="{kp:.5g}" '
                f'kv="{cfg.kv_ratio * kp:.5g}" ctrlrange="{lo:.5g} {hi:.5g}" '
                f'forcelimited="true" forcerange="{-lim:.5g} {lim:.5g}"/>'
            )
        for k, g in enumerate(b.geoms):
            gname = f"{pre}{b.name}_g{k}"
            common = f'name="{gname}" contype="{ct}" conaffinity="{ca}"'
            if g.kind == "capsule":
                lines.append(f'{ind}  <geom {common} type="capsule" fromto="{_f(g.a_m + g.b_m)}" size="{g.radius_m:.5g}"/>')
            elif g.kind == "sphere":
                lines.append(f'{ind}  <geom {common} type="sphere" pos="{_f(g.a_m)}" size="{g.radius_m:.5g}"/>')
            elif g.kind == "box":
                lines.append(f'{ind}  <geom {common} type="box" pos="{_f(g.a_m)}" size="{_f(g.b_m)}" class="sole"/>')
            elif g.kind == "mesh":
                if assets is None or g.vertices_m is None:
                    raise ValueError(f"mesh geom {gname} needs vertices and an asset list")
                # Vertices only: MuJoCo builds their convex hull; inertia="convex" takes
                # mass and inertia from that hull's volume at the default density.
                verts = " ".join(_f(v) for v in g.vertices_m)
                assets.append(f'    <mesh name="{gname}" vertex="{verts}" inertia="convex"/>')
                is_sole = k == 0 and b.name.endswith("_foot")
                sole = ' class="sole"' if is_sole else ""
                lines.append(f'{ind}  <geom {common} type="mesh" mesh="{gname}"{sole}/>')
                if is_sole and cfg.mesh_foot_sole == "box":
                    sole_c, half, quat = sole_box(np.asarray(g.vertices_m, dtype=float))
                    lines.append(
                        f'{ind}  <geom name="{pre}{b.name}_sole" contype="{ct}" conaffinity="{ca}" type="box" '
                        f'pos="{_f(sole_c)}" size="{_f(half)}" quat="{_f(quat)}" mass="0" class="sole"/>'
                    )
            else:
                raise ValueError(f"unsupported geom kind {g.kind!r} in body {b.name}")
        for sname, spos in b.sites:
            lines.append(f'{ind}  <site name="{pre}{sname}" pos="{_f(spos)}" size="0.012"/>')
        for c in children.get(name, []):
            lines += emit(c, depth + 1)
        lines.append(f"{ind}</body>")
        return lines

    root = children[""][0]
    body_lines = emit(root, 2)
    if residual is not None:
        lim = residual.force_frac * mass * GRAVITY
        kp = lim / residual.saturation_m
        kv = 2.0 * np.sqrt(kp * mass)
        for ax in "xyz":
            actuators.append(
                f'    <position name="{pre}res_{ax}" joint="{pre}root_{ax}" kp="{kp:.5g}" kv="{kv:.5g}" group="3" '
                f'ctrlrange="-1000 1000" forcelimited="true" forcerange="{-lim:.5g} {lim:.5g}"/>'
            )
    return "\n".join(body_lines), actuators


def build_scene_mjcf(
    skeletons: list[Skeleton],
    person_ids: list[int],
    fps: float,
    cfg: HumanoidConfig = HumanoidConfig(),
    residual: ResidualConfig | None = ResidualConfig(),
) -> str:
    """MJCF text of all persons on a ground plane (z = 0), timestep 1/(fps·substeps), with the
    residual root actuators of ``residual`` (disabled until the optimiser enables them; none
    when ``residual`` is None).

    Raises ``ValueError`` for mismatched inputs or a non-positive fps.
    """
    if len(skeletons) != len(person_ids) or not skeletons:
        raise ValueError(f"need one skeleton per person id, got {len(skeletons)} for {person_ids}")
    if not (fps > 0):
        raise ValueError(f"fps must be positive, got {fps}")
    if cfg.substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {cfg.substeps}")
    bodies: list[str] = []
    acts: list[str] = []
    excludes: list[str] = []
    assets: list[str] = []
    for i, (pid, skel) in enumerate(zip(person_ids, skeletons, strict=True)):
        mass = person_mass_kg(skel, cfg.density_kg_m3)
        offset = np.array([0.0, cfg.person_spacing_m * i, skel.pelvis_height_m])
        xml, a = _person_xml(pid, skel, cfg, offset, mass, assets, residual)
        bodies.append(xml)
        acts += a
        if cfg.self_collision == "adjacent_filtered":
            excludes += [f'    <exclude body1="p{pid}_{a_}" body2="p{pid}_{b_}"/>' for a_, b_ in _excluded_pairs(skel)]
    fr = cfg.floor_friction
    if cfg.arm_contacts != "simulate":
        excludes += _inter_person_excludes(skeletons, person_ids, ARM_BODIES)
    if cfg.foot_contacts != "simulate":
        excludes += _inter_person_excludes(skeletons, person_ids, FOOT_BODIES)
    asset_xml = f"  <asset>\n{chr(10).join(assets)}\n  </asset>\n" if assets else ""
    return f"""<mujoco model="cornerman_scene">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{1.0 / (fps * cfg.substeps):.6g}" integrator="implicitfast" iterations="{cfg.solver_iterations}" ls_iterations="10"
          actuatorgroupdisable="3"/>
  <default>
    <joint damping="{cfg.joint_damping:.5g}" limited="true"/>
    <geom density="{cfg.density_kg_m3:.6g}" friction="{cfg.body_friction:.3g} 0.01 0.001" condim="3" rgba="0.7 0.6 0.5 1"
          solref="{cfg.body_solref_s:.4g} 1"/>
    <default class="sole">
      <geom rgba="0.3 0.3 0.3 1" solref="0.02 1" friction="{fr:.3g} 0.01 0.001"/>
    </default>
    <site rgba="1 0 0 1" group="3"/>
  </default>
  <visual>
    <headlight ambient="0.4 0.4 0.4"/>
  </visual>
{asset_xml}  <worldbody>
    <light pos="0 0 6" dir="0 0 -1"/>
    <geom name="floor" type="plane" size="20 20 0.1" priority="1" contype="1" conaffinity="2147483647" friction="{fr:.3g} 0.01 0.001"
          margin="{cfg.floor_margin_m:.4g}" solimp="{' '.join(f'{v:.6g}' for v in cfg.floor_solimp)}"
          solref="{' '.join(f'{v:.6g}' for v in cfg.floor_solref)}" rgba="0.85 0.85 0.8 1"/>
{chr(10).join(bodies)}
  </worldbody>
  <contact>
{chr(10).join(excludes)}
  </contact>
  <actuator>
{chr(10).join(acts)}
  </actuator>
</mujoco>
"""


ARM_BODIES = tuple(f"{side}_{b}" for side in ("left", "right") for b in ("upper_arm", "forearm", "hand"))
"""Bodies whose contacts with the other athlete's arms ``arm_contacts = "reference"`` drops."""


FOOT_BODIES = ("left_foot", "right_foot")
"""Bodies whose contacts with the other athlete's feet ``foot_contacts = "reference"`` drops."""


def _inter_person_excludes(skeletons: list[Skeleton], person_ids: list[int], names: tuple[str, ...]) -> list[str]:
    """``<exclude>`` lines for every pair of ``names`` bodies of two different persons."""
    out = []
    for i, (pa, ska) in enumerate(zip(person_ids, skeletons, strict=True)):
        in_a = [b.name for b in ska.bodies if b.name in names]
        for pb, skb in zip(person_ids[i + 1 :], skeletons[i + 1 :], strict=True):
            in_b = [b.name for b in skb.bodies if b.name in names]
            out += [f'    <exclude body1="p{pa}_{a}" body2="p{pb}_{b}"/>' for a in in_a for b in in_b]
    return out


def load_model(mjcf: str) -> mujoco.MjModel:
    """Compile MJCF text; MuJoCo's compile error is raised as ``ValueError``."""
    try:
        return mujoco.MjModel.from_xml_string(mjcf)
    except ValueError as e:
        raise ValueError(f"MJCF does not compile: {e}") from e


def scene_layout(model: mujoco.MjModel, person_ids: list[int]) -> SceneLayout:
    """Index maps of the persons in a model built by :func:`build_scene_mjcf`."""
    persons = []
    geom_person = np.full(model.ngeom, -1, dtype=np.int64)
    for i, pid in enumerate(person_ids):
        pre = f"p{pid}_"
        root_j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, pre + "root_x")
        if root_j < 0:
            raise ValueError(f"model has no person {pid} (joint {pre}root missing)")
        joints = [j for j in range(model.njnt) if model.joint(j).name.startswith(pre)]
        hinges = [j for j in joints if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
        acts = [a for a in range(model.nu) if model.actuator(a).name.startswith(pre)]
        servo = [a for a in acts if "_res_" not in model.actuator(a).name]
        resid = [a for a in acts if "_res_" in model.actuator(a).name]
        sites = {model.site(s).name[len(pre):]: s for s in range(model.nsite) if model.site(s).name.startswith(pre)}
        bodies = np.array(
            [b for b in range(model.nbody) if model.body(b).name.startswith(pre)], dtype=np.int64
        )
        root_body = int(model.jnt_bodyid[root_j])
        qadr = int(model.jnt_qposadr[root_j])
        vadr = int(model.jnt_dofadr[root_j])
        nq = 7 + len(hinges)
        nv = 6 + len(hinges)
        for g in range(model.ngeom):
            if model.geom_bodyid[g] in set(bodies.tolist()):
                geom_person[g] = i
        persons.append(
            PersonLayout(
                person_id=int(pid),
                qpos_adr=qadr,
                qvel_adr=vadr,
                nq=nq,
                nv=nv,
                hinge_qpos=np.array([model.jnt_qposadr[j] for j in hinges], dtype=np.int64),
                hinge_dof=np.array([model.jnt_dofadr[j] for j in hinges], dtype=np.int64),
                servo_ids=np.array(servo, dtype=np.int64),
                residual_ids=np.array(resid, dtype=np.int64),
                site_ids=sites,
                root_body=root_body,
                body_ids=bodies,
                mass_kg=float(model.body_subtreemass[root_body]),
            )
        )
    is_foot = np.array([model.geom(g).name.endswith(("_foot_g0", "_foot_sole")) for g in range(model.ngeom)])
    return SceneLayout(persons=tuple(persons), geom_person=geom_person, geom_is_foot=is_foot)
