"""The kinematic reference the physics stage tracks.

Per-frame inverse kinematics of the 3D joints onto the humanoids' sites, made
contact-consistent (planted feet held still and flat on the floor, overlapping athletes
separated: ``separation``), and the servo targets with inverse-dynamics
feed-forward (per substep: ``schedule``; ground reactions on the feet, what they
cannot supply is the residual root wrench). The scene itself is ``scene``
(``Scene`` and ``build_scene`` are re-exported here). An earlier inverse kinematics is
reused where its inputs are unchanged (``ik_reuse``, ``reference_and_ik``).
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from pipeline.backends.mujoco.absent import out_of_view
from pipeline.backends.mujoco.config import ReferenceConfig
from pipeline.backends.mujoco.humanoid import SceneLayout
from pipeline.backends.mujoco.ik_reuse import (
    ReferenceIK,
    ik_input_digests,
    ik_model_digest,
    reusable_ik_frames,
)
from pipeline.backends.mujoco.scene import Scene, build_scene
from pipeline.backends.mujoco.schedule import contact_inverse_dynamics_point, foot_site_ids, servo_schedule
from pipeline.backends.mujoco.separation import separate_persons, separate_reference
from pipeline.backends.mujoco.skeleton import sole_height_m
from pipeline.backends.mujoco.tracking import FOOT_SITES, Reference

__all__ = [
    "Scene",
    "build_reference",
    "build_scene",
    "contact_inverse_dynamics",
    "inverse_kinematics",
    "lift_off_floor",
    "plant_feet",
    "planted_site_targets",
    "reference_and_ik",
    "reference_velocity",
    "separate_persons",
    "separate_reference",
    "servo_feedforward",
    "site_targets",
]
from pipeline.schema.keypoints3d import Keypoints3D


def _initial_root(targets: np.ndarray, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Root position and quat_wxyz from hips and shoulders (rest pose faces +x, left +y)."""
    ix = {n: i for i, n in enumerate(names)}
    lh, rh = targets[ix["left_hip"]], targets[ix["right_hip"]]
    ls, rs = targets[ix["left_shoulder"]], targets[ix["right_shoulder"]]
    y = lh - rh
    y /= max(np.linalg.norm(y), 1e-6)
    z = 0.5 * (ls + rs) - 0.5 * (lh + rh)
    z -= y * (z @ y)
    z = z / np.linalg.norm(z) if np.linalg.norm(z) > 1e-6 else np.array([0.0, 0.0, 1.0])
    x = np.cross(y, z)
    R = np.column_stack([x, y, z])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, R.ravel())
    return 0.5 * (lh + rh), quat


def inverse_kinematics(
    scene: Scene,
    targets: np.ndarray,
    weight: np.ndarray,
    iters_first: int = 60,
    iters: int = 10,
    damping: float = 1e-3,
    flat: np.ndarray | None = None,
    sole_lift_m: float = 0.0,
    flat_weight: float = 100.0,
    restart_tol_m: float = 0.05,
    posture_weight: float = 0.0,
    limit_active_set: bool = True,
    prefix: np.ndarray | None = None,
) -> np.ndarray:
    """Per-frame damped least squares of sites onto targets, warm-started in time.

    targets: (frames, persons, sites, 3) world; weight: (frames, persons, sites).
    ``flat`` (frames, persons, 2): feet (left, right) that must stand flat on the floor
    in that frame: the foot body's z axis vertical (its sole, flat at rest, parallel to
    the floor) and its sole ``sole_lift_m`` above z = 0, with weight ``flat_weight``
    (sites: their confidence). A planted foot's keypoints alone leave it tilted by
    ~5° (up to 10°) and ~7 mm up, which the simulated foot, flat on the floor, fights
    by rocking on its sole. A person whose worst site misses its target by more than
    ``restart_tol_m`` after a frame's iterations is solved again from its rest joint
    angles, and the better of the two kept. ``posture_weight`` > 0 adds
    ``posture_weight · Σ (hinge − rest)²`` (rad²; the sites' residuals are in m): the
    keypoints leave some joints free (trunk twist against the shoulder girdle, hip
    twist against the knee's), and each frame, warm-started from the last, let them
    drift to their limits. ``limit_active_set``: a hinge at a limit that a step pushes
    further out is held for that step and the step solved again without it; False clamps
    the step after the solve, and the joints that moved with it stay moved (a straight knee
    then leaves a flat-planted foot tilted toes down). Returns qpos (frames, nq), hinge
    angles clamped to their ranges.

    Frame f depends on the inputs of frames 0..f only (the warm start; the first pose's
    root comes from a person's first frame with targets). ``prefix`` (k, nq), 1 <= k <=
    frames: this function's result for frames 0..k-1 from inputs equal to these there
    (``reusable_ik_frames``): those rows are copied and the solve goes on from frame k,
    bit for bit as if it had run from frame 0.
    """
    m, lay = scene.model, scene.layout
    d = mujoco.MjData(m)
    F, P, S = weight.shape
    bad = ~np.isfinite(weight) | ((weight > 0) & ~np.isfinite(targets).all(axis=-1))
    if bad.any():
        f, i, s = (int(v) for v in np.argwhere(bad)[0])
        raise ValueError(
            f"inverse_kinematics: {int(bad.sum())} non-finite site weights or weighted targets, the first at frame {f}, "
            f"person {i}, site {scene.site_names[s]} (weight {weight[f, i, s]}, target {targets[f, i, s]})"
        )
    k0 = 0 if prefix is None else int(prefix.shape[0])
    if prefix is not None and (prefix.ndim != 2 or not 1 <= k0 <= F or prefix.shape[1] != m.nq):
        raise ValueError(f"inverse_kinematics: prefix has shape {prefix.shape}, expected (1..{F}, {m.nq})")
    feet = _foot_rest_heights(scene) if flat is not None else []
    jacr = np.zeros((3, m.nv))
    q = m.qpos0.copy()
    for i, p in enumerate(lay.persons):
        ok = weight[:, i].sum(axis=-1) > 0
        f0 = int(np.argmax(ok))
        pos, quat = _initial_root(targets[f0, i], scene.site_names)
        q[p.qpos_adr : p.qpos_adr + 3] = pos
        q[p.qpos_adr + 3 : p.qpos_adr + 7] = quat
    hinge_j = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    hq = np.array([m.jnt_qposadr[j] for j in hinge_j], dtype=np.int64)
    hv = np.array([m.jnt_dofadr[j] for j in hinge_j], dtype=np.int64)
    lo, hi = m.jnt_range[hinge_j, 0], m.jnt_range[hinge_j, 1]
    out = np.zeros((F, m.nq))
    jac = np.zeros((3, m.nv))
    dq = np.zeros(m.nv)

    # A person's sites and feet move only that person's degrees of freedom, so the normal
    # equations are block diagonal: each person's block is accumulated on its own (the
    # full matrix's other blocks only ever received exact zeros there).
    blocks = [slice(p.qvel_adr, p.qvel_adr + p.nv) for p in lay.persons]
    person_dofs = sum(p.nv for p in lay.persons)
    if person_dofs != m.nv:
        raise ValueError(f"inverse_kinematics: the scene has {m.nv} dofs, its persons {person_dofs}; each dof must be one person's")
    site_ids = np.asarray(scene.site_ids, dtype=np.int64)
    jacs = np.zeros((S, 3, m.nv))

    def iterate(q: np.ndarray, f: int, n_iters: int, cold: bool) -> None:
        for it in range(n_iters):
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            JtJ = np.zeros((m.nv, m.nv))
            Jtr = np.zeros(m.nv)
            for i in range(P):
                b = blocks[i]
                JtJ_b, Jtr_b, jac_b, jacr_b = JtJ[b, b], Jtr[b], jac[:, b], jacr[:, b]
                sel = np.flatnonzero(weight[f, i] > 0)
                if sel.size:
                    sids = site_ids[i, sel]
                    for n, sid in enumerate(sids):
                        mujoco.mj_jacSite(m, d, jacs[n], None, int(sid))
                    # w J^T J and w J^T r of every site, summed in site order.
                    wjt = weight[f, i, sel][:, None, None] * jacs[: sel.size, :, b].transpose(0, 2, 1)
                    r = d.site_xpos[sids] - targets[f, i, sel]
                    JtJ_b += np.matmul(wjt, jacs[: sel.size, :, b]).sum(axis=0)
                    Jtr_b += np.matmul(wjt, r[:, :, None])[:, :, 0].sum(axis=0)
                for k_side in (0, 1):
                    if flat is None or not flat[f, i, k_side]:
                        continue
                    body, h0 = feet[i][k_side]
                    mujoco.mj_jacBody(m, d, jac, jacr, body)
                    z_axis = d.xmat[body].reshape(3, 3)[:, 2]
                    # d(z_axis) = omega x z_axis = -[z_axis]x J_r dq; keep its x, y rows.
                    Jt = (-_skew(z_axis) @ jacr_b)[:2] * FLAT_LEVER_M
                    rt = z_axis[:2] * FLAT_LEVER_M
                    rh = d.xpos[body, 2] - (h0 + sole_lift_m)
                    JtJ_b += flat_weight * (Jt.T @ Jt + np.outer(jac_b[2], jac_b[2]))
                    Jtr_b += flat_weight * (Jt.T @ rt + jac_b[2] * rh)
            if posture_weight > 0:
                # A weak pull of every hinge towards its rest angle (rad² against the
                # sites' m²): keeps the joints the keypoints do not pin down from drifting.
                JtJ[hv, hv] += posture_weight
                Jtr[hv] += posture_weight * (q[hq] - m.qpos0[hq])
            lam = damping * (10.0 if (cold and it < 10) else 1.0)
            A = JtJ + lam * np.eye(m.nv) + 1e-6 * np.diag(np.diag(JtJ))
            dq[:] = -np.linalg.solve(A, Jtr)
            if limit_active_set:
                # Hinges at a limit that the step pushes further out are held there and the
                # step is solved again without them, so the other joints do not move as if
                # they had given way.
                free = np.ones(m.nv, dtype=bool)
                for _ in range(4):
                    out_lo = (q[hq] <= lo + 1e-9) & (dq[hv] < 0)
                    out_hi = (q[hq] >= hi - 1e-9) & (dq[hv] > 0)
                    held = hv[(out_lo | out_hi) & free[hv]]
                    if held.size == 0:
                        break
                    free[held] = False
                    dq[:] = 0.0
                    dq[free] = -np.linalg.solve(A[np.ix_(free, free)], Jtr[free])
            mujoco.mj_integratePos(m, q, dq, 1.0)
            q[hq] = np.clip(q[hq], lo, hi)

    def site_errors(q: np.ndarray, f: int) -> np.ndarray:
        """(persons,) worst weighted site error (m) of each person at ``q``."""
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        err = np.linalg.norm(d.site_xpos[scene.site_ids] - targets[f], axis=-1)
        return np.where(weight[f] > 0, err, 0.0).max(axis=1)

    if prefix is not None:
        out[:k0] = prefix
        q = out[k0 - 1].copy()
    for f in range(k0, F):
        iterate(q, f, iters_first if f == 0 else iters, cold=f == 0)
        bad = [i for i, e in enumerate(site_errors(q, f)) if e > restart_tol_m]
        if bad and f > 0:
            # A warm start can keep a limb in the wrong valley (an elbow bent the wrong
            # way through a fast punch) for many frames: retry those persons from their
            # rest joint angles and keep whichever fits better.
            q2 = q.copy()
            for i in bad:
                hp = lay.persons[i].hinge_qpos
                q2[hp] = m.qpos0[hp]
            iterate(q2, f, iters_first, cold=True)
            e1, e2 = site_errors(q, f), site_errors(q2, f)
            for i in bad:
                if e2[i] < e1[i]:
                    p = lay.persons[i]
                    q[p.qpos_adr : p.qpos_adr + p.nq] = q2[p.qpos_adr : p.qpos_adr + p.nq]
        out[f] = q
    return out


FLAT_LEVER_M = 0.1
"""Length that turns a foot's tilt (rad) into the metres of the IK's residuals."""


def _skew(a: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _foot_rest_heights(scene: Scene) -> list[list[tuple[int, float]]]:
    """Per person and side (left, right): the foot body id and the height of its origin
    above its sole (the lowest point of its geoms when the foot is level)."""
    m = scene.model
    d = mujoco.MjData(m)
    d.qpos[:] = m.qpos0
    mujoco.mj_fwdPosition(m, d)
    floor = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    out = []
    for p in scene.layout.persons:
        sides = []
        for side in ("left", "right"):
            body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"p{p.person_id}_{side}_foot")
            if body < 0:
                raise ValueError(f"inverse_kinematics: person {p.person_id} has no {side}_foot body")
            geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == body]
            gap = min(mujoco.mj_geomDistance(m, d, g, floor, 1.0, None) for g in geoms)
            if not np.all(np.abs(d.xmat[body].reshape(3, 3) - np.eye(3)) < 1e-6):
                raise ValueError(f"inverse_kinematics: the {side}_foot of person {p.person_id} is not level at rest")
            sides.append((body, float(d.xpos[body, 2] - gap)))
        out.append(sides)
    return out


def reference_velocity(model: mujoco.MjModel, qpos: np.ndarray, fps: float) -> np.ndarray:
    """Central-difference generalised velocities (frames, nv)."""
    F = qpos.shape[0]
    v = np.zeros((F, model.nv))
    for f in range(F):
        a, b = max(f - 1, 0), min(f + 1, F - 1)
        if a == b:
            continue
        mujoco.mj_differentiatePos(model, v[f], (b - a) / fps, qpos[a], qpos[b])
    return v


def site_targets(scene: Scene, kp: Keypoints3D, person_rows: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """The scene's site targets from ``kp``: world positions (frames, persons, sites, 3),
    zero where invalid, and weights (frames, persons, sites) = validity × confidence."""
    jidx = [kp.joint_names.index(n) for n in scene.site_names]
    # An invalid joint weighs 0 whatever its confidence (a NaN there must not reach the solve);
    # a valid joint's confidence is in [0, 1] (``Keypoints3D`` checks it).
    weight = np.where(kp.valid[:, person_rows][:, :, jidx], kp.confidence[:, person_rows][:, :, jidx], 0.0).astype(float)
    targets = np.where(weight[..., None] > 0, kp.xyz_m[:, person_rows][:, :, jidx].astype(float), 0.0)
    return targets, weight


def sole_heights_m(kp: Keypoints3D, person_rows: list[int]) -> np.ndarray:
    """(persons,) height of each person's foot keypoints above the sole (``sole_height_m``;
    0 without foot keypoints)."""
    return np.array([sole_height_m(kp, r) or 0.0 for r in person_rows])


def planted_site_targets(
    scene: Scene, kp: Keypoints3D, person_rows: list[int], sole_m: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``site_targets`` with planted feet held still at the sole height (``plant_feet``;
    ``sole_m`` (persons,), default ``sole_heights_m``): (targets, weight, foot contact
    (frames, persons, 2))."""
    targets, weight = site_targets(scene, kp, person_rows)
    sole = sole_heights_m(kp, person_rows) if sole_m is None else np.asarray(sole_m, dtype=float)
    targets, contact = plant_feet(targets, weight, scene.site_names, kp.fps, sole)
    return targets, weight, contact


def build_reference(
    scene: Scene, kp: Keypoints3D, person_rows: list[int], **options: Any
) -> tuple[Reference, np.ndarray, np.ndarray]:
    """``reference_and_ik`` (same keyword options) with no stored IK and its IK left out:
    (reference, targets_world, weight)."""
    if "stored_ik" in options:
        raise TypeError("build_reference: stored_ik is reference_and_ik's; call that to reuse an IK")
    ref, targets, weight, _ = reference_and_ik(scene, kp, person_rows, **options)
    return ref, targets, weight


def reference_and_ik(
    scene: Scene,
    kp: Keypoints3D,
    person_rows: list[int],
    plant: bool = True,
    separate: bool = True,
    substeps: int = 0,
    flat_feet: bool = False,
    sole_lift_m: float = 0.0,
    ff_friction: float = 0.3,
    ff_smooth_frames: float = 0.0,
    separation_clearance_m: float = 0.003,
    posture_weight: float = 0.0,
    sole_m: np.ndarray | None = None,
    balance: ReferenceConfig | None = None,
    stored_ik: ReferenceIK | None = None,
) -> tuple[Reference, np.ndarray, np.ndarray, ReferenceIK]:
    """IK reference + body-frame targets. Returns (reference, targets_world, weight, ik).
    ``sole_m``: (persons,) height of the foot keypoints above the sole (default: measured
    on ``kp``, ``sole_heights_m``).

    With ``substeps`` > 0 the reference carries a per-substep servo schedule
    (``schedule.servo_schedule``: the reference interpolated between frames, with
    inverse-dynamics feed-forward whose ground reactions are on the planted feet);
    with 0, per-frame servo targets with feed-forward from smoothed accelerations
    (``servo_feedforward``, the scheme before the schedule).

    With ``plant``, planted feet are held still and lifted to the sole height
    (``tracking.plant_feet``) before the IK. With ``separate``, each frame of
    the IK reference is freed of inter-person overlap (``separate_persons``: minimal
    change of all DOFs) and the tracked targets become the reference's own sites:
    the optimiser then tracks a contact-free, reachable motion instead of fighting
    keypoints that pass through the other athlete (the synthetic clinches do).

    ``balance``: a config whose ``balance`` is ``zmp`` moves each athlete's body above the
    planted feet after the IK (and before the separation) so that the zero-moment point
    stays over them (``balance.balance_reference``; needs ``plant``); None or ``none``: not.

    ``stored_ik``: the ``ik`` of an earlier call (same scene and settings, e.g. the previous
    run of the stage): its frames before the first whose IK inputs differ are copied
    (``ik_reuse``), bit for bit what solving them again gives; ``ik.reused_frames`` says how
    many, ``ik.why`` why none."""
    m, lay = scene.model, scene.layout
    contact: np.ndarray | None = None
    if plant:
        targets, weight, contact = planted_site_targets(scene, kp, person_rows, sole_m)
    else:
        targets, weight = site_targets(scene, kp, person_rows)
    flat = contact if flat_feet else None
    ik_inputs = ik_input_digests(targets, weight, flat)
    ik_model = ik_model_digest(scene, flat is not None, sole_lift_m, posture_weight)
    k, why = reusable_ik_frames(stored_ik, ik_inputs, ik_model, weight)
    qref = inverse_kinematics(
        scene, targets, weight, flat=flat, sole_lift_m=sole_lift_m, posture_weight=posture_weight,
        prefix=stored_ik.qpos[:k] if stored_ik is not None and k > 0 else None,
    )
    ik = ReferenceIK(qpos=qref.copy(), input_digest=ik_inputs, model_digest=ik_model, reused_frames=k, why=why)
    F, P, S = weight.shape
    if balance is not None and balance.balance != "none" and contact is not None:
        from pipeline.backends.mujoco.balance import balance_reference

        qref, _ = balance_reference(scene, qref, contact, kp.fps, balance, posture_weight=posture_weight, sole_lift_m=sole_lift_m)
    if separate and P > 1:
        # a person absent from the input in a frame is not separated from, nor pushed away
        qref = separate_reference(scene, qref, clearance_m=separation_clearance_m, absent=out_of_view(weight))
    vref = reference_velocity(m, qref, kp.fps)
    d = mujoco.MjData(m)
    local = np.zeros((F, P, S, 3))
    for f in range(F):
        d.qpos[:] = qref[f]
        mujoco.mj_kinematics(m, d)
        for i, p in enumerate(lay.persons):
            if separate:
                targets[f, i] = d.site_xpos[scene.site_ids[i]]
            R = d.xmat[p.root_body].reshape(3, 3)
            local[f, i] = (targets[f, i] - d.xpos[p.root_body]) @ R
    schedule = None
    if substeps > 0 and F > 1:
        schedule = servo_schedule(m, lay, qref, kp.fps, substeps, contact, friction=ff_friction, smooth_frames=ff_smooth_frames)
        vref = schedule.qvel[:, 0].copy()
        ctrl, root_torque = schedule.ctrl[:, 0].copy(), schedule.root_torque[:, 0].copy()
    else:
        ctrl, root_torque = servo_feedforward(scene, qref, vref, kp.fps)
    ref = Reference(
        site_ids=scene.site_ids, site_local_m=local, site_world_m=targets, site_weight=weight, qpos=qref, qvel=vref,
        ctrl=ctrl, root_torque_ff=root_torque, foot_contact=contact, schedule=schedule,
    )
    return ref, targets, weight, ik


def servo_feedforward(scene: Scene, qref: np.ndarray, vref: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Servo targets (frames, nu) that reproduce the inverse-dynamics torques of the
    reference with ground reactions at the feet (``contact_inverse_dynamics``):
    u = q̂ + (τ_id + kv·q̂̇) / kp, clamped to the control range. The residual root
    servos get the same form with the root force the feet cannot supply; the
    matching residual root torque (frames, persons, 3, world) is returned too.

    Without this feed-forward a PD servo sags by τ/kp under gravity (~0.2 rad at
    the stance knee).
    """
    m, lay = scene.model, scene.layout
    tau, resid = contact_inverse_dynamics(m, lay, qref, vref, fps)
    acts = np.concatenate([lay.servo_ids, lay.residual_ids])
    dof = np.array([m.jnt_dofadr[m.actuator_trnid[a, 0]] for a in acts], dtype=np.int64)
    qa = np.array([m.jnt_qposadr[m.actuator_trnid[a, 0]] for a in acts], dtype=np.int64)
    kp = m.actuator_gainprm[acts, 0]
    kv = -m.actuator_biasprm[acts, 2]
    ctrl = np.zeros((qref.shape[0], m.nu))
    ctrl[:, acts] = qref[:, qa] + (tau[:, dof] + kv * vref[:, dof]) / kp
    lo, hi = m.actuator_ctrlrange[acts, 0], m.actuator_ctrlrange[acts, 1]
    ctrl[:, acts] = np.clip(ctrl[:, acts], lo, hi)
    return ctrl, resid[..., 3:]


def lift_off_floor(scene: Scene, qpos: np.ndarray) -> np.ndarray:
    """Raise each person so that no geom penetrates the floor (initial state only)."""
    m, lay = scene.model, scene.layout
    d = mujoco.MjData(m)
    q = qpos.copy()
    d.qpos[:] = q
    mujoco.mj_forward(m, d)
    floor = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    lift = np.zeros(len(lay.persons))
    for c in range(d.ncon):
        g1, g2 = d.contact.geom[c]
        if floor not in (g1, g2):
            continue
        other = g2 if g1 == floor else g1
        pi = lay.geom_person[other]
        if pi >= 0:
            lift[pi] = max(lift[pi], -d.contact.dist[c])
    for i, p in enumerate(lay.persons):
        q[p.qpos_adr + 2] += lift[i] + 1e-3 if lift[i] > 0 else 0.0
    return q


def contact_inverse_dynamics(
    model: mujoco.MjModel,
    layout: SceneLayout,
    qref: np.ndarray,
    vref: np.ndarray,
    fps: float,
    contact_height_m: float = 0.06,
    friction: float = 0.8,
    smooth_frames: float = 3.0,
    force_reg: float = 1e-4,
) -> tuple[np.ndarray, np.ndarray]:
    """Inverse dynamics of the reference with ground reaction forces at the feet.

    Per frame, ``mj_inverse`` without constraints gives the generalised forces of
    the reference motion, whose root part W (6 per person) a free-floating body
    cannot produce itself. It is distributed to the foot sites (heel, toes) lower
    than ``contact_height_m`` as forces in a linearised friction cone (4 edges,
    coefficient ``friction``), by non-negative least squares; the hinge torques
    then are τ − Jᵀf. Whatever the feet cannot supply (flight, or a wrench outside
    the cone) is left as the residual root wrench.

    Returns ``(hinge_and_root_forces (frames, nv), residual (frames, persons, 6))``:
    the first array holds τ at hinge DOFs (and W − Jᵀf at root DOFs); the residual
    is world force (N) at the pelvis origin and world torque (N·m).
    """
    from scipy.ndimage import gaussian_filter1d

    d = mujoco.MjData(model)
    F = qref.shape[0]
    v_s = gaussian_filter1d(vref, smooth_frames, axis=0, mode="nearest") if F > 2 and smooth_frames > 0 else vref
    acc = np.gradient(v_s, 1.0 / fps, axis=0) if F > 1 else np.zeros_like(vref)
    feet = [[s for side in person for s in side] for person in foot_site_ids(layout)]
    out = np.zeros((F, model.nv))
    resid = np.zeros((F, len(layout.persons), 6))
    saved = int(model.opt.disableflags)
    model.opt.disableflags = saved | int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    try:
        for f in range(F):
            d.qpos[:] = qref[f]
            d.qvel[:] = vref[f]
            d.qacc[:] = acc[f]
            mujoco.mj_kinematics(model, d)
            loaded = [[s for s in person if d.site_xpos[s, 2] < contact_height_m] for person in feet]
            out[f], resid[f] = contact_inverse_dynamics_point(model, d, layout, loaded, friction, force_reg)
    finally:
        model.opt.disableflags = saved
    return out, resid


def plant_feet(
    targets: np.ndarray,
    weight: np.ndarray,
    names: tuple[str, ...],
    fps: float,
    sole_m: np.ndarray,
    height_tol_m: float = 0.02,
    speed_max_m_s: float = 0.3,
    min_frames: int = 3,
    blend_frames: int = 3,
    extend_frames: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Contact-consistent reference feet (pure numpy).

    A foot is planted where its lowest point (heel, toes) is within
    ``height_tol_m`` of the sole height ``sole_m`` (persons,) and its centre moves
    slower than ``speed_max_m_s`` (5-frame smoothed), for at least ``min_frames``.
    During a plant each foot point is held at its median position (z clamped to
    the sole height or above), blended in and out over ``blend_frames``; elsewhere
    foot points are only lifted to the sole height. Triangulation noise otherwise
    makes planted feet skate and dip into the floor, which the simulated contact
    then fights.

    The 5-frame smoothed speed still carries the swing into the first and last frames
    of a stance (a fitted foot lands at 5–10 mm/frame), so plants were found a frame or
    two late and ended a frame early: on the synthetic bouts 0 and 2, 23 and 41 of 420
    labelled contact frames were left sliding. Each plant is therefore extended by up to
    ``extend_frames`` frames at either end where the foot is low (within
    ``height_tol_m``), and held at the median of its core frames. Bouts 0–3 (multi,
    same fitted input): the simulation's skating 0.51 → 0.42 mm/frame at the same
    MPJPE (11.90 → 11.94 mm); 2 frames overshoot (0.49 mm/frame, 12.77 mm); extending
    only the start by 1 or 2 frames gave 0.47 / 11.79 and 0.47 / 11.88. On
    ``cornerman bench physics`` (bouts 0–3, refitted): skating 0.51 → 0.43 mm/frame (its
    stance edges 1.29 → 0.59), MPJPE 11.7 → 12.0 mm.

    targets: (frames, persons, sites, 3); weight: (frames, persons, sites).
    Returns (targets, contact (frames, persons, 2) for left/right).
    """
    from scipy.ndimage import uniform_filter1d

    out = targets.copy()
    F, P = targets.shape[:2]
    contact = np.zeros((F, P, 2), dtype=bool)
    for i in range(P):
        for k, side in enumerate(("left", "right")):
            idx = [names.index(f"{side}_{n}") for n in FOOT_SITES if f"{side}_{n}" in names]
            if not idx:
                continue
            w = weight[:, i, idx] > 0
            ok = w.any(axis=1)
            pts = targets[:, i, idx]
            z = np.where(w, pts[..., 2], np.inf).min(axis=1)
            centre = np.where(w[..., None], pts, 0.0).sum(axis=1) / np.maximum(w.sum(axis=1), 1)[:, None]
            v = np.zeros(F)
            if F > 1:
                v[1:] = np.linalg.norm(np.diff(centre[:, :2], axis=0), axis=-1) * fps
                v[0] = v[1]
            v = uniform_filter1d(v, 5, mode="nearest")
            low = ok & (z < sole_m[i] + height_tol_m)
            on = low & (v < speed_max_m_s)
            # Keep runs of at least min_frames.
            f = 0
            while f < F:
                if not on[f]:
                    f += 1
                    continue
                g = f
                while g < F and on[g]:
                    g += 1
                if g - f >= min_frames:
                    core = slice(f, g)
                    a0, b0 = f, g
                    for _ in range(extend_frames):
                        if a0 > 0 and low[a0 - 1] and not contact[a0 - 1, i, k]:
                            a0 -= 1
                        if b0 < F and low[b0] and not on[b0]:
                            b0 += 1
                    contact[a0:b0, i, k] = True
                    for j_local, j in enumerate(idx):
                        okj = w[core, j_local]
                        if not okj.any():
                            continue
                        hold = np.median(targets[core, i, j][okj], axis=0)
                        hold[2] = max(hold[2], sole_m[i])
                        for t in range(max(a0 - blend_frames, 0), min(b0 + blend_frames, F)):
                            dist = max(a0 - t, t - (b0 - 1), 0)
                            a = 1.0 - dist / (blend_frames + 1)
                            out[t, i, j] = a * hold + (1.0 - a) * out[t, i, j]
                f = g
            for j in idx:
                out[:, i, j, 2] = np.maximum(out[:, i, j, 2], sole_m[i])
    return out, contact
