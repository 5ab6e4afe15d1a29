"""Physics backend entry point: humanoids from 3D joints, reference IK, receding-
horizon iLQR over a bout, and per-frame contacts.

Called by ``pipeline.stages.physics`` (which stays free of mujoco imports).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import mujoco
import numpy as np

from pipeline.backends.humanoid_skeleton import Skeleton
from pipeline.backends.mujoco_humanoid import (
    HumanoidConfig,
    SceneLayout,
    build_scene_mjcf,
    load_model,
    scene_layout,
)
from pipeline.backends.mujoco_ilqr import ILQRConfig, ILQRResult, UnstableRollout, optimise
from pipeline.backends.mujoco_tracking import CostWeights, Reference, TrackingCost, collision_depths
from pipeline.schema.keypoints3d import Keypoints3D

log = logging.getLogger(__name__)

RESIDUAL_GROUP = 3
"""Actuator group of the residual root servos (see ``mujoco_humanoid``)."""


@dataclass(frozen=True)
class Scene:
    mjcf: str
    model: mujoco.MjModel
    layout: SceneLayout
    person_ids: tuple[int, ...]
    site_names: tuple[str, ...]
    site_ids: np.ndarray  # (persons, sites)


def build_scene(skeletons: list[Skeleton], person_ids: list[int], fps: float, joint_names: tuple[str, ...], cfg: HumanoidConfig) -> Scene:
    """Compile the scene and map ``joint_names`` to sites of every person."""
    mjcf = build_scene_mjcf(skeletons, person_ids, fps, cfg)
    model = load_model(mjcf)
    layout = scene_layout(model, person_ids)
    names = tuple(n for n in joint_names if n in layout.persons[0].site_ids)
    ids = np.array([[p.site_ids[n] for n in names] for p in layout.persons], dtype=np.int64)
    return Scene(mjcf, model, layout, tuple(person_ids), names, ids)


def _servo_qpos(model: mujoco.MjModel, layout: SceneLayout) -> np.ndarray:
    return np.array([model.jnt_qposadr[model.actuator_trnid[a, 0]] for a in layout.servo_ids], dtype=np.int64)


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
) -> np.ndarray:
    """Per-frame damped least squares of sites onto targets, warm-started in time.

    targets: (frames, persons, sites, 3) world; weight: (frames, persons, sites).
    Returns qpos (frames, nq), hinge angles clamped to their ranges.
    """
    m, lay = scene.model, scene.layout
    d = mujoco.MjData(m)
    F, P, S = weight.shape
    q = m.qpos0.copy()
    for i, p in enumerate(lay.persons):
        ok = weight[:, i].sum(axis=-1) > 0
        f0 = int(np.argmax(ok))
        pos, quat = _initial_root(targets[f0, i], scene.site_names)
        q[p.qpos_adr : p.qpos_adr + 3] = pos
        q[p.qpos_adr + 3 : p.qpos_adr + 7] = quat
    hinge_j = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    hq = np.array([m.jnt_qposadr[j] for j in hinge_j], dtype=np.int64)
    lo, hi = m.jnt_range[hinge_j, 0], m.jnt_range[hinge_j, 1]
    out = np.zeros((F, m.nq))
    jac = np.zeros((3, m.nv))
    dq = np.zeros(m.nv)
    for f in range(F):
        for it in range(iters_first if f == 0 else iters):
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            JtJ = np.zeros((m.nv, m.nv))
            Jtr = np.zeros(m.nv)
            for i in range(P):
                for s in range(S):
                    w = weight[f, i, s]
                    if w <= 0:
                        continue
                    sid = int(scene.site_ids[i, s])
                    r = d.site_xpos[sid] - targets[f, i, s]
                    mujoco.mj_jacSite(m, d, jac, None, sid)
                    JtJ += w * jac.T @ jac
                    Jtr += w * jac.T @ r
            lam = damping * (10.0 if (f == 0 and it < 10) else 1.0)
            dq[:] = -np.linalg.solve(JtJ + lam * np.eye(m.nv) + 1e-6 * np.diag(np.diag(JtJ)), Jtr)
            mujoco.mj_integratePos(m, q, dq, 1.0)
            q[hq] = np.clip(q[hq], lo, hi)
        out[f] = q
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


def build_reference(scene: Scene, kp: Keypoints3D, person_rows: list[int]) -> tuple[Reference, np.ndarray, np.ndarray]:
    """IK reference + body-frame targets. Returns (reference, targets_world, weight)."""
    m, lay = scene.model, scene.layout
    jidx = [kp.joint_names.index(n) for n in scene.site_names]
    targets = kp.xyz_m[:, person_rows][:, :, jidx].astype(float)
    weight = (kp.valid[:, person_rows][:, :, jidx] * np.clip(kp.confidence[:, person_rows][:, :, jidx], 0.0, 1.0)).astype(float)
    targets = np.where(weight[..., None] > 0, targets, 0.0)
    qref = inverse_kinematics(scene, targets, weight)
    vref = reference_velocity(m, qref, kp.fps)
    d = mujoco.MjData(m)
    F, P, S = weight.shape
    local = np.zeros((F, P, S, 3))
    for f in range(F):
        d.qpos[:] = qref[f]
        mujoco.mj_kinematics(m, d)
        for i, p in enumerate(lay.persons):
            R = d.xmat[p.root_body].reshape(3, 3)
            local[f, i] = (targets[f, i] - d.xpos[p.root_body]) @ R
    ctrl = servo_feedforward(scene, qref, vref, kp.fps)
    nxt = np.minimum(np.arange(F) + 1, F - 1)
    for p in lay.persons:
        # Residual servos (used only in fallback windows) target the reference root.
        for k, a in enumerate(p.residual_ids):
            ctrl[:, a] = qref[nxt, p.qpos_adr + k]
    ref = Reference(site_ids=scene.site_ids, site_local_m=local, site_world_m=targets, site_weight=weight, qpos=qref, qvel=vref, ctrl=ctrl)
    return ref, targets, weight


def servo_feedforward(scene: Scene, qref: np.ndarray, vref: np.ndarray, fps: float) -> np.ndarray:
    """Servo targets (frames, nu) that reproduce the inverse-dynamics hinge torques
    of the reference: u = q̂ + (τ_id + kv·q̂̇) / kp, clamped to the joint range.

    Without this feed-forward a PD servo sags by τ/kp under gravity (~0.2 rad at
    the stance knee). Residual root controls are 0.
    """
    m, lay = scene.model, scene.layout
    d = mujoco.MjData(m)
    F = qref.shape[0]
    servo = lay.servo_ids
    dof = np.array([m.jnt_dofadr[m.actuator_trnid[a, 0]] for a in servo], dtype=np.int64)
    sq = _servo_qpos(m, lay)
    kp = m.actuator_gainprm[servo, 0]
    kv = -m.actuator_biasprm[servo, 2]
    acc = np.gradient(vref, 1.0 / fps, axis=0) if F > 1 else np.zeros_like(vref)
    ctrl = np.zeros((F, m.nu))
    for f in range(F):
        d.qpos[:] = qref[f]
        d.qvel[:] = vref[f]
        d.qacc[:] = acc[f]
        mujoco.mj_inverse(m, d)
        # Passive joint damping is part of qfrc_inverse's balance; the servo supplies the rest.
        tau = d.qfrc_inverse[dof]
        ctrl[f, servo] = qref[f, sq] + (tau + kv * vref[f, dof]) / kp
    lo, hi = m.actuator_ctrlrange[servo, 0], m.actuator_ctrlrange[servo, 1]
    ctrl[:, servo] = np.clip(ctrl[:, servo], lo, hi)
    return ctrl


def separate_persons(scene: Scene, qpos: np.ndarray, iters: int = 20, damping: float = 1e-3) -> np.ndarray:
    """Remove inter-person overlap from one configuration by Gauss–Newton on the
    contact depths (minimal change of all DOFs), so that a simulation does not
    start from a deep interpenetration (which MuJoCo resolves explosively)."""
    m, lay = scene.model, scene.layout
    d = mujoco.MjData(m)
    q = qpos.copy()
    for _ in range(iters):
        d.qpos[:] = q
        mujoco.mj_fwdPosition(m, d)
        depth, J = collision_depths(m, d, lay.geom_person, True)
        if depth.size == 0 or depth.max() < 1e-4:
            break
        assert J is not None
        r = depth + 1e-3
        dq = -np.linalg.solve(J.T @ J + damping * np.eye(m.nv), J.T @ r)
        mujoco.mj_integratePos(m, q, dq, 1.0)
    return q


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


@dataclass(frozen=True)
class SolverConfig:
    """Receding-horizon iLQR settings (see ``pipeline.stages.physics.PhysicsConfig``)."""

    window: int = 24
    """Frames per receding-horizon window."""
    commit: int = 16
    """Frames kept from each window."""
    ilqr: ILQRConfig = ILQRConfig()
    """Solver settings per window."""
    weights: CostWeights = CostWeights()
    """Cost weights (eq. 5)."""
    residual: str = "fallback"
    """``fallback`` / ``always`` / ``off`` (see ``PhysicsConfig.residual_root``)."""
    fallback_tol_m: float = 0.05
    """Mean joint error of a window above which it is redone with the residual."""
    residual_torque_frac: float = 0.5
    """Residual root torque limit: this fraction of body weight × 0.3 m."""


@dataclass
class BoutSolution:
    qpos: np.ndarray  # (F, nq)
    qvel: np.ndarray  # (F, nv)
    ctrl: np.ndarray  # (F, nu)
    actuator_force: np.ndarray  # (F, nu)
    root_wrench: np.ndarray  # (F, persons, 6) residual root force (N) and torque (N·m), world
    windows: int = 0
    windows_with_residual: int = 0
    resets: int = 0
    iterations: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    cost_first: list[float] = field(default_factory=list)
    cost_final: list[float] = field(default_factory=list)


def _first_stable(
    m: mujoco.MjModel,
    d: mujoco.MjData,
    cost: TrackingCost,
    qpos0: np.ndarray,
    qvel0: np.ndarray,
    inits: list[np.ndarray],
    cfg: SolverConfig,
    active: np.ndarray,
    t0: int,
    warm: np.ndarray | None,
) -> ILQRResult | None:
    """Optimise from the first initial control sequence that does not diverge."""
    for u0 in inits:
        try:
            return optimise(m, d, cost, qpos0, qvel0, u0, cfg.ilqr, active=active, t0=t0, warm0=warm)
        except UnstableRollout:
            continue
    return None


def _mean_site_error(scene: Scene, qpos: np.ndarray, targets: np.ndarray, weight: np.ndarray) -> float:
    d = mujoco.MjData(scene.model)
    err, tot = 0.0, 0.0
    for f in range(qpos.shape[0]):
        d.qpos[:] = qpos[f]
        mujoco.mj_kinematics(scene.model, d)
        for i in range(len(scene.layout.persons)):
            e = np.linalg.norm(d.site_xpos[scene.site_ids[i]] - targets[f, i], axis=-1)
            err += float((e * weight[f, i]).sum())
            tot += float(weight[f, i].sum())
    return err / max(tot, 1e-9)


def count_windows(n_frames: int, window: int, commit: int) -> int:
    """Number of receding-horizon windows over ``n_frames`` (the last one is kept whole)."""
    s, n = 0, 0
    while s < n_frames - 1:
        H = min(window, n_frames - 1 - s)
        s += H if s + H >= n_frames - 1 else min(commit, H)
        n += 1
    return n


def optimise_bout(
    scene: Scene,
    ref: Reference,
    targets: np.ndarray,
    weight: np.ndarray,
    cfg: SolverConfig,
    progress: Callable[[int, int, str], None] | None = None,
) -> BoutSolution:
    """Receding-horizon iLQR: windows of ``cfg.window`` steps, the first
    ``cfg.commit`` of which are kept; the next window starts from the simulated
    state, so the whole output is one continuous simulation. Cost is linear in the
    number of frames."""
    m, lay = scene.model, scene.layout
    d = mujoco.MjData(m)
    F = ref.qpos.shape[0]
    cost = TrackingCost(m, lay, ref, cfg.weights)
    sol = BoutSolution(
        qpos=np.zeros((F, m.nq)), qvel=np.zeros((F, m.nv)), ctrl=np.zeros((F, m.nu)), actuator_force=np.zeros((F, m.nu)),
        root_wrench=np.zeros((F, len(lay.persons), 6)),
        seconds={"derivatives_fd": 0.0, "derivatives_cost": 0.0, "backward": 0.0, "rollouts": 0.0},
    )
    qpos0 = lift_off_floor(scene, separate_persons(scene, ref.qpos[0]))
    qvel0 = ref.qvel[0].copy()
    warm = None
    carry = np.zeros((0, m.nu))
    servo = lay.servo_ids
    resid = lay.residual_ids
    res_bit = 1 << RESIDUAL_GROUP
    base_disable = int(m.opt.disableactuator)
    s = 0
    n_windows = count_windows(F, cfg.window, cfg.commit)
    sol.qpos[0], sol.qvel[0] = qpos0, qvel0

    bw = np.array([p.mass_kg * 9.81 for p in lay.persons])

    def set_residual(on: bool) -> None:
        m.opt.disableactuator = (base_disable & ~res_bit) if on else (base_disable | res_bit)
        cost.set_residual(on, cfg.residual_torque_frac * bw * 0.3)
        if not on:
            d.xfrc_applied[:] = 0.0

    try:
        while s < F - 1:
            H = min(cfg.window, F - 1 - s)
            u0 = ref.ctrl[s : s + H].copy()
            nc = min(carry.shape[0], H)
            u0[:nc, servo] = carry[:nc, servo]
            use_res = cfg.residual == "always" and resid.size > 0
            set_residual(use_res)
            res_or_none = _first_stable(m, d, cost, qpos0, qvel0, [u0, ref.ctrl[s : s + H]], cfg, servo, s, warm)
            if res_or_none is None and cfg.residual != "off" and resid.size and not use_res:
                use_res = True
                set_residual(True)
                res_or_none = _first_stable(m, d, cost, qpos0, qvel0, [u0, ref.ctrl[s : s + H]], cfg, servo, s, warm)
            if res_or_none is None:
                # Last resort: restart this window from the reference state.
                log.warning("physics: window at frame %d diverges from the simulated state; reset to the reference", s)
                sol.resets += 1
                qpos0 = lift_off_floor(scene, separate_persons(scene, ref.qpos[s]))
                qvel0, warm = ref.qvel[s].copy(), None
                res_or_none = _first_stable(m, d, cost, qpos0, qvel0, [ref.ctrl[s : s + H]], cfg, servo, s, warm)
                if res_or_none is None:
                    raise ValueError(f"physics: the simulation diverges at frame {s} even from the reference state")
            res = res_or_none
            if cfg.residual == "fallback" and resid.size and not use_res:
                err = _mean_site_error(scene, res.traj.qpos, targets[s : s + H + 1], weight[s : s + H + 1])
                if err > cfg.fallback_tol_m:
                    for k_, v_ in res.seconds.items():
                        sol.seconds[k_] += v_
                    sol.iterations += res.iterations
                    set_residual(True)
                    res2 = _first_stable(m, d, cost, qpos0, qvel0, [res.traj.ctrl], cfg, servo, s, warm)
                    if res2 is not None and res2.traj.total < res.traj.total:
                        res, use_res = res2, True
                    else:
                        set_residual(False)
            for k_, v_ in res.seconds.items():
                sol.seconds[k_] += v_
            sol.iterations += res.iterations
            sol.windows += 1
            sol.windows_with_residual += int(use_res)
            sol.cost_first.append(res.cost_history[0])
            sol.cost_final.append(res.cost_history[-1])
            C = H if s + H >= F - 1 else min(cfg.commit, H)
            tr = res.traj
            sol.qpos[s : s + C + 1] = tr.qpos[: C + 1]
            sol.qvel[s : s + C + 1] = tr.qvel[: C + 1]
            sol.ctrl[s : s + C] = tr.ctrl[:C]
            sol.actuator_force[s : s + C] = tr.actuator_force[:C]
            if not use_res:
                sol.actuator_force[s : s + C, resid] = 0.0
            for i, p in enumerate(lay.persons):
                sol.root_wrench[s : s + C, i, : p.residual_ids.size] = sol.actuator_force[s : s + C, p.residual_ids]
            if use_res:
                for t in range(C):
                    sol.root_wrench[s + t, :, 3:] = cost.root_torque(tr.qpos[t], tr.qvel[t], s + t)
            qpos0, qvel0, warm = tr.qpos[C].copy(), tr.qvel[C].copy(), tr.warmstart[C].copy()
            carry = tr.ctrl[C:]
            s += C
            if progress is not None:
                msg = f"window {sol.windows}/{n_windows}: cost {res.cost_history[0]:.3g} -> {res.cost_history[-1]:.3g}"
                progress(sol.windows, n_windows, msg)
    finally:
        m.opt.disableactuator = base_disable
        cost.set_residual(False)
    sol.ctrl[F - 1] = sol.ctrl[F - 2] if F > 1 else ref.ctrl[0]
    sol.actuator_force[F - 1] = sol.actuator_force[F - 2] if F > 1 else 0.0
    return sol


@dataclass
class FrameContacts:
    frame: np.ndarray  # (c,)
    person: np.ndarray  # (c, 2) person ids, -1 = ground
    body: np.ndarray  # (c, 2) indices into body_names
    depth_m: np.ndarray  # (c,)
    body_names: tuple[str, ...]


def contacts_and_sites(scene: Scene, qpos: np.ndarray, qvel: np.ndarray) -> tuple[FrameContacts, np.ndarray]:
    """Contacts of every frame (inter-person and ground) and the site positions
    (frames, persons, sites, 3)."""
    m, lay = scene.model, scene.layout
    d = mujoco.MjData(m)
    F = qpos.shape[0]
    names = tuple(m.body(b).name for b in range(m.nbody))
    pid = np.array([p.person_id for p in lay.persons])
    rows: list[tuple[int, int, int, int, int, float]] = []
    sites = np.zeros((F, len(lay.persons), scene.site_ids.shape[1], 3))
    for f in range(F):
        d.qpos[:] = qpos[f]
        d.qvel[:] = qvel[f]
        mujoco.mj_fwdPosition(m, d)
        for i in range(len(lay.persons)):
            sites[f, i] = d.site_xpos[scene.site_ids[i]]
        for c in range(d.ncon):
            g1, g2 = d.contact.geom[c]
            p1, p2 = lay.geom_person[g1], lay.geom_person[g2]
            if p1 == p2:
                continue
            rows.append((
                f,
                int(pid[p1]) if p1 >= 0 else -1,
                int(pid[p2]) if p2 >= 0 else -1,
                int(m.geom_bodyid[g1]),
                int(m.geom_bodyid[g2]),
                float(-d.contact.dist[c]),
            ))
    arr = np.array(rows, dtype=float).reshape(-1, 6)
    fc = FrameContacts(
        frame=arr[:, 0].astype(np.int64),
        person=arr[:, 1:3].astype(np.int64),
        body=arr[:, 3:5].astype(np.int64),
        depth_m=arr[:, 5].copy(),
        body_names=names,
    )
    return fc, sites
