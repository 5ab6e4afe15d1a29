"""``cornerman bench physics``: kinematic input vs single- and multi-person physics.

The synthetic bout (with clinches) is generated; the kinematic input is the filtered
triangulation of its 2D tracks (ground-truth identities), the anny fit of it, or
ground truth plus smooth noise. The physics stage runs in multi-person and
single-person mode on the same input, and every row (ground truth, input, physics)
is scored with the same metrics (``pipeline.evaluate.physics_metrics``) against
ground truth, with the ground-truth foot contacts. Physics rows add compute time,
the real-time factor (compute seconds per second of motion, both boxers) and
where the time went.
"""

from __future__ import annotations

import time
from typing import Any, Literal

import numpy as np

from pipeline.evaluate.physics_metrics import physics_metrics
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit
from pipeline.stages.physics import PhysicsConfig, PhysicsInputs
from pipeline.stages.physics import run as run_physics


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


def run_bench(
    n_frames: int = 150,
    cameras: int = 4,
    seed: int = 0,
    kinematic: Literal["triangulation", "fit", "noisy_gt"] = "fit",
    modes: tuple[str, ...] = ("multi", "single"),
    **physics_overrides: Any,
) -> list[dict]:
    """Rows: ground truth, kinematic input, then one per physics mode."""
    from pipeline.synthetic.bout import make_bout
    from pipeline.synthetic.config import SyntheticConfig

    bout = make_bout(SyntheticConfig(seed=seed, n_cameras=cameras, n_frames=n_frames))
    gt = bout.gt
    kin, bodyfit = _kinematic_input(bout, kinematic, seed)
    rows: list[dict] = [
        {"method": "ground truth", **physics_metrics(gt, gt, bout.foot_contact)},
        {"method": f"kinematic ({kinematic})", **physics_metrics(kin, gt, bout.foot_contact)},
    ]
    motion_s = (n_frames - 1) / gt.fps
    for mode in modes:
        cfg = PhysicsConfig(mode=mode, **physics_overrides)  # type: ignore[arg-type]
        t0 = time.perf_counter()
        out = run_physics(PhysicsInputs(keypoints=kin, bodyfit=bodyfit), cfg)
        wall = time.perf_counter() - t0
        st = out.stats
        rows.append(
            {
                "method": f"physics ({mode}, {st['skeleton']} {st['geometry']})",
                **physics_metrics(out.keypoints, gt, bout.foot_contact),
                "compute_s": wall,
                "realtime_factor": wall / motion_s,
                "fd_s": st.get("seconds_derivatives_fd", 0.0),
                "cost_derivs_s": st.get("seconds_derivatives_cost", 0.0),
                "backward_s": st.get("seconds_backward", 0.0),
                "rollouts_s": st.get("seconds_rollouts", 0.0),
                "residual_windows": f"{st['windows_with_residual']}/{st['windows']}",
                "residual_mean_frac_bw": st["residual_force_mean_frac_bw"],
                "mujoco_inter_pen_max_mm": st["mujoco_inter_penetration_max_mm"],
            }
        )
    return rows


COLUMNS: tuple[tuple[str, str], ...] = (
    ("method", "method"),
    ("inter_penetration_max_mm", "pen max mm"),
    ("inter_penetration_mean_mm", "pen mean mm"),
    ("ground_penetration_max_mm", "ground max mm"),
    ("foot_skate_mm_per_frame", "skate mm/f"),
    ("foot_speed_contact_mm_s", "foot v mm/s"),
    ("foot_height_err_contact_mm", "foot z err mm"),
    ("mpjpe_mm", "MPJPE mm"),
    ("accel_err_mm_per_frame2", "accel err"),
    ("jerk_mm_per_frame3", "jerk"),
    ("realtime_factor", "RTF ×"),
    ("fd_s", "FD s"),
    ("backward_s", "bwd s"),
    ("rollouts_s", "rollout s"),
    ("residual_windows", "residual win"),
    ("residual_mean_frac_bw", "residual bw"),
)


def print_table(rows: list[dict]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title="physics: kinematic vs single/multi-person physics (synthetic bout)")
    for _, head in COLUMNS:
        table.add_column(head, justify="right" if head != "method" else "left")
    for r in rows:
        cells = []
        for key, _ in COLUMNS:
            v = r.get(key, "")
            cells.append(f"{v:.1f}" if isinstance(v, float) else str(v))
        table.add_row(*cells)
    Console().print(table)
