"""``cornerman bench physics``: kinematic input vs single- and multi-person physics.

The synthetic bout (with clinches) is generated; the kinematic input is the filtered
triangulation of its 2D tracks (ground-truth identities), the anny fit of it, or
ground truth plus smooth noise. The physics stage runs in multi-person and
single-person mode on the same input, and every row (ground truth, input, physics)
is scored with the same metrics (``pipeline.evaluate.physics_metrics``) against
ground truth, with the ground-truth foot contacts. Physics rows add compute time,
the real-time factor (compute seconds per second of motion, both boxers), the same time
as a multiple of a plain ``mj_step`` rollout of the scene over the bout (``× mj_step``,
``pipeline.backends.mujoco.timing``: less sensitive to the machine and its load) and
where the time went.

Penetration is reported twice. ``pen`` uses fixed capsules around the keypoints
(``physics_metrics``: the synthetic bout's own body volumes, zero for ground
truth). ``body pen`` uses the athletes' fitted bodies, i.e. the humanoids the
physics collides, with ground truth and the kinematic input posed in them by
inverse kinematics. The two disagree: the synthetic ground truth, dressed in the
fitted bodies, overlaps by several centimetres in clinches, so a motion that is
penetration-free in the athletes' bodies cannot also stay at ground truth there.

``needed F`` / ``needed τ`` (``pipeline.stages.physics_dynamics``) tell how physically
consistent each row's motion is: the mean root force (body weights) and torque (N·m)
it needs beyond its foot contacts, in the same fitted bodies. The synthetic ground
truth is choreographed, not simulated, so it needs some itself; a simulation can
follow a motion only as far as its residual supplies that.

``scenes`` adds motion the defaults were not tuned on: ``"deepmimic:<clip>+<clip>"`` is
two athletes doing DeepMimic mocap clips (``pipeline.synthetic.mocap_scene``; punch,
kick, walk, run, spin, backflip...), seen by the same cameras with the same 2D noise,
e.g. ``--opt scenes='["synthetic","deepmimic:punch+walk","deepmimic:kick+spin"]'``.
Every row carries its scene; deltas and means over seeds are per scene.
"""

from __future__ import annotations

import time
from typing import Any, Literal

import numpy as np

from pipeline.bench.effort import effort_columns
from pipeline.evaluate.physics_metrics import physics_metrics
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit
from pipeline.stages.physics import PhysicsConfig, PhysicsInputs, penetration_of_pose, posed_humanoids
from pipeline.stages.physics import run as run_physics
from pipeline.stages.physics_dynamics import needed_residual, residual_of_pose


def _kinematic_input(bout: Any, source: str, seed: int) -> tuple[Keypoints3D, BodyFit | None]:
    """The kinematic motion the physics starts from, and its BodyFit when it is a fit."""
    if source == "noisy_gt":
        from scipy.ndimage import gaussian_filter1d

        rng = np.random.default_rng(seed)
        noise = gaussian_filter1d(rng.normal(scale=0.024, size=bout.gt.xyz_m.shape), 2.0, axis=0)
        return bout.gt.replace(xyz_m=bout.gt.xyz_m + noise, source="fit"), None
    from pipeline.stages.triangulate import TriangulateConfig
    from pipeline.stages.triangulate import run as run_triangulate

    assoc = bout.gt_association()
    _, tri = run_triangulate(bout.tracks, assoc, bout.rig, TriangulateConfig())
    if source == "triangulation":
        return tri, None
    from pipeline.stages.fit import FitConfig
    from pipeline.stages.fit import run as run_fit

    fit = run_fit(tri, bout.tracks, assoc, bout.rig, FitConfig())
    return fit.keypoints3d, fit.bodyfit


TARGETS = (
    "targets (multi vs kinematic): pen max -80 %, skate -70 %, MPJPE <= +10 %, ground <= 2 mm; multi pen < single pen; "
    "residual <= 0.02 bw; joint torques over human limits <= 1 % of frames"
)
DELTAS: tuple[tuple[str, str], ...] = (
    ("inter_penetration_max_mm", "d_pen_max_pct"),
    ("body_pen_max_mm", "d_body_pen_max_pct"),
    ("foot_skate_mm_per_frame", "d_skate_pct"),
    ("mpjpe_mm", "d_mpjpe_pct"),
)


def with_deltas(rows: list[dict]) -> list[dict]:
    """Add, to every physics row, its % change vs the kinematic row of the same scene and seed
    (penetration max, foot skating, MPJPE: the quantities of the targets)."""
    kin = {(r.get("scene"), r.get("seed")): r for r in rows if str(r["method"]).startswith("kinematic")}
    out = []
    for r in rows:
        r = dict(r)
        k = kin.get((r.get("scene"), r.get("seed")))
        if k is not None and str(r["method"]).startswith("physics"):
            for key, name in DELTAS:
                if key in r and key in k:
                    r[name] = 100.0 * (r[key] / k[key] - 1.0) if k[key] > 0 else float("nan")
        out.append(r)
    return out


def mean_over_seeds(rows: list[dict]) -> list[dict]:
    """One row per (scene, method) with every numeric column averaged over the seeds."""
    methods = list(dict.fromkeys((r.get("scene"), r["method"]) for r in rows))
    out = []
    for sc, m in methods:
        group = [r for r in rows if r["method"] == m and r.get("scene") == sc]
        agg: dict[str, Any] = {"method": m, "seed": f"mean of {len(group)}"}
        if sc is not None:
            agg["scene"] = sc
        for key in group[0]:
            vals = [g.get(key) for g in group]
            if key not in ("method", "seed", "scene") and all(isinstance(v, (int, float)) for v in vals):
                agg[key] = float(np.mean([float(v) for v in vals if v is not None]))
        out.append(agg)
    return out


def run_bench(
    n_frames: int = 150,
    cameras: int = 4,
    seed: int = 0,
    kinematic: Literal["triangulation", "fit", "noisy_gt"] = "fit",
    modes: tuple[str, ...] = ("multi", "single"),
    seeds: tuple[int, ...] | None = None,
    scenes: tuple[str, ...] = ("synthetic",),
    **physics_overrides: Any,
) -> list[dict]:
    """Rows: ground truth, kinematic input, then one per physics mode, for ``seed`` or
    for each of ``seeds`` (different bouts; then also their means: single-bout physics
    numbers move by several mm between bouts), for each of ``scenes`` (``"synthetic"``
    or ``"deepmimic:<clip>+<clip>"``, see ``pipeline.synthetic.mocap_scene``)."""
    from pipeline.synthetic.mocap_scene import parse_scene

    scenes = (scenes,) if isinstance(scenes, str) else tuple(scenes)  # ``--opt scenes=synthetic`` gives a string
    if not scenes or not all(isinstance(sc, str) for sc in scenes):
        raise ValueError(f"bench physics: scenes must be a non-empty list of scene names, e.g. [\"synthetic\"]; got {scenes!r}")
    for sc in scenes:
        parse_scene(sc)  # a bad name fails before any work
    if seeds is not None and (
        isinstance(seeds, (str, bytes)) or not seeds or not all(isinstance(s, int) and not isinstance(s, bool) for s in seeds)
    ):
        raise ValueError(f"bench physics: seeds must be a non-empty list of integers, e.g. seeds=[0,1]; got {seeds!r}")
    modes = (modes,) if isinstance(modes, str) else tuple(modes)  # ``--opt modes=multi`` gives a string
    rows: list[dict] = []
    for sc in scenes:
        for s in seeds if seeds else (seed,):
            rows += [{"scene": sc, **r} for r in _run_seed(s, n_frames, cameras, kinematic, modes, physics_overrides, sc)]
    rows = with_deltas(rows)
    if seeds and len(seeds) > 1:
        rows += mean_over_seeds(rows)
    return rows


def _run_seed(
    seed: int,
    n_frames: int,
    cameras: int,
    kinematic: str,
    modes: tuple[str, ...],
    physics_overrides: dict[str, Any],
    scene: str = "synthetic",
) -> list[dict]:
    from pipeline.synthetic.config import SyntheticConfig
    from pipeline.synthetic.mocap_scene import make_scene

    bout = make_scene(scene, SyntheticConfig(seed=seed, n_cameras=cameras, n_frames=n_frames))
    gt = bout.gt
    kin, bodyfit = _kinematic_input(bout, kinematic, seed)
    pids = [int(p) for p in kin.person_ids]

    def body_pen(motion: Keypoints3D) -> dict[str, float]:
        # Overlap of the athletes' own bodies (the humanoids the physics collides),
        # posed onto ``motion``; ground truth is scored in the same bodies.
        # Posed once for both measures (the inverse kinematics is the costly part).
        scene, qpos = posed_humanoids(motion, bodyfit, PhysicsConfig(**physics_overrides), pids, kin, 2, "bench physics")
        pen = penetration_of_pose(scene, qpos)
        need = residual_of_pose(scene, qpos, motion.fps).summary()
        return {"body_pen_max_mm": float(pen.max()), "body_pen_mean_mm": float(pen.mean()), **needed_cols(need)}

    def needed_cols(s: dict[str, float]) -> dict[str, float]:
        # The root wrench the motion needs beyond its foot contacts, in the same bodies.
        return {k: s[k] for k in ("needed_force_frac_bw", "needed_torque_nm")}

    rows: list[dict] = [
        {"method": "ground truth", "seed": seed, **physics_metrics(gt, gt, bout.foot_contact), **body_pen(gt)},
        {"method": f"kinematic ({kinematic})", "seed": seed, **physics_metrics(kin, gt, bout.foot_contact), **body_pen(kin)},
    ]
    motion_s = (n_frames - 1) / gt.fps
    for mode in modes:
        cfg = PhysicsConfig(mode=mode, **physics_overrides)  # type: ignore[arg-type]
        t0 = time.perf_counter()
        out = run_physics(PhysicsInputs(keypoints=kin, bodyfit=bodyfit), cfg)
        wall = time.perf_counter() - t0
        st = out.stats
        # The yardstick: a plain mj_step rollout of the same scene over the same frames.
        from pipeline.backends.mujoco.timing import plain_rollout_seconds

        plain = plain_rollout_seconds(out.mjcf, out.result.qpos[0], out.result.ctrl[:-1], out.result.fps)
        rows.append(
            {
                "method": f"physics ({mode}, {st['skeleton']} {st['geometry']})",
                "seed": seed,
                **physics_metrics(out.keypoints, gt, bout.foot_contact),
                "compute_s": wall,
                "realtime_factor": wall / motion_s,
                "plain_step_s": plain,
                "x_plain_step": wall / plain if plain > 0 else float("nan"),
                "fd_s": st.get("seconds_derivatives_fd", 0.0),
                "cost_derivs_s": st.get("seconds_derivatives_cost", 0.0),
                "backward_s": st.get("seconds_backward", 0.0),
                "rollouts_s": st.get("seconds_rollouts", 0.0),
                "residual_windows": f"{st['windows_with_residual']}/{st['windows']}",
                "residual_mean_frac_bw": st["residual_force_mean_frac_bw"],
                "residual_max_frac_bw": st["residual_force_max_frac_bw"],
                "body_pen_max_mm": st["body_penetration_max_mm"],
                "body_pen_mean_mm": st["body_penetration_mean_mm"],
                **effort_columns(out.mjcf, out.result),
                **needed_cols(
                    needed_residual(out.keypoints, bodyfit, cfg, pids, body_keypoints=kin).summary()
                ),
            }
        )
    return rows


COLUMNS: tuple[tuple[str, str], ...] = (
    ("scene", "scene"),
    ("method", "method"),
    ("seed", "seed"),
    ("inter_penetration_max_mm", "pen max mm"),
    ("inter_penetration_mean_mm", "pen mean mm"),
    ("body_pen_max_mm", "body pen max mm"),
    ("body_pen_mean_mm", "body pen mean mm"),
    ("ground_penetration_max_mm", "ground max mm"),
    ("foot_skate_mm_per_frame", "skate mm/f"),
    ("foot_skate_interior_mm_per_frame", "skate mid mm/f"),
    ("foot_skate_edge_mm_per_frame", "skate edge mm/f"),
    ("foot_speed_contact_mm_s", "foot v mm/s"),
    ("foot_height_err_contact_mm", "foot z err mm"),
    ("mpjpe_mm", "MPJPE mm"),
    ("d_pen_max_pct", "Δpen max %"),
    ("d_body_pen_max_pct", "Δbody pen max %"),
    ("d_skate_pct", "Δskate %"),
    ("d_mpjpe_pct", "ΔMPJPE %"),
    ("accel_err_mm_per_frame2", "accel err"),
    ("jerk_mm_per_frame3", "jerk"),
    ("realtime_factor", "RTF ×"),
    ("x_plain_step", "× mj_step"),
    ("fd_s", "FD s"),
    ("backward_s", "bwd s"),
    ("rollouts_s", "rollout s"),
    ("residual_windows", "residual win"),
    ("residual_mean_frac_bw", "residual bw"),
    ("residual_max_frac_bw", "residual max bw"),
    ("residual_xy_mean_frac_bw", "residual xy bw"),
    ("grf_z_mean_frac_bw", "floor Fz bw"),
    ("torque_over_pct_any", "τ>human %"),
    ("torque_peak_ratio_max", "τ/human max"),
    ("needed_force_frac_bw", "needed F bw"),
    ("needed_torque_nm", "needed τ N·m"),
)


def print_table(rows: list[dict]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title="physics: kinematic vs single/multi-person physics (synthetic bouts, mocap scenes)", caption=TARGETS)
    for _, head in COLUMNS:
        if head in ("method", "scene"):
            table.add_column(head, justify="left", no_wrap=True)
        else:
            table.add_column(head, justify="right", overflow="fold")
    for r in rows:
        cells = []
        for key, _ in COLUMNS:
            v = r.get(key, "")
            fmt = "{:.2f}" if key.endswith("frac_bw") or key.startswith("foot_skate") else "{:.1f}"
            cells.append(fmt.format(v) if isinstance(v, float) else str(v))
        table.add_row(*cells)
    # Wide enough for every column also when the output is a file or a pipe (80 columns).
    Console(width=max(Console().width, 260)).print(table)
