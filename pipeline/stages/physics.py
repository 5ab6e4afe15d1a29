"""Physics stage (paper §3.4): per-athlete MuJoCo humanoids + multi-person iLQR.

``run(inputs, cfg)`` builds one humanoid per person — from the fitted anny body
(``cfg.skeleton == "bodyfit"``: anny's main skeleton, convex-hull or capsule geoms cut
from the body mesh, see ``pipeline.backends.anny.humanoid``) or sized from the fitted
3D joints (``"keypoints"``: capsules from median bone lengths) — puts all
persons on one ground plane, computes a kinematic reference by inverse kinematics
and optimises servo targets with receding-horizon iLQR so that the simulated
motion tracks the joints while contacts (ground, other athlete) stay physical.

The reference is made contact-consistent before tracking: planted feet are held
still and flat on the floor, overlapping athletes are separated in order, frame by
frame (arms and spine move first; arm-arm overlap is only removed here, the
simulation leaves arm-arm contacts out: ``arm_contacts``), and the hands are boxing
gloves. Between video frames the servo targets move along the reference at every
substep, with inverse-dynamics feed-forward whose ground reactions sit on the planted
feet (``schedule``). The initial controls of every window are that schedule; the
iLQR optimises the servo targets and the residual root servos' targets. The residual
root wrench (feed-forward + PD, ≤ ``residual.force_frac`` body weights per axis) lets
the kinematic, not dynamically consistent motion be followed; its use is reported. With
``residual.mode`` ``off`` or ``fallback`` the windows that cannot be tracked without it
are flagged per frame (``PhysicsResult.untrackable``), counted in the stats
(``untrackable_windows``, ``untrackable_frames``) and summarised in one log warning.

mujoco is only imported inside ``run`` via ``pipeline.backends``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Literal

import numpy as np

from pipeline.backends.mujoco.config import (
    HumanoidConfig,
    ReferenceConfig,
    ResidualConfig,
    SolverConfig,
    nested_from_dicts,
)
from pipeline.schema.config_types import check_field_types
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit, PhysicsResult
from pipeline.stages.physics_incremental import (
    PhysicsCheckpoints,
    PhysicsPrevious,
    body_digest,
    checkpoints_of,
    first_beyond,
    first_changed,
    input_digests,
    layout_mismatch,
    reference_digests,
    reference_reach,
    reference_values,
    replan_window,
    skeletons_from_json,
)

if TYPE_CHECKING:
    from pipeline.backends.mujoco.ik_reuse import ReferenceIK
    from pipeline.backends.mujoco.reference import Scene
    from pipeline.backends.mujoco.skeleton import Skeleton
    from pipeline.backends.mujoco.tracking import Reference

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PhysicsConfig:
    """Settings of the physics stage: the stage's own, then one object per part, each
    defined once in ``pipeline.backends.mujoco.config`` and taken as is by the backends.

    In ``session.json``: ``{"physics": {"mode": "single", "solver": {"weights": {"w_pos": 50}}}}``.
    """

    mode: Literal["multi", "single"] = "multi"
    """``multi``: all persons in one simulation (inter-person contacts); ``single``: each
    person optimised alone (the paper's ablation)."""
    skeleton: Literal["bodyfit", "keypoints"] = "bodyfit"
    """``bodyfit``: humanoids built from the anny ``BodyFit`` (falls back to ``keypoints``,
    with a log message, when the fit is missing or not anny); ``keypoints``: capsule
    humanoids sized from the fitted joints' bone lengths (~3x faster)."""
    geometry: Literal["capsule", "mesh"] = "mesh"
    """Collision geometry of the ``bodyfit`` humanoid: convex hulls of the body mesh segmented
    by skinning weights, or one capsule per part fitted to the same vertices."""
    glove_radius_m: float = 0.065
    """Boxing gloves on the ``bodyfit`` humanoids: each hand is a ball of this radius (m, >= 0)
    around the fist; 0: anny's open hand."""
    max_frames: int = 0
    """Process only the first N frames (>= 0; 0 = all)."""
    incremental: bool = True
    """Re-use the previous run (same config and code, same frames and persons): keep its
    humanoids and every window whose reference frames did not change, re-plan the rest
    (``pipeline.stages.physics_incremental``); False: always run in full."""
    incremental_tol_m: float = 0.0005
    """An incremental re-run treats a frame as unchanged when no reference length (tracked
    site, root position) moved by more than this (m, >= 0; 0: equal in float32) and the
    velocities by more than this per frame (``physics_incremental.reference_values``)."""
    incremental_tol_rad: float = 0.005
    """The same for the reference's angles (joint angles, quaternion components, servo
    targets; rad, >= 0)."""
    humanoid: HumanoidConfig = field(default_factory=HumanoidConfig)
    """The simulated bodies and the scene (servos, contacts, floor, MuJoCo steps per frame)."""
    residual: ResidualConfig = field(default_factory=ResidualConfig)
    """The residual root wrench: when it is used (``mode``) and its limits."""
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)
    """The kinematic reference: separation, flat feet, inverse kinematics, feed-forward."""
    solver: SolverConfig = field(default_factory=SolverConfig)
    """The receding-horizon iLQR (``window``, ``commit``, ``ilqr``, ``weights``)."""

    MOVED: ClassVar[dict[str, str]] = {
        **{k: f"humanoid.{k}" for k in ("armature", "body_friction", "floor_friction", "floor_margin_m", "floor_solref",
                                          "floor_solimp", "substeps", "self_collision", "arm_contacts", "foot_contacts")},
        "servo_kp_per_kg": "humanoid.kp_per_kg", "servo_torque_per_kg": "humanoid.torque_per_kg",
        "body_solref_s": "humanoid.body_solref_s", "residual_root": "residual.mode",
        "residual_force_frac": "residual.force_frac (and residual.torque_frac)", "residual_saturation_m": "residual.saturation_m",
        "fallback_tol_m": "residual.fallback_tol_m", "separate_reference": "reference.separate",
        **{k: f"reference.{k}" for k in ("separation_clearance_m", "flat_feet", "calibrate_foot_sites", "ik_posture_weight",
                                           "schedule", "feedforward_friction", "feedforward_smooth_frames")},
        "window": "solver.window", "commit": "solver.commit",
        **{k: f"solver.ilqr.{k}" for k in ("max_iter", "deriv_every", "n_alpha", "alpha_min", "fd_centered", "jacobian_reuse", "threads")},
        **{k: f"solver.weights.{k}" for k in ("w_reg", "w_pos", "w_vel", "w_collision", "w_residual", "w_skate", "collision_clearance_m")},
    }  # fmt: skip
    """Flat keys of ``session.json`` before the settings were nested -> where they are now
    (``pipeline.schema.config_types.build_config`` names the new place in its error)."""

    def __post_init__(self) -> None:
        nested_from_dicts(self)
        check_field_types(self)  # values from Python callers; session.json goes through build_config
        if self.glove_radius_m < 0.0:
            raise ValueError(f"PhysicsConfig.glove_radius_m must be >= 0, got {self.glove_radius_m}")
        if self.max_frames < 0:
            raise ValueError(f"PhysicsConfig.max_frames must be >= 0, got {self.max_frames}")
        if self.incremental_tol_m < 0.0 or self.incremental_tol_rad < 0.0:
            raise ValueError(
                "PhysicsConfig.incremental_tol_m and incremental_tol_rad must be >= 0, got "
                f"{self.incremental_tol_m} and {self.incremental_tol_rad}"
            )


@dataclass(frozen=True)
class PhysicsInputs:
    """keypoints: the fitted joints (``source="fit"``, world z-up metres);
    bodyfit: the fitted body model (optional; its person ids must match);
    previous: the stage's previous run on earlier inputs, for an incremental re-run
    (``PhysicsConfig.incremental``; None: run in full)."""

    keypoints: Keypoints3D
    bodyfit: BodyFit | None = None
    previous: PhysicsPrevious | None = None


@dataclass(frozen=True)
class PhysicsOutput:
    result: PhysicsResult
    keypoints: Keypoints3D
    mjcf: str
    stats: dict[str, Any]
    checkpoints: PhysicsCheckpoints | None = None
    """What a later incremental re-run needs (None for ``mode="single"``)."""


def _select_persons(kp: Keypoints3D) -> list[int]:
    rows = [i for i in range(kp.n_persons) if kp.valid[:, i].any(axis=-1).sum() >= 2]
    if not rows:
        raise ValueError("physics: no person has at least 2 frames of valid joints")
    return rows


def skeleton_source(kp: Keypoints3D, rows: list[int], bodyfit: BodyFit | None, cfg: PhysicsConfig) -> str:
    """Why the humanoids of these rows cannot be built from ``bodyfit`` ("" when they
    are; see ``PhysicsConfig.skeleton``)."""
    pids = [int(kp.person_ids[r]) for r in rows]
    why = ""
    if cfg.skeleton != "bodyfit":
        why = f"skeleton={cfg.skeleton!r}"
    elif bodyfit is None:
        why = "no BodyFit given"
    elif bodyfit.body_model != "anny":
        why = f"BodyFit body_model is {bodyfit.body_model!r}, not 'anny'"
    else:
        fit_ids = [int(i) for i in bodyfit.person_ids]
        lacking = [p for p in pids if p not in fit_ids or not bodyfit.valid[:, fit_ids.index(p)].any()]
        if lacking:
            why = f"BodyFit has no valid fit of persons {lacking}"
    return why


def build_skeletons(
    kp: Keypoints3D, rows: list[int], bodyfit: BodyFit | None, cfg: PhysicsConfig
) -> tuple[list[Skeleton], str]:
    """One rest skeleton per keypoint person row, and which builder was used
    (``"bodyfit"`` or ``"keypoints"``; see ``PhysicsConfig.skeleton``)."""
    from pipeline.backends.mujoco.skeleton import skeleton_from_keypoints

    pids = [int(kp.person_ids[r]) for r in rows]
    why = skeleton_source(kp, rows, bodyfit, cfg)
    if not why:
        from pipeline.backends.anny.humanoid import skeleton_from_bodyfit

        assert bodyfit is not None
        fit_ids = [int(i) for i in bodyfit.person_ids]
        skels = [
            skeleton_from_bodyfit(bodyfit, fit_ids.index(p), keypoints=kp, geometry=cfg.geometry, glove_radius_m=cfg.glove_radius_m)
            for p in pids
        ]
        log.info("physics: humanoids from the anny BodyFit (%s geometry)", cfg.geometry)
        return skels, "bodyfit"
    if cfg.geometry == "mesh":
        log.info("physics: mesh geometry needs the BodyFit skeleton; using capsules")
    log.info("physics: humanoids sized from the keypoints (%s)", why)
    return [skeleton_from_keypoints(kp, r) for r in rows], "keypoints"


def posed_humanoids(
    kp: Keypoints3D,
    bodyfit: BodyFit | None = None,
    cfg: PhysicsConfig = PhysicsConfig(),
    person_ids: list[int] | None = None,
    body_keypoints: Keypoints3D | None = None,
    min_persons: int = 1,
    what: str = "posed_humanoids",
) -> tuple[Scene, np.ndarray]:
    """The humanoids this stage builds (from ``bodyfit``, with ``cfg``'s geometry, sized
    from ``body_keypoints``, default ``kp``), posed by inverse kinematics onto ``kp``'s
    joints: no separation, no floor lift, no simulation. Returns ``(scene, qpos)``.

    ``person_ids`` restricts the persons (default: all with motion). Raises
    ``ValueError`` (prefixed with ``what``) when fewer than ``min_persons`` remain or
    one of them is not in ``body_keypoints``."""
    from pipeline.backends.mujoco import physics as mp

    rows = _select_persons(kp)
    moving = [int(kp.person_ids[r]) for r in rows]
    if person_ids is not None:
        rows = [r for r in rows if int(kp.person_ids[r]) in {int(p) for p in person_ids}]
    if len(rows) < min_persons:
        need = "two persons" if min_persons == 2 else f"{min_persons} person(s)"
        asked = f" of the requested {sorted(int(p) for p in person_ids)}" if person_ids is not None else ""
        raise ValueError(f"{what} needs {need} with motion, got {len(rows)}{asked} (persons with motion: {moving})")
    pids = [int(kp.person_ids[r]) for r in rows]
    bkp = kp if body_keypoints is None else body_keypoints
    bids = [int(i) for i in bkp.person_ids]
    lacking = [p for p in pids if p not in bids]
    if lacking:
        raise ValueError(f"{what}: persons {lacking} are not in body_keypoints (ids {bids})")
    skels, _ = build_skeletons(bkp, [bids.index(p) for p in pids], bodyfit, cfg)
    scene = mp.build_scene(skels, pids, kp.fps, kp.joint_names, cfg.humanoid, residual_actuators(cfg))
    targets, weight = mp.site_targets(scene, kp, rows)
    return scene, mp.inverse_kinematics(scene, targets, weight)


def body_penetration_mm(
    kp: Keypoints3D,
    bodyfit: BodyFit | None = None,
    cfg: PhysicsConfig = PhysicsConfig(),
    person_ids: list[int] | None = None,
    body_keypoints: Keypoints3D | None = None,
) -> np.ndarray:
    """(frames,) deepest overlap in mm between two athletes' *own bodies*: the humanoids
    this stage builds (from ``bodyfit``, with ``cfg``'s geometry), each posed by inverse
    kinematics onto ``kp``'s joints; no separation, no floor lift, no simulation.

    ``pipeline.evaluate.physics_metrics`` measures penetration on fixed capsules around
    the keypoints, which need not match a real athlete's volume; this measure uses
    the body the physics stage collides. The humanoids are built as the stage builds
    them from ``body_keypoints`` (default ``kp``; pass the physics input to score
    another motion, e.g. ground truth, in the same bodies). ``person_ids`` restricts
    the persons (default: all with motion).
    Raises ``ValueError`` when fewer than two persons remain or one of them is not in
    ``body_keypoints``.
    """
    scene, qpos = posed_humanoids(kp, bodyfit, cfg, person_ids, body_keypoints, 2, "body_penetration_mm")
    return penetration_of_pose(scene, qpos)


def penetration_of_pose(scene: Scene, qpos: np.ndarray) -> np.ndarray:
    """(frames,) deepest overlap in mm between persons of ``scene`` posed at ``qpos``
    (frames, nq), e.g. from ``posed_humanoids``."""
    from pipeline.backends.mujoco import physics as mp

    contacts, _ = mp.contacts_and_sites(scene, qpos, np.zeros((qpos.shape[0], scene.model.nv)))
    return mp.deepest_inter_person_mm(contacts, qpos.shape[0])


def floor_timeconst_warning(cfg: PhysicsConfig, fps: float) -> str | None:
    """A message when ``cfg.humanoid.floor_solref``'s time constant is below two MuJoCo steps at
    ``fps`` (MuJoCo then silently uses two steps: a softer floor than configured), else
    None."""
    tc = float(cfg.humanoid.floor_solref[0])
    dt = 1.0 / (fps * cfg.humanoid.substeps)
    if tc <= 0.0 or tc >= 2.0 * dt - 1e-12:
        return None
    need = int(np.ceil(2.0 / (fps * tc) - 1e-9))
    return (
        f"physics: floor_solref time constant {tc:g} s is below two steps ({2.0 * dt:.4g} s at "
        f"{fps:g} fps with humanoid.substeps={cfg.humanoid.substeps}); MuJoCo uses {2.0 * dt:.4g} s, a softer floor. "
        f"Use substeps >= {need} or a larger time constant."
    )


def residual_actuators(cfg: PhysicsConfig) -> ResidualConfig | None:
    """The residual root actuators the scene needs: none when the residual is off."""
    return None if cfg.residual.mode == "off" else cfg.residual


def sole_lift_m(cfg: PhysicsConfig) -> float:
    """Height (m, >= 0) of a planted sole above the floor in the reference: 1 mm inside the
    floor's contact margin."""
    return max(cfg.humanoid.floor_margin_m - 0.001, 0.0)


def stage_reference(
    scene: Scene, kp: Keypoints3D, rows: list[int], cfg: PhysicsConfig, sole_m: np.ndarray, stored_ik: ReferenceIK | None = None
) -> tuple[Reference, np.ndarray, np.ndarray, ReferenceIK]:
    """The kinematic reference this stage tracks for keypoint rows ``rows`` in ``scene``
    (``reference.reference_and_ik`` with ``cfg``'s settings; ``sole_m`` (persons,) m):
    (reference, targets, weight, inverse kinematics). ``stored_ik``: an earlier run's IK to
    reuse where its inputs are unchanged (``pipeline.backends.mujoco.ik_reuse``)."""
    from pipeline.backends.mujoco.reference import reference_and_ik

    rcfg = cfg.reference
    return reference_and_ik(
        scene, kp, rows, separate=rcfg.separate, substeps=cfg.humanoid.substeps if rcfg.schedule else 0,
        flat_feet=rcfg.flat_feet, sole_lift_m=sole_lift_m(cfg), ff_friction=rcfg.feedforward_friction,
        ff_smooth_frames=rcfg.feedforward_smooth_frames, separation_clearance_m=rcfg.separation_clearance_m,
        posture_weight=rcfg.ik_posture_weight, sole_m=sole_m, balance=rcfg, stored_ik=stored_ik,
    )  # fmt: skip


def run(
    inputs: PhysicsInputs,
    cfg: PhysicsConfig = PhysicsConfig(),
    progress: Callable[[int, int, str], None] | None = None,
) -> PhysicsOutput:
    """Simulate all persons of ``inputs.keypoints``; see the module docstring.

    Raises ``ValueError`` when no person has enough valid joints or the joint set
    lacks the COCO-17 joints.

    BLAS runs on one thread meanwhile, so the result does not depend on the machine's
    core count. The iLQR is chaotic, and OpenBLAS sums a matrix product's parts in
    another order on 2 threads than on 1: bench bout 2 (multi-person) ended with its
    deepest capsule overlap at 25.6 mm with ``OMP_NUM_THREADS=2`` and 6.3 mm with 1; it
    is 6.3 either way with the pin, at the same backward-pass time (the matrices are
    ≈ 250 × 250). The limit is the BLAS library's own, process-wide setting; the job
    worker runs each job in its own process.
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return _run(inputs, cfg, progress)


def _run(
    inputs: PhysicsInputs,
    cfg: PhysicsConfig,
    progress: Callable[[int, int, str], None] | None,
) -> PhysicsOutput:
    from pipeline.backends.mujoco import physics as mp

    kp = inputs.keypoints
    if cfg.max_frames and kp.n_frames > cfg.max_frames:
        sl = slice(0, cfg.max_frames)
        kp = kp.replace(
            frame_indices=kp.frame_indices[sl], xyz_m=kp.xyz_m[sl], valid=kp.valid[sl], confidence=kp.confidence[sl],
            n_views=kp.n_views[sl], reproj_err_px=kp.reproj_err_px[sl],
        )
    t_start = time.perf_counter()
    if (msg := floor_timeconst_warning(cfg, kp.fps)) is not None:
        log.warning(msg)
    rows = _select_persons(kp)
    pids = [int(kp.person_ids[r]) for r in rows]
    in_digest = input_digests(kp, inputs.bodyfit)
    reach = reference_reach(cfg.reference.schedule and cfg.humanoid.substeps > 0, cfg.reference.feedforward_smooth_frames)
    prev, why = _previous_or_why(inputs, kp, pids, cfg, in_digest, reach)
    skeleton_kind = "keypoints" if skeleton_source(kp, rows, inputs.bodyfit, cfg) else "bodyfit"
    body = body_digest(skeleton_kind, pids, inputs.bodyfit)
    hcfg, rcfg, res_act = cfg.humanoid, cfg.reference, residual_actuators(cfg)
    sole_lift = sole_lift_m(cfg)
    foot_offsets_mm = 0.0
    scene = None
    if prev is not None and prev.checkpoints.body_digest != body:
        prev, why = None, "the humanoids' body fit shapes changed"
    if prev is not None:  # the previous humanoids, kept (``physics_incremental``)
        skels = skeletons_from_json(prev.checkpoints.skeletons_json)
        foot_offsets_mm = prev.checkpoints.foot_site_offset_mm_mean
        scene = mp.build_scene(skels, pids, kp.fps, kp.joint_names, hcfg, res_act)
        if scene.mjcf != prev.mjcf:
            prev, scene, why = None, None, "the rebuilt humanoids differ from the stored scene"
    sole = prev.checkpoints.sole_m if prev is not None else mp.sole_heights_m(kp, rows)
    if scene is None:
        skels, skeleton_kind = build_skeletons(kp, rows, inputs.bodyfit, cfg)
    if scene is None and rcfg.flat_feet and rcfg.calibrate_foot_sites:
        from pipeline.backends.mujoco.foot_sites import move_sites, planted_site_offsets

        offs = planted_site_offsets(mp.build_scene(skels, pids, kp.fps, kp.joint_names, hcfg, res_act), kp, rows, sole_lift_m=sole_lift)
        skels = [move_sites(sk, o) for sk, o in zip(skels, offs, strict=True)]
        moved = [float(np.linalg.norm(v)) for o in offs for v in o.values()]
        foot_offsets_mm = 1000.0 * float(np.mean(moved)) if moved else 0.0
        log.info("physics: foot sites moved onto the planted keypoints by %.1f mm on average (%d sites)", foot_offsets_mm, len(moved))
    if scene is None:
        scene = mp.build_scene(skels, pids, kp.fps, kp.joint_names, hcfg, res_act)
    groups = [list(range(len(rows)))] if cfg.mode == "multi" else [[i] for i in range(len(rows))]
    F = kp.n_frames
    qpos = np.zeros((F, scene.model.nq))
    qvel = np.zeros((F, scene.model.nv))
    ctrl = np.zeros((F, scene.model.nu))
    force = np.zeros((F, scene.model.nu))
    resid = np.zeros((F, len(rows), 6))
    untrackable = np.zeros((F, len(rows)), dtype=bool)
    agg: dict[str, float] = {"windows": 0, "windows_with_residual": 0, "untrackable_windows": 0, "iterations": 0, "resets": 0, "kinematic_frames": 0, "exact_retry_windows": 0}
    untrackable_starts: list[tuple[int, int]] = []
    secs: dict[str, float] = {}
    done = [0]
    ref_digest = np.zeros(0, dtype=np.uint64)
    ref_vals: tuple[np.ndarray, np.ndarray] | None = None
    first_ref_change, first_ref_change_exact, reused_frames, bout = -1, -1, 0, None
    ik: ReferenceIK | None = None
    ik_note = "solved every frame (full run)" if prev is None else ""
    for g in groups:
        sub = scene if len(g) == len(rows) else mp.build_scene([skels[i] for i in g], [pids[i] for i in g], kp.fps, kp.joint_names, hcfg, res_act)
        stored_ik = prev.checkpoints.stored_ik() if prev is not None and len(g) == len(rows) else None
        ref, targets, weight, g_ik = stage_reference(sub, kp, [rows[i] for i in g], cfg, sole[g], stored_ik)
        if len(g) == len(rows):
            ik = g_ik
            if prev is not None:
                ik_note = _ik_note(g_ik, stored_ik is not None)
                log.info("physics: inverse kinematics %s", ik_note)

        def prog(d: int, n: int, msg: str, _g: list[int] = g) -> None:
            if progress is not None:
                progress(done[0] + d, n * len(groups), f"persons {[pids[i] for i in _g]}: {msg}")

        resume = None
        if len(g) == len(rows):
            ref_digest = reference_digests(ref, targets, weight)
            ref_vals = _reference_values(scene, ref, targets, weight, kp.fps, cfg)
        if prev is not None:
            first_ref_change_exact = first_changed(prev.checkpoints.reference_digest, ref_digest)
            first_ref_change, why = _first_reference_change(prev.checkpoints, ref_vals)
            if first_ref_change >= 0:
                resume, why = _resume_from(prev, first_ref_change, F, cfg)
        sol = mp.optimise_bout(sub, ref, targets, weight, cfg.solver, cfg.residual, prog, resume=resume)
        if resume is not None:
            starts = mp.window_starts(F, cfg.solver.window, cfg.solver.commit)
            reused_frames = starts[resume.replan_from] if resume.replan_from < len(starts) else F
        if len(g) == len(rows):
            bout = sol
        done[0] += sol.windows
        for i_sub, i in enumerate(g):
            ps, pf = sub.layout.persons[i_sub], scene.layout.persons[i]
            qpos[:, pf.qpos_adr : pf.qpos_adr + pf.nq] = sol.qpos[:, ps.qpos_adr : ps.qpos_adr + ps.nq]
            qvel[:, pf.qvel_adr : pf.qvel_adr + pf.nv] = sol.qvel[:, ps.qvel_adr : ps.qvel_adr + ps.nv]
            src = np.concatenate([ps.servo_ids, ps.residual_ids])
            dst = np.concatenate([pf.servo_ids, pf.residual_ids])
            ctrl[:, dst] = sol.ctrl[:, src]
            force[:, dst] = sol.actuator_force[:, src]
            resid[:, i] = sol.root_wrench[:, i_sub]
        per_frame = mp.untrackable_frames(sol.records, F)
        untrackable[:, g] |= per_frame[:, None]
        untrackable_starts += _runs(per_frame)
        agg["windows"] += sol.windows
        agg["windows_with_residual"] += sol.windows_with_residual
        agg["untrackable_windows"] += sol.untrackable_windows
        agg["iterations"] += sol.iterations
        agg["resets"] += sol.resets
        agg["kinematic_frames"] += sol.kinematic_frames
        agg["exact_retry_windows"] += sol.exact_retry_windows
        for k, v in sol.seconds.items():
            secs[k] = secs.get(k, 0.0) + v
    contacts, sites = mp.contacts_and_sites(scene, qpos, qvel)
    lay = scene.layout
    # A person absent from the input (no valid joint: not yet in view, or gone) is still
    # simulated, untracked; those samples are neither output nor counted in the stats.
    observed = np.asarray(kp.valid[:, rows].any(axis=-1), dtype=bool)
    result = PhysicsResult(
        person_ids=np.asarray(pids, dtype=np.int64),
        frame_indices=kp.frame_indices.astype(np.int64),
        fps=float(kp.fps),
        qpos=qpos,
        qvel=qvel,
        ctrl=ctrl,
        joint_torque_nm=force,
        residual_root_force=resid,
        actuation="pd",
        contact_frame=contacts.frame,
        contact_person=contacts.person,
        contact_body=contacts.body,
        contact_depth_m=contacts.depth_m,
        body_names=contacts.body_names,
        untrackable=untrackable,
        observed=observed,
    )
    names = scene.site_names
    out_kp = Keypoints3D.empty(names, np.asarray(pids), kp.frame_indices, kp.fps, "physics")
    seen = np.broadcast_to(observed[..., None], sites.shape[:3])
    out_kp = out_kp.replace(xyz_m=sites, valid=seen.copy(), confidence=seen.astype(float))
    first_input_change = -1
    if inputs.previous is not None and inputs.previous.checkpoints.input_digest.shape == in_digest.shape:
        first_input_change = first_changed(inputs.previous.checkpoints.input_digest, in_digest)
    checkpoints = None
    if bout is not None:
        checkpoints = checkpoints_of(kp, pids, in_digest, ref_digest, body, skels, sole, bout, foot_offsets_mm, ref_vals, ik)
    compute_s = time.perf_counter() - t_start
    motion_s = max(F - 1, 1) / kp.fps
    body_pen = mp.deepest_inter_person_mm(contacts, F, observed, np.asarray(pids))  # absent persons left out
    weight_n = np.array([p.mass_kg * 9.81 for p in lay.persons])
    resid_bw = np.linalg.norm(resid[..., :3], axis=-1) / weight_n[None]
    n_bad, bad_frames = int(agg["untrackable_windows"]), int(untrackable.any(axis=1).sum())
    if n_bad:
        log.warning(untrackable_message(cfg.residual.mode, n_bad, int(agg["windows"]), untrackable_starts, kp.frame_indices))
    stats: dict[str, Any] = {
        "mode": cfg.mode,
        "skeleton": skeleton_kind,
        "geometry": cfg.geometry if skeleton_kind == "bodyfit" else "capsule",
        "frames": F,
        "persons": len(rows),
        "nq": int(scene.model.nq),
        "nv": int(scene.model.nv),
        "nu": int(scene.model.nu),
        "mass_kg": [round(p.mass_kg, 2) for p in lay.persons],
        "foot_site_offset_mm_mean": round(foot_offsets_mm, 2),
        "windows": int(agg["windows"]),
        "windows_with_residual": int(agg["windows_with_residual"]),
        "residual_mode": cfg.residual.mode,
        "untrackable_windows": n_bad,
        "untrackable_windows_pct": 100.0 * n_bad / max(int(agg["windows"]), 1),
        "untrackable_frames": bad_frames,
        "untrackable_frames_pct": 100.0 * bad_frames / max(F, 1),
        "exact_retry_windows": int(agg["exact_retry_windows"]),
        "iterations": int(agg["iterations"]),
        "resets": int(agg["resets"]),
        "kinematic_frames": int(agg["kinematic_frames"]),
        "residual_force_mean_frac_bw": float(np.mean(resid_bw[observed])) if observed.any() else 0.0,
        "residual_force_max_frac_bw": float(np.max(resid_bw[observed], initial=0.0)),
        "observed_pct": 100.0 * float(observed.mean()) if observed.size else 0.0,
        "body_penetration_max_mm": float(body_pen.max(initial=0.0)),
        "body_penetration_mean_mm": float(body_pen.mean()) if body_pen.size else 0.0,
        "incremental": f"reused frames 0-{reused_frames - 1}" if reused_frames else f"full run: {why}",
        "reused_frames": int(reused_frames),
        "replanned_from_frame": int(reused_frames) if reused_frames < F else -1,
        "replanned_windows": int(agg["windows"]) - (bout.planned_from_window if bout is not None else 0),
        "ik_reused_frames": int(ik.reused_frames) if ik is not None else 0,
        "ik_incremental": ik_note,
        "first_changed_input_frame": first_input_change,
        "first_changed_reference_frame": first_ref_change,
        "first_changed_reference_frame_exact": first_ref_change_exact,
        "compute_s": compute_s,
        "realtime_factor": compute_s / motion_s,
        **{f"seconds_{k}": v for k, v in secs.items()},
    }
    return PhysicsOutput(result=result, keypoints=out_kp, mjcf=scene.mjcf, stats=stats, checkpoints=checkpoints)


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """Inclusive (first, last) rows of each run of True in ``flags`` (frames,)."""
    d = np.diff(np.r_[0, flags.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1).tolist(), (np.flatnonzero(d == -1) - 1).tolist(), strict=True))


def untrackable_message(
    mode: str, n_bad: int, n_windows: int, runs: list[tuple[int, int]], frame_indices: np.ndarray, shown: int = 8
) -> str:
    """The run's one warning about windows that could not be tracked without the residual
    root force: how many, their video frames (``runs``: inclusive rows of
    ``frame_indices``; the first ``shown`` listed) and what residual ``mode`` did."""
    spans = sorted({(int(frame_indices[a]), int(frame_indices[b])) for a, b in runs})
    text = ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in spans[:shown])
    more = f", … ({len(spans) - shown} more)" if len(spans) > shown else ""
    what = (
        "retried with the residual (residual.mode=fallback; stats: windows_with_residual)" if mode == "fallback"
        else "kept without it (residual.mode=off; stats: untrackable_windows)"
    )
    return f"physics: {n_bad} of {n_windows} windows (frames {text}{more}) could not be tracked without a residual root force; {what}"


def _ik_note(ik: ReferenceIK, stored: bool) -> str:
    """What an incremental run did with the previous run's inverse kinematics (``ik``: the
    reference's; ``stored``: whether the previous checkpoints held one)."""
    F = int(ik.input_digest.shape[0])
    if not stored:
        return "solved every frame: the previous run stored no inverse kinematics (older checkpoints)"
    if ik.reused_frames == 0:
        return f"solved every frame: {ik.why}"
    if ik.reused_frames == F:
        return f"reused every frame (0-{F - 1})"
    return f"reused frames 0-{ik.reused_frames - 1}, solved from frame {ik.reused_frames}"


def _reference_values(
    scene: Scene, ref: Any, targets: np.ndarray, weight: np.ndarray, fps: float, cfg: PhysicsConfig
) -> tuple[np.ndarray, np.ndarray]:
    """``physics_incremental.reference_values`` of a multi-person reference, with the
    scene's units per column: lengths in qpos/qvel (free joints' translations, slide joints),
    joint servos in ctrl (the rest are residual root servos), each person's weight."""
    free, slide = 0, 2  # mujoco.mjtJoint.mjJNT_FREE, mjJNT_SLIDE (no mujoco import here)
    m = scene.model
    lin_q, lin_v = np.zeros(m.nq, dtype=bool), np.zeros(m.nv, dtype=bool)
    for j in range(m.njnt):
        qa, da = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
        if m.jnt_type[j] == free:
            lin_q[qa : qa + 3], lin_v[da : da + 3] = True, True
        elif m.jnt_type[j] == slide:
            lin_q[qa], lin_v[da] = True, True
    servo = np.zeros(m.nu, dtype=bool)
    for p in scene.layout.persons:
        servo[np.asarray(p.servo_ids, dtype=int)] = True
    weight_n = np.array([p.mass_kg * 9.81 for p in scene.layout.persons])
    return reference_values(
        ref, targets, weight, lin_q, lin_v, servo, weight_n, fps, cfg.incremental_tol_m, cfg.incremental_tol_rad
    )


def _first_reference_change(
    ck: PhysicsCheckpoints, new: tuple[np.ndarray, np.ndarray] | None
) -> tuple[int, str]:
    """First frame whose reference moved beyond the tolerances (``first_beyond`` with the
    current run's tolerances), or -1 and why the previous run cannot be compared."""
    if new is None:
        return -1, "mode is not 'multi'"
    if ck.reference_values is None:
        return -1, "the previous run stored no reference values (older checkpoints)"
    if ck.reference_values.shape != new[0].shape:
        return -1, f"the reference has another layout ({ck.reference_values.shape} -> {new[0].shape} values)"
    return first_beyond(ck.reference_values, new[0], new[1]), ""


def _previous_or_why(
    inputs: PhysicsInputs, kp: Keypoints3D, pids: list[int], cfg: PhysicsConfig, in_digest: np.ndarray, reach: int
) -> tuple[PhysicsPrevious | None, str]:
    """The previous run to reuse, or None and why not: also when the inputs changed so early
    that no window can be kept (a full run then re-estimates the humanoids too)."""
    if inputs.previous is None:
        return None, "no previous run given"
    if not cfg.incremental:
        return None, "incremental is off"
    why = layout_mismatch(inputs.previous, kp, pids, cfg.mode)
    if why:
        return None, why
    from pipeline.backends.mujoco.physics import window_starts

    first = first_changed(inputs.previous.checkpoints.input_digest, in_digest)
    F = kp.n_frames
    if first < F and replan_window(window_starts(F, cfg.solver.window, cfg.solver.commit), F, cfg.solver.window, first - reach) == 0:
        return None, f"the inputs changed from frame {first} on, inside the first window"
    return inputs.previous, ""


def _resume_from(prev: PhysicsPrevious, first_ref_change: int, n_frames: int, cfg: PhysicsConfig) -> tuple[Any, str]:
    """The backend's ``BoutResume`` that keeps every window before the first one reading a
    changed reference frame (all of them when none changed), or None and why nothing can
    be reused."""
    from pipeline.backends.mujoco import physics as mp

    ck, res = prev.checkpoints, prev.result
    starts = mp.window_starts(n_frames, cfg.solver.window, cfg.solver.commit)
    if [int(s) for s in ck.window_start] != starts:
        return None, "the previous run's windows differ"
    k = replan_window(starts, n_frames, cfg.solver.window, first_ref_change)
    if k == 0:
        return None, f"the reference changed from frame {first_ref_change} on, inside the first window"
    if res.untrackable.shape[0] != n_frames:
        return None, "the previous run did not record which windows could not be tracked without the residual"
    resume = mp.BoutResume(
        windows=ck.records(), replan_from=k, qpos=res.qpos, qvel=res.qvel, ctrl=res.ctrl,
        actuator_force=res.joint_torque_nm, root_wrench=res.residual_root_force, untrackable=np.asarray(res.untrackable.any(axis=1)),
    )
    return resume, ""
