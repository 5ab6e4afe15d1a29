"""The physics stage's cost (paper eq. 5) and the kinematic reference it tracks.

Cost at step t (x = (q, v), u = servo targets):

    w1 (‖v‖² + ‖u − û‖²)                                  L_reg
  + w2 (Σ_sites c_j [(1−β) ‖R_rootᵀ(s_j − p_root) − ŝ_j^body‖²   L_p, body frame
                     + β ‖s_j − ŝ_j^world‖²]                    (+ world frame, β = world_frac)
        + ‖p_root − p̂_root‖² + (0.3 m)² ‖q_root ⊖ q̂_root‖²)  (+ root placement)
  + w3 ‖v − v̂‖²                                           L_v
  + w4 Σ_{contacts between people} depth²                  L_collision
  + w_skate Σ_{foot points of planted feet} ‖v_xy‖²        (foot contact, ours)

Hatted quantities come from the reference: per-frame inverse kinematics of the
fitted 3D joints onto the humanoid's sites, made contact-consistent
(``reference.build_reference``). The
servo-target regulariser replaces the paper's ‖u‖² because our controls are PD
targets, not torques: û are the reference servo targets with the inverse-dynamics
feed-forward (``reference.servo_feedforward``), which cost nothing.
Gauss–Newton Hessians: lxx = 2 Σ w Jᵀ J. Contact-depth Jacobians use the contact
normal n (geom1 → geom2): ∂dist/∂q = nᵀ (J_body2(p) − J_body1(p)).
"""

from __future__ import annotations

import copy
import math
import threading
from dataclasses import dataclass

import mujoco
import numpy as np

from pipeline.backends.mujoco.absent import geom_groups
from pipeline.backends.mujoco.config import CostWeights
from pipeline.backends.mujoco.humanoid import SceneLayout
from pipeline.backends.mujoco.schedule import ServoSchedule

ROOT_ROT_LEVER_M = 0.3
FOOT_SITES = ("heel", "big_toe", "small_toe")
_EYE3 = np.eye(3)


@dataclass(frozen=True)
class Reference:
    """What the optimiser tracks, frame by frame.

    site_ids: (persons, sites) MuJoCo site ids of the tracked keypoints.
    site_local_m: (frames, persons, sites, 3) keypoints in the reference root frame.
    site_world_m: (frames, persons, sites, 3) keypoints in the world frame.
    site_weight: (frames, persons, sites) ≥ 0 (0 where the joint was not observed).
    qpos: (frames, nq) reference (IK) configuration; qvel: (frames, nv).
    ctrl: (frames, nu) reference servo targets (inverse-dynamics feed-forward
    included, residual root servos too).
    """

    site_ids: np.ndarray
    site_local_m: np.ndarray
    site_world_m: np.ndarray
    site_weight: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    ctrl: np.ndarray
    root_torque_ff: np.ndarray | None = None
    """(frames, persons, 3) world-frame residual root torque (N·m) the reference
    needs beyond what the feet can supply (inverse dynamics), or None."""
    foot_contact: np.ndarray | None = None
    """(frames, persons, 2) planted left/right feet of the reference, or None."""
    schedule: ServoSchedule | None = None
    """The reference between frames, per substep (``schedule.servo_schedule``):
    ``prepare`` moves the servo targets and the residual root torque along it within a
    frame. None: both are held for the whole frame."""


def _skew(a: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _skews(a: np.ndarray) -> np.ndarray:
    """(n, 3, 3) cross-product matrices of the rows of ``a`` (n, 3): ``_skew`` of each."""
    out = np.zeros((a.shape[0], 3, 3))
    out[:, 0, 1], out[:, 0, 2] = -a[:, 2], a[:, 1]
    out[:, 1, 0], out[:, 1, 2] = a[:, 2], -a[:, 0]
    out[:, 2, 0], out[:, 2, 1] = -a[:, 1], a[:, 0]
    return out


def collision_depths(
    model: mujoco.MjModel, data: mujoco.MjData, geom_group: np.ndarray, with_jac: bool, max_dist_m: float = 0.0
) -> tuple[np.ndarray, np.ndarray | None]:
    """Penetration depths (c,) of contacts between geoms of different groups
    (``geom_group`` (ngeom,): person index, -1 = not a person) and, optionally,
    their Jacobians (c, nv) with respect to the tangent of qpos. Contacts up to
    ``max_dist_m`` apart (within a geom margin) are included, with negative depth.

    Uses the contact normal n (geom1 → geom2): ∂dist/∂q = nᵀ (J_body2(p) − J_body1(p)),
    so ∂depth/∂q = −nᵀ (J_body2(p) − J_body1(p)). ``data`` must hold a forward pass.
    """
    n = data.ncon
    if n == 0:
        idx: list[int] = []
        depth = np.zeros(0)
    else:
        # Whole-array reads: indexing the contact list one contact at a time is slow.
        g, dist = data.contact.geom[:n], data.contact.dist[:n]
        pa, pb = geom_group[g[:, 0]], geom_group[g[:, 1]]
        sel = np.flatnonzero((pa >= 0) & (pb >= 0) & (pa != pb) & (dist < max_dist_m))
        idx, depth = sel.tolist(), -dist[sel]
    if not with_jac:
        return depth, None
    J = np.zeros((len(idx), model.nv))
    j1, j2 = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    for row, c in enumerate(idx):
        con = data.contact[c]
        mujoco.mj_jac(model, data, j1, None, con.pos, model.geom_bodyid[con.geom[0]])
        mujoco.mj_jac(model, data, j2, None, con.pos, model.geom_bodyid[con.geom[1]])
        J[row] = -(con.frame[:3] @ (j2 - j1))
    return depth, J


class TrackingCost:
    """Eq. 5 as a :class:`pipeline.backends.mujoco.ilqr.Cost`."""

    thread_safe = True
    """``prepare`` and ``value`` keep their scratch per call or per thread (the collision
    probe's data), so the iLQR may roll out and differentiate on worker threads."""
    derivatives_thread_safe = True
    """``derivatives`` too keeps its scratch per call or per thread."""
    non_negative = True
    """Every term is a weighted square with a weight >= 0 (``CostWeights`` refuses negative
    ones), so the iLQR may stop a line-search rollout once its cost exceeds the best total."""

    def __init__(
        self,
        model: mujoco.MjModel,
        layout: SceneLayout,
        ref: Reference,
        weights: CostWeights,
        probe: mujoco.MjModel | None = None,
    ) -> None:
        """``probe``: a model of the same scene whose contacts the collision term reads
        (``Scene.probe_model``: every pair of the athletes' geoms, also the arm-arm pairs
        the simulated ``model`` leaves out); None: ``model``'s own contacts."""
        self.model = model
        if weights.collision_clearance_m > 0.0:
            # Contacts are generated within a geom's margin: a copy of the probe with
            # the clearance as margin reports pairs closer than it (the simulation's own
            # model is not touched).
            probe = copy.deepcopy(probe if probe is not None else model)
            probe.geom_margin[layout.geom_person >= 0] = weights.collision_clearance_m
        self._probe = probe
        self._probe_data = threading.local()
        self.layout = layout
        self.geom_group = layout.geom_person
        """Person index per geom for the collision term, -1 = left out (the floor, and absent
        persons: ``set_absent``)."""
        self.ref = ref
        self.w = weights
        self.servo = layout.servo_ids
        self.hinge_qpos = np.concatenate([p.hinge_qpos for p in layout.persons])
        self._ref_root = []
        nf = ref.qpos.shape[0]
        for p in layout.persons:
            pos = ref.qpos[:, p.qpos_adr : p.qpos_adr + 3]
            quat = ref.qpos[:, p.qpos_adr + 3 : p.qpos_adr + 7]
            self._ref_root.append((pos, quat))
        self._nf = nf
        self._root_rot_dofs = [np.arange(p.qvel_adr + 3, p.qvel_adr + 6) for p in layout.persons]
        self._root_damping0 = [model.dof_damping[d].copy() for d in self._root_rot_dofs]
        P = len(layout.persons)
        self.residual_on = False
        self._tau_lim, self._kp_rot, self._kd_rot = np.zeros(P), np.zeros(P), np.zeros(P)
        self._acts = np.concatenate([layout.servo_ids, layout.residual_ids]).astype(np.int64)
        # (frames, persons, sites) square roots of the body- and world-frame site weights.
        self._sqrt_w_body = np.sqrt(ref.site_weight * (1.0 - weights.world_frac))
        self._sqrt_w_world = np.sqrt(ref.site_weight * weights.world_frac)
        sch = ref.schedule
        # (frames, substeps, acts) what ``prepare`` adds to a frame's servo targets at each substep.
        self._ctrl_shift = (
            None if sch is None else sch.ctrl[:, :, self._acts] - sch.ctrl[:, :1, self._acts]
        )
        self._ref_ctrl_acts = ref.ctrl[:, self._acts]
        # Per person: (qpos address of the root quaternion, root body id).
        self._root_adr_body = [(p.qpos_adr + 3, p.root_body) for p in layout.persons]
        self._ref_cache: dict[tuple[int, int], list[tuple[np.ndarray, np.ndarray, np.ndarray | None]]] = {}
        # ``prepare``'s per-person constants at (frame, substep): the root's qpos address and
        # body, −kp, the torque limit and ``_root_ref``'s parts (cleared with ``_ref_cache``).
        self._prep_cache: dict[tuple[int, int], list[tuple[int, int, float, float, np.ndarray, np.ndarray, np.ndarray | None]]] = {}
        self._scratch = threading.local()
        self._jac_scratch = threading.local()
        # ``data.ctrl[acts] += x`` is ``data.ctrl += x`` when the controls are all of them, in order.
        self._acts_all = bool(np.array_equal(self._acts, np.arange(model.nu)))
        # Per person: the Jacobians (3, nv) of the root placement residuals (position, rotation).
        self._root_jacs = []
        for p in layout.persons:
            Jp = np.zeros((3, model.nv))
            Jp[:, p.qvel_adr : p.qvel_adr + 3] = np.eye(3)
            Jr = np.zeros((3, model.nv))
            Jr[:, p.qvel_adr + 3 : p.qvel_adr + 6] = ROOT_ROT_LEVER_M * np.eye(3)
            self._root_jacs.append((Jp, Jr))
        self._zero_jac = np.zeros((3, model.nv))
        # Gauss-Newton Hessian of the velocity terms (w_reg, w_vel) in the qvel block.
        self._vel_hess = 2 * (weights.w_reg + weights.w_vel) * np.eye(model.nv)
        # Per-control weight of the deviation from the reference's targets: w_reg for the
        # servos, w_residual for the residual root servos (their use is to be rare).
        self._u_weight = np.concatenate(
            [np.full(layout.servo_ids.size, weights.w_reg), np.full(layout.residual_ids.size, weights.w_residual)]
        )
        self._feet = [
            [[int(p.site_ids[f"{side}_{n}"]) for n in FOOT_SITES if f"{side}_{n}" in p.site_ids] for side in ("left", "right")]
            for p in layout.persons
        ]

    def _t(self, t: int) -> int:
        return min(max(t, 0), self._nf - 1)

    def _pose_residuals(self, data: mujoco.MjData, t: int, with_jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """Stacked sqrt-weighted residuals of L_p (and their Jacobians, (r, nv))."""
        m, ref, lay = self.model, self.ref, self.layout
        rs: list[np.ndarray] = []
        js: list[np.ndarray] = []
        xpos, xmat, site_xpos, qpos = data.xpos, data.xmat, data.site_xpos, data.qpos
        for i, p in enumerate(lay.persons):
            proot = xpos[p.root_body]
            R = xmat[p.root_body].reshape(3, 3)
            w, ww = self._sqrt_w_body[t, i], self._sqrt_w_world[t, i]
            sites = ref.site_ids[i]
            sx = site_xpos[sites]
            v = sx - proot  # (S, 3)
            local = v @ R  # R^T v per row
            rs.append(((local - ref.site_local_m[t, i]) * w[:, None]).ravel())
            rs.append(((sx - ref.site_world_m[t, i]) * ww[:, None]).ravel())
            pos_ref, quat_ref = self._ref_root[i][0][t], self._ref_root[i][1][t]
            rs.append(proot - pos_ref)
            drot = np.zeros(3)
            mujoco.mju_subQuat(drot, qpos[p.qpos_adr + 3 : p.qpos_adr + 7], quat_ref)
            rs.append(ROOT_ROT_LEVER_M * drot)
            if with_jac:
                va = p.qvel_adr
                jw: list[np.ndarray] = []
                J = getattr(self._jac_scratch, "J", None)
                if J is None:  # per thread: derivatives may run on several
                    J = self._jac_scratch.J = np.zeros((3, m.nv))
                skews = _skews(local)
                zero = self._zero_jac  # np.vstack copies: the rows may share one array
                for s_idx, sid in enumerate(sites.tolist()):
                    if w[s_idx] == 0.0 and ww[s_idx] == 0.0:
                        js.append(zero)
                        jw.append(zero)
                        continue
                    mujoco.mj_jacSite(m, data, J, None, sid)
                    jw.append(ww[s_idx] * J)
                    J[:, va : va + 3] -= _EYE3
                    Jl = R.T @ J
                    Jl[:, va + 3 : va + 6] += skews[s_idx]
                    js.append(w[s_idx] * Jl)
                js += jw
                js += self._root_jacs[i]
        r = np.concatenate(rs)
        return r, (np.vstack(js) if with_jac else None)

    def _skate(self, data: mujoco.MjData, t: int, with_jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """Horizontal velocities of planted foot points (k,) and their Jacobians wrt qvel (k, nv)."""
        fc = self.ref.foot_contact
        if fc is None or self.w.w_skate <= 0:
            return np.zeros(0), (np.zeros((0, self.model.nv)) if with_jac else None)
        rs, js = [], []
        jac = np.zeros((3, self.model.nv))  # per call: rollouts may run on threads
        J = jac[:2]
        qvel = data.qvel
        planted = fc[t].tolist()
        for i in range(len(self.layout.persons)):
            for k in range(2):
                if not planted[i][k]:
                    continue
                for sid in self._feet[i][k]:
                    mujoco.mj_jacSite(self.model, data, jac, None, sid)
                    rs.append(J @ qvel)
                    if with_jac:
                        js.append(J.copy())
        if not rs:
            return np.zeros(0), (np.zeros((0, self.model.nv)) if with_jac else None)
        return np.concatenate(rs), (np.vstack(js) if with_jac else None)

    def _collision(self, data: mujoco.MjData, with_jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """Depths by which pairs of the athletes' geoms fall short of the clearance."""
        if self._probe is None:
            return collision_depths(self.model, data, self.geom_group, with_jac)
        gap = self.w.collision_clearance_m
        pd = getattr(self._probe_data, "d", None)
        if pd is None:  # one per thread: line-search rollouts may run on threads
            pd = self._probe_data.d = mujoco.MjData(self._probe)
        pd.qpos[:] = data.qpos
        mujoco.mj_kinematics(self._probe, pd)
        mujoco.mj_comPos(self._probe, pd)
        mujoco.mj_collision(self._probe, pd)
        depth, J = collision_depths(self._probe, pd, self.geom_group, with_jac, max_dist_m=gap)
        return depth + gap, J

    def set_absent(self, absent: np.ndarray) -> None:
        """Leave the ``absent`` (persons,) persons out of the collision term (their stand-ins
        may overlap anyone: ``absent.geom_groups``)."""
        self.geom_group = geom_groups(self.layout.geom_person, absent)

    def set_residual(self, on: bool, torque_limit_nm: np.ndarray | None = None, saturation_rad: float = 0.1) -> None:
        """Enable the residual root torque: a PD on each root orientation towards the
        reference, plus the reference's feed-forward torque.

        The proportional and feed-forward parts (together |τ| ≤ ``torque_limit_nm``
        (persons,)) are applied through ``xfrc_applied`` before each step
        (``prepare``). The damping, −kd (ω − ω̂), is not limited and is split: −kd ω
        is the root ball joint's ``dof_damping``, which MuJoCo's implicit integrator
        treats implicitly, and +kd ω̂ is added to the explicit torque (unclipped, or
        the two halves would no longer cancel at ω = ω̂). Computed explicitly, the
        damping was unstable at the stiffness a strong residual needs, and even at
        the default gains it cost tracking (single person, first 80 frames of the
        bench bout, open loop: MPJPE 38.3 → 34.1 mm; with iLQR 29.2 → 23.5 mm).
        ``set_residual(False)`` restores the model's damping."""
        self.residual_on = on
        if torque_limit_nm is not None:
            self._tau_lim = np.asarray(torque_limit_nm, dtype=float)
            self._kp_rot = self._tau_lim / saturation_rad
            inertia = np.array([p.mass_kg * 0.15**2 for p in self.layout.persons])
            self._kd_rot = 2.0 * np.sqrt(self._kp_rot * inertia)
            self._ref_cache.clear()
            self._prep_cache.clear()
        for i, dofs in enumerate(self._root_rot_dofs):
            extra = self._kd_rot[i] if on else 0.0
            self.model.dof_damping[dofs] = self._root_damping0[i] + extra

    def _root_ref(self, t: int, sub: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray | None]]:
        """Per person, the reference's part of the residual root torque at substep ``sub`` of
        frame ``t`` (clamped to the reference): (root quaternion wxyz (4,), kd·ω̂ in the
        world (3,) N·m, feed-forward torque (3,) N·m or None). Cached: they depend on the
        reference and the gains only, and ``prepare`` needs them at every substep."""
        key = (t, sub)
        hit = self._ref_cache.get(key)
        if hit is not None:
            return hit
        tr = self._t(t)
        sch = self.ref.schedule
        s = min(max(sub, 0), sch.substeps - 1) if sch is not None else 0
        R_ref = np.zeros(9)
        out = []
        for i, p in enumerate(self.layout.persons):
            if sch is not None:
                q_ref = sch.qpos[tr, s, p.qpos_adr + 3 : p.qpos_adr + 7].copy()
                w_loc = sch.qvel[tr, s, p.qvel_adr + 3 : p.qvel_adr + 6]
                ff: np.ndarray | None = sch.root_torque[tr, s, i].copy()
            else:
                q_ref = self._ref_root[i][1][tr].copy()
                w_loc = self.ref.qvel[tr, p.qvel_adr + 3 : p.qvel_adr + 6]
                ff = None if self.ref.root_torque_ff is None else self.ref.root_torque_ff[tr, i].copy()
            mujoco.mju_quat2Mat(R_ref, q_ref)
            w_ref = R_ref.reshape(3, 3) @ w_loc
            out.append((q_ref, self._kd_rot[i] * w_ref, ff))
        self._ref_cache[key] = out
        return out

    def _root_torque_parts(self, qpos: np.ndarray, qvel: np.ndarray, t: int, sub: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(explicit, implicit) residual root torques (persons, 3), world frame, N·m, at
        substep ``sub`` of frame ``t`` (the reference interpolated there when it has a
        schedule)."""
        P = len(self.layout.persons)
        expl, impl = np.zeros((P, 3)), np.zeros((P, 3))
        if not self.residual_on:
            return expl, impl
        R = np.zeros(9)
        err = np.zeros(3)
        for i, (p, (q_ref, kd_w_ref, ff)) in enumerate(zip(self.layout.persons, self._root_ref(t, sub), strict=True)):
            mujoco.mju_subQuat(err, qpos[p.qpos_adr + 3 : p.qpos_adr + 7], q_ref)
            mujoco.mju_quat2Mat(R, qpos[p.qpos_adr + 3 : p.qpos_adr + 7])
            Rm = R.reshape(3, 3)
            tau = -self._kp_rot[i] * (Rm @ err)
            if ff is not None:
                tau = tau + ff
            # sqrt(τ·τ): what np.linalg.norm computes for a vector, without its overhead.
            n = math.sqrt(float(tau.dot(tau)))
            expl[i] = (tau if n <= self._tau_lim[i] else tau * (self._tau_lim[i] / n)) + kd_w_ref
            impl[i] = -self._kd_rot[i] * (Rm @ qvel[p.qvel_adr + 3 : p.qvel_adr + 6])
        return expl, impl

    def root_torque(self, qpos: np.ndarray, qvel: np.ndarray, t: int) -> np.ndarray:
        """(persons, 3) residual root torque (world frame, N·m) at state (qpos, qvel):
        the explicit part plus the joint damping's −kd ω (what acts on the root)."""
        expl, impl = self._root_torque_parts(qpos, qvel, t)
        return expl + impl

    def prepare(self, model: mujoco.MjModel, data: mujoco.MjData, t: int, sub: int = 0) -> None:
        """Before substep ``sub`` of frame ``t``: move the servo targets in ``data.ctrl``
        (the frame's controls, set by the caller) along the reference's schedule, and
        apply the explicit part of the residual root torque of the current state (when
        the residual is on; its damping part is the joint's)."""
        if self._ctrl_shift is not None and sub > 0:
            k = min(sub, self._ctrl_shift.shape[1] - 1)
            if self._acts_all:
                data.ctrl += self._ctrl_shift[self._t(t), k]
            else:
                data.ctrl[self._acts] += self._ctrl_shift[self._t(t), k]
        if not self.residual_on:
            return
        # ``_root_torque_parts``' explicit part, written straight into ``xfrc_applied``
        # (the same arithmetic; this runs at every substep of every rollout).
        qpos, xfrc = data.qpos, data.xfrc_applied
        scratch = self._scratch.__dict__
        if not scratch:  # per thread: rollouts run on several
            scratch["R"] = np.empty(9)
            scratch["err"] = np.empty(3)
        R, err = scratch["R"], scratch["err"]
        R33 = R.reshape(3, 3)
        parts = self._prep_cache.get((t, sub))
        if parts is None:
            parts = self._prep_cache[(t, sub)] = [
                (adr, body, float(-kp), float(lim), q_ref, kd_w_ref, ff)
                for (adr, body), kp, lim, (q_ref, kd_w_ref, ff) in zip(
                    self._root_adr_body, self._kp_rot, self._tau_lim, self._root_ref(t, sub), strict=True
                )
            ]
        for adr, body, neg_kp, lim, q_ref, kd_w_ref, ff in parts:
            q = qpos[adr : adr + 4]
            mujoco.mju_subQuat(err, q, q_ref)
            mujoco.mju_quat2Mat(R, q)
            tau = neg_kp * (R33 @ err)
            if ff is not None:
                tau += ff
            n = math.sqrt(float(tau.dot(tau)))
            xfrc[body, 3:6] = (tau if n <= lim else tau * (lim / n)) + kd_w_ref

    def value(self, model: mujoco.MjModel, data: mujoco.MjData, t: int, u: np.ndarray | None) -> float:
        t = self._t(t)
        w, ref = self.w, self.ref
        v = data.qvel
        rp, _ = self._pose_residuals(data, t, False)
        depth, _ = self._collision(data, False)
        c = w.w_reg * float(v @ v) + w.w_pos * float(rp @ rp) + w.w_vel * float(np.sum((v - ref.qvel[t]) ** 2))
        c += w.w_collision * float(depth @ depth)
        rs, _ = self._skate(data, t, False)
        c += w.w_skate * float(rs @ rs)
        if u is not None:
            du = (u if self._acts_all else u[self._acts]) - self._ref_ctrl_acts[t]
            c += float(du @ (self._u_weight * du))
        return c

    def derivatives(
        self, model: mujoco.MjModel, data: mujoco.MjData, t: int, u: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        t = self._t(t)
        w, ref, nv, nu = self.w, self.ref, model.nv, model.nu
        lx = np.zeros(2 * nv)
        lxx = np.zeros((2 * nv, 2 * nv))
        rp, Jp = self._pose_residuals(data, t, True)
        assert Jp is not None
        lx[:nv] += 2 * w.w_pos * (Jp.T @ rp)
        lxx[:nv, :nv] += 2 * w.w_pos * (Jp.T @ Jp)
        depth, Jc = self._collision(data, True)
        if depth.size:
            assert Jc is not None
            lx[:nv] += 2 * w.w_collision * (Jc.T @ depth)
            lxx[:nv, :nv] += 2 * w.w_collision * (Jc.T @ Jc)
        rs, Js = self._skate(data, t, True)
        if rs.size:
            assert Js is not None
            lx[nv:] += 2 * w.w_skate * (Js.T @ rs)
            lxx[nv:, nv:] += 2 * w.w_skate * (Js.T @ Js)
        v = data.qvel
        lx[nv:] += 2 * w.w_reg * v + 2 * w.w_vel * (v - ref.qvel[t])
        lxx[nv:, nv:] += self._vel_hess
        lu = np.zeros(nu)
        luu = np.zeros((nu, nu))
        if u is not None:
            lu[self._acts] = 2 * self._u_weight * (u[self._acts] - ref.ctrl[t, self._acts])
            luu[self._acts, self._acts] = 2 * self._u_weight
        return lx, lu, lxx, luu


