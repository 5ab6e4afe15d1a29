"""Physics backend entry point: receding-horizon iLQR over a bout and per-frame
contacts; the scene and the reference come from ``reference`` (re-exported).

Called by ``pipeline.stages.physics`` (which stays free of mujoco imports).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import mujoco
import numpy as np

from pipeline.backends.mujoco.absent import AbsentContacts, absent_persons
from pipeline.backends.mujoco.config import ILQRConfig, ResidualConfig, SolverConfig
from pipeline.backends.mujoco.fd_split import PersonBlocks
from pipeline.backends.mujoco.ilqr import ILQRResult, UnstableRollout, optimise
from pipeline.backends.mujoco.reference import (
    Scene,
    build_reference,
    build_scene,
    contact_inverse_dynamics,
    inverse_kinematics,
    lift_off_floor,
    plant_feet,
    reference_velocity,
    separate_persons,
    separate_reference,
    servo_feedforward,
    site_targets,
    sole_heights_m,
)
from pipeline.backends.mujoco.tracking import Reference, TrackingCost

__all__ = [
    "BoutResume",
    "BoutSolution",
    "WindowRecord",
    "FrameContacts",
    "Scene",
    "SolverConfig",
    "build_reference",
    "build_scene",
    "contact_inverse_dynamics",
    "contacts_and_sites",
    "count_windows",
    "deepest_inter_person_mm",
    "inverse_kinematics",
    "lift_off_floor",
    "optimise_bout",
    "window_starts",
    "plant_feet",
    "reference_velocity",
    "separate_persons",
    "separate_reference",
    "servo_feedforward",
    "site_targets",
    "sole_heights_m",
    "untrackable_frames",
]

log = logging.getLogger(__name__)

RESIDUAL_GROUP = 3
"""Actuator group of the residual root servos (see ``humanoid``)."""


@dataclass
class BoutSolution:
    qpos: np.ndarray  # (F, nq)
    qvel: np.ndarray  # (F, nv)
    ctrl: np.ndarray  # (F, nu)
    actuator_force: np.ndarray  # (F, nu)
    root_wrench: np.ndarray  # (F, persons, 6) residual root force (N) and torque (N·m), world
    windows: int = 0
    windows_with_residual: int = 0
    untrackable_windows: int = 0
    """Windows that could not be tracked without the residual root force
    (``WindowRecord.untrackable``; 0 in residual mode ``always``, which does not try)."""
    resets: int = 0
    kinematic_frames: int = 0
    """Frames of windows that diverged even from the reference state: they hold the
    (separated) reference instead of a simulation, and the next window restarts from it."""
    iterations: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    cost_first: list[float] = field(default_factory=list)
    cost_final: list[float] = field(default_factory=list)
    records: list[WindowRecord] = field(default_factory=list)
    """One record per window, in order: where it started and what it carried in."""
    exact_retry_windows: int = 0
    """Windows this call re-planned with every substep differentiated
    (``SolverConfig.exact_retry_tol_m``), whether or not the new plan was kept."""
    planned_from_window: int = 0
    """Index of the first window this call optimised (the earlier ones came from ``resume``)."""


@dataclass(frozen=True)
class WindowRecord:
    """What a receding-horizon window started from and how it went: enough to re-run the
    bout from this window on exactly.

    start: first frame; qpos (nq,), qvel (nv,): the simulated state it started from (a
    reset window's output begins at the reference state instead); warm: (nv,) MuJoCo's
    ``qacc_warmstart`` there (zeros: none);
    carry: (k, nu) the previous window's controls past its committed frames, the initial
    controls of this window's first k steps (0 <= k < window); residual: whether the
    residual root wrench acted; iterations: iLQR iterations; reset: restarted from the
    reference state; kinematic: frames that kept the reference (diverged);
    cost_first/cost_final: the window's cost before and after the iLQR (nan: none);
    untrackable: without the residual root force the window diverged, was reset or
    tracked the sites worse than ``ResidualConfig.fallback_tol_m`` on average (residual
    modes ``off`` and ``fallback``; in ``fallback`` exactly the windows redone with the
    residual; always False in mode ``always``, which never tracks without it)."""

    start: int
    qpos: np.ndarray
    qvel: np.ndarray
    warm: np.ndarray
    carry: np.ndarray
    residual: bool = False
    iterations: int = 0
    reset: bool = False
    kinematic: int = 0
    cost_first: float = float("nan")
    cost_final: float = float("nan")
    untrackable: bool = False


@dataclass(frozen=True)
class BoutResume:
    """Re-run a bout from window ``replan_from`` on, keeping the windows before it.

    windows: the previous solution's records (``BoutSolution.records``, one per window of
    this bout); replan_from: index of the first window to re-plan (1 <= it <= windows; all
    windows: nothing is re-planned), which starts from its record's state, warm start and
    carried controls; qpos (frames, nq), qvel (frames, nv), ctrl, actuator_force
    (frames, nu), root_wrench (frames, persons, 6): the previous solution, whose frames
    before that window's start (all frames when nothing is re-planned) are copied;
    untrackable (frames,) bool: the previous solution's ``untrackable_frames``, which sets
    the kept windows' ``WindowRecord.untrackable`` (None: the records' own flags)."""

    windows: tuple[WindowRecord, ...]
    replan_from: int
    qpos: np.ndarray
    qvel: np.ndarray
    ctrl: np.ndarray
    actuator_force: np.ndarray
    root_wrench: np.ndarray
    untrackable: np.ndarray | None = None


def untrackable_frames(records: list[WindowRecord] | tuple[WindowRecord, ...], n_frames: int) -> np.ndarray:
    """(n_frames,) bool: the frames of the windows flagged ``untrackable``; a window owns
    the frames from its start up to the next window's start (the last one: to the end)."""
    out = np.zeros(n_frames, dtype=bool)
    for w, r in enumerate(records):
        end = records[w + 1].start if w + 1 < len(records) else n_frames
        out[r.start : end] = r.untrackable
    return out


def person_blocks(scene: Scene) -> PersonBlocks | None:
    """The scene's persons as ``fd_split.PersonBlocks`` (their DOFs, actuators and geoms), or
    None for one person or when they do not cover the model (the plain finite differences)."""
    lay, m = scene.layout, scene.model
    if len(lay.persons) < 2:
        return None
    blocks = PersonBlocks(
        dofs=tuple(np.arange(p.qvel_adr, p.qvel_adr + p.nv, dtype=np.int64) for p in lay.persons),
        acts=tuple(np.concatenate([p.servo_ids, p.residual_ids]).astype(np.int64) for p in lay.persons),
        geom_person=np.asarray(lay.geom_person, dtype=np.int64),
    )
    return blocks if blocks.fits(m) else None


def _first_stable(
    m: mujoco.MjModel,
    d: mujoco.MjData,
    cost: TrackingCost,
    qpos0: np.ndarray,
    qvel0: np.ndarray,
    inits: list[np.ndarray],
    cfg: ILQRConfig,
    active: np.ndarray,
    t0: int,
    warm: np.ndarray | None,
    substeps: int,
    blocks: PersonBlocks | None = None,
) -> ILQRResult | None:
    """Optimise from the first initial control sequence that does not diverge."""
    for u0 in inits:
        try:
            return optimise(m, d, cost, qpos0, qvel0, u0, cfg, active=active, t0=t0, warm0=warm, substeps=substeps, blocks=blocks)
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


def _committed_frames(start: int, horizon: int, n_frames: int, commit: int) -> int:
    """Frames kept from a window of ``horizon`` steps at ``start``: ``commit``, or the whole
    window when it reaches the last frame."""
    return horizon if start + horizon >= n_frames - 1 else min(commit, horizon)


def window_starts(n_frames: int, window: int, commit: int) -> list[int]:
    """First frame of every receding-horizon window over ``n_frames``, in order."""
    s, out = 0, []
    while s < n_frames - 1:
        out.append(s)
        s += _committed_frames(s, min(window, n_frames - 1 - s), n_frames, commit)
    return out


def _resume(sol: BoutSolution, resume: BoutResume, n_frames: int, cfg: SolverConfig) -> WindowRecord | None:
    """Fill ``sol`` with the kept windows of ``resume`` (frames, records, counts) and return
    the record of the window to re-plan first (None: every window is kept)."""
    starts = window_starts(n_frames, cfg.window, cfg.commit)
    k = resume.replan_from
    got = [w.start for w in resume.windows]
    if got != starts or not 1 <= k <= len(starts):
        raise ValueError(
            f"optimise_bout: resume windows start at {got} (re-plan from #{k}), not at this bout's window starts {starts}"
        )
    s = starts[k] if k < len(starts) else n_frames
    for name in ("qpos", "qvel", "ctrl", "actuator_force", "root_wrench"):
        getattr(sol, name)[:s] = getattr(resume, name)[:s]
    flags = resume.untrackable
    if flags is not None and np.shape(flags) != (n_frames,):
        raise ValueError(f"optimise_bout: resume untrackable flags of shape {np.shape(flags)}, expected ({n_frames},)")
    for i, w in enumerate(resume.windows[:k]):
        if flags is not None:
            end = starts[i + 1] if i + 1 < len(starts) else n_frames
            w = dataclasses.replace(w, untrackable=bool(flags[w.start : end].any()))
        sol.records.append(w)
        sol.windows += 1
        sol.windows_with_residual += int(w.residual)
        sol.untrackable_windows += int(w.untrackable)
        sol.iterations += w.iterations
        sol.resets += int(w.reset)
        sol.kinematic_frames += w.kinematic
        if w.kinematic == 0:
            sol.cost_first.append(w.cost_first)
            sol.cost_final.append(w.cost_final)
    sol.planned_from_window = k
    return resume.windows[k] if k < len(starts) else None


def count_windows(n_frames: int, window: int, commit: int) -> int:
    """Number of receding-horizon windows over ``n_frames`` (the last one is kept whole)."""
    return len(window_starts(n_frames, window, commit))


def optimise_bout(
    scene: Scene,
    ref: Reference,
    targets: np.ndarray,
    weight: np.ndarray,
    cfg: SolverConfig,
    residual: ResidualConfig = ResidualConfig(),
    progress: Callable[[int, int, str], None] | None = None,
    resume: BoutResume | None = None,
) -> BoutSolution:
    """Receding-horizon iLQR: windows of ``cfg.window`` steps, the first
    ``cfg.commit`` of which are kept; the next window starts from the simulated
    state, so the whole output is one continuous simulation. Cost is linear in the
    number of frames. The residual root wrench is used as ``residual.mode`` says (the
    scene must have its actuators, ``build_scene(residual=...)``, unless it is off).
    In modes ``off`` and ``fallback`` every window is first tracked without it, and one
    that diverges or misses the sites by more than ``residual.fallback_tol_m`` on average
    is flagged (``WindowRecord.untrackable``, ``BoutSolution.untrackable_windows``):
    ``fallback`` redoes it with the residual, ``off`` keeps it as it is.

    ``resume``: start at a window of a previous solution of the same scene, from its stored
    state, warm start and carried controls, and copy the frames before it; with the same
    reference up to there the result is the one a run from frame 0 gives (every window
    starts from its state alone: ``ilqr.rollout`` resets the data). ``ValueError`` when its
    start is not a window start of this bout."""
    m, lay = scene.model, scene.layout
    d = mujoco.MjData(m)
    F = ref.qpos.shape[0]
    # The collision term sees every pair of the athletes' geoms, also the arm-arm pairs
    # the simulation leaves out: the optimiser keeps arms apart softly, through the cost.
    cost = TrackingCost(m, lay, ref, cfg.weights, probe=scene.collision_probe())
    blocks = person_blocks(scene)
    sol = BoutSolution(
        qpos=np.zeros((F, m.nq)), qvel=np.zeros((F, m.nv)), ctrl=np.zeros((F, m.nu)), actuator_force=np.zeros((F, m.nu)),
        root_wrench=np.zeros((F, len(lay.persons), 6)),
        seconds={"derivatives_fd": 0.0, "derivatives_cost": 0.0, "backward": 0.0, "rollouts": 0.0},
    )
    qpos0 = lift_off_floor(scene, separate_persons(scene, ref.qpos[0], absent=absent_persons(weight, 0, 1)))
    qvel0 = ref.qvel[0].copy()
    warm = None
    # A person absent from the committed frames of a window is simulated as a stand-in that
    # touches no athlete in view, in the simulation and in the collision cost (``absent``).
    switch = AbsentContacts(m, lay.geom_person)
    carry = np.zeros((0, m.nu))
    servo = lay.servo_ids
    resid = lay.residual_ids
    res_bit = 1 << RESIDUAL_GROUP
    base_disable = int(m.opt.disableactuator)
    s = 0
    n_windows = count_windows(F, cfg.window, cfg.commit)
    sol.qpos[0], sol.qvel[0] = qpos0, qvel0
    if resume is not None:
        first = _resume(sol, resume, F, cfg)
        if first is None:
            s = F - 1  # every window kept
        else:
            s, qpos0, qvel0, warm, carry = first.start, first.qpos.copy(), first.qvel.copy(), first.warm.copy(), first.carry.copy()

    bw = np.array([p.mass_kg * 9.81 for p in lay.persons])

    def active(with_residual: bool) -> np.ndarray:
        # The residual servos' targets are optimised too when they act: the optimiser can
        # then move a root away from the other athlete instead of the residual pinning it
        # to a reference that overlaps him.
        return np.concatenate([servo, resid]) if with_residual else servo

    def set_residual(on: bool) -> None:
        m.opt.disableactuator = (base_disable & ~res_bit) if on else (base_disable | res_bit)
        cost.set_residual(on, residual.torque_frac * bw * 0.3, residual.rot_saturation_rad)
        if not on:
            d.xfrc_applied[:] = 0.0

    def spend(r: ILQRResult) -> None:
        """Count a plan's optimisation time and iterations in the bout's totals."""
        for k_, v_ in r.seconds.items():
            sol.seconds[k_] += v_
        sol.iterations += r.iterations

    try:
        while s < F - 1:
            H = min(cfg.window, F - 1 - s)
            absent = absent_persons(weight, s, s + _committed_frames(s, H, F, cfg.commit) + 1)
            switch.apply(absent)
            cost.set_absent(absent)
            start = WindowRecord(s, qpos0.copy(), qvel0.copy(), np.zeros(m.nv) if warm is None else warm.copy(), carry.copy())
            it0, resets0 = sol.iterations, sol.resets
            u0 = ref.ctrl[s : s + H].copy()
            nc = min(carry.shape[0], H)
            both = np.concatenate([servo, resid])
            u0[:nc, both] = carry[:nc, both]
            use_res = residual.mode == "always" and resid.size > 0
            # Modes off and fallback first track without the residual; what fails is flagged.
            checked = residual.mode != "always"
            set_residual(use_res)
            res_or_none = _first_stable(m, d, cost, qpos0, qvel0, [u0, ref.ctrl[s : s + H]], cfg.ilqr, active(use_res), s, warm, scene.substeps, blocks)
            untrackable = checked and res_or_none is None  # diverged: redone with the residual or reset
            if res_or_none is None and residual.mode != "off" and resid.size and not use_res:
                use_res = True
                set_residual(True)
                res_or_none = _first_stable(m, d, cost, qpos0, qvel0, [u0, ref.ctrl[s : s + H]], cfg.ilqr, active(True), s, warm, scene.substeps, blocks)
            if res_or_none is None:
                # Last resort: restart this window from the reference state.
                log.warning("physics: window at frame %d diverges from the simulated state; reset to the reference", s)
                sol.resets += 1
                qpos0 = lift_off_floor(scene, separate_persons(scene, ref.qpos[s], absent=absent))
                qvel0, warm = ref.qvel[s].copy(), None
                res_or_none = _first_stable(m, d, cost, qpos0, qvel0, [ref.ctrl[s : s + H]], cfg.ilqr, active(use_res), s, warm, scene.substeps, blocks)
                if res_or_none is None:
                    # Keep the job alive: these frames hold the reference, reported as such.
                    C = _committed_frames(s, H, F, cfg.commit)
                    log.warning(
                        "physics: the simulation diverges at frame %d even from the reference state; "
                        "frames %d-%d keep the reference motion (stats: kinematic_frames)", s, s + 1, s + C
                    )
                    for t in range(1, C + 1):
                        sol.qpos[s + t] = lift_off_floor(scene, separate_persons(scene, ref.qpos[s + t], absent=absent))
                    sol.qvel[s + 1 : s + C + 1] = ref.qvel[s + 1 : s + C + 1]
                    sol.ctrl[s : s + C] = ref.ctrl[s : s + C]
                    sol.kinematic_frames += C
                    sol.untrackable_windows += int(checked)
                    sol.records.append(dataclasses.replace(
                        start, residual=use_res, iterations=sol.iterations - it0, reset=True, kinematic=C, untrackable=checked,
                    ))
                    qpos0, qvel0, warm = sol.qpos[s + C].copy(), sol.qvel[s + C].copy(), None
                    carry = np.zeros((0, m.nu))
                    s += C
                    sol.windows += 1
                    if progress is not None:
                        progress(sol.windows, n_windows, f"window {sol.windows}/{n_windows}: diverged, kept the reference")
                    continue
            res = res_or_none
            if checked and not untrackable:
                err = _mean_site_error(scene, res.traj.qpos, targets[s : s + H + 1], weight[s : s + H + 1])
                untrackable = err > residual.fallback_tol_m
                if untrackable and residual.mode == "fallback" and resid.size:
                    set_residual(True)
                    res2 = _first_stable(m, d, cost, qpos0, qvel0, [res.traj.ctrl], cfg.ilqr, active(True), s, warm, scene.substeps, blocks)
                    if res2 is not None and res2.traj.total < res.traj.total:
                        spend(res)
                        res, use_res = res2, True
                    else:
                        if res2 is not None:
                            spend(res2)
                        set_residual(False)
            if cfg.exact_retry_tol_m > 0 and cfg.ilqr.fd_interval_s > 0:
                err = _mean_site_error(scene, res.traj.qpos, targets[s : s + H + 1], weight[s : s + H + 1])
                off_at_start = _mean_site_error(scene, qpos0[None], targets[s : s + 1], weight[s : s + 1])
                if err > cfg.exact_retry_tol_m and off_at_start <= cfg.exact_retry_max_start_m:
                    sol.exact_retry_windows += 1
                    exact = dataclasses.replace(cfg.ilqr, fd_interval_s=0.0)
                    res2 = _first_stable(m, d, cost, qpos0, qvel0, [u0, ref.ctrl[s : s + H]], exact, active(use_res), s, warm, scene.substeps, blocks)
                    if res2 is not None:
                        kept, dropped = (res2, res) if res2.traj.total < res.traj.total else (res, res2)
                        spend(dropped)
                        res = kept
            spend(res)
            sol.windows += 1
            sol.windows_with_residual += int(use_res)
            sol.untrackable_windows += int(untrackable)
            sol.cost_first.append(res.cost_history[0])
            sol.cost_final.append(res.cost_history[-1])
            sol.records.append(dataclasses.replace(
                start, residual=use_res, iterations=sol.iterations - it0, reset=sol.resets > resets0,
                cost_first=float(res.cost_history[0]), cost_final=float(res.cost_history[-1]), untrackable=untrackable,
            ))
            C = _committed_frames(s, H, F, cfg.commit)
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
        switch.restore()
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


def deepest_inter_person_mm(
    contacts: FrameContacts, n_frames: int, observed: np.ndarray | None = None, person_ids: np.ndarray | None = None
) -> np.ndarray:
    """(n_frames,) deepest overlap in mm between bodies of different persons in each
    frame (0 where they do not overlap; ground contacts are ignored). With ``observed``
    (frames, persons) bool, columns in ``person_ids`` order, only contacts between two persons
    observed in that frame count (an absent person is still simulated, not output)."""
    inter = (contacts.person[:, 0] >= 0) & (contacts.person[:, 1] >= 0)
    if observed is not None and person_ids is not None:
        col = {int(p): i for i, p in enumerate(np.asarray(person_ids).tolist())}
        a = np.array([col.get(int(p), -1) for p in contacts.person[:, 0]], dtype=np.int64)
        b = np.array([col.get(int(p), -1) for p in contacts.person[:, 1]], dtype=np.int64)
        seen = np.zeros(len(a), dtype=bool)
        ok = inter & (a >= 0) & (b >= 0)
        seen[ok] = observed[contacts.frame[ok], a[ok]] & observed[contacts.frame[ok], b[ok]]
        inter = inter & seen
    out = np.zeros(n_frames)
    np.maximum.at(out, contacts.frame[inter], 1000.0 * contacts.depth_m[inter])
    return out


def contacts_and_sites(scene: Scene, qpos: np.ndarray, qvel: np.ndarray) -> tuple[FrameContacts, np.ndarray]:
    """Contacts of every frame (inter-person and ground) and the site positions
    (frames, persons, sites, 3). Contacts come from ``scene.probe_model()``: every pair
    of the athletes' geoms, also those the simulation leaves out (arm-arm), so that
    overlap the simulation did not prevent is still reported."""
    m, lay = scene.probe_model(), scene.layout
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
