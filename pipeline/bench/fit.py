"""``cornerman bench fit``: body-model fit vs triangulation on the synthetic bout.

For each camera count, the bout is generated, identities come from ground truth (so only
triangulation and fitting are measured), triangulation runs, then the fit; both are scored
against ground truth in the same run: MPJPE, acceleration error (jitter), bone-length std,
the lowest foot joint, and the fit's speed with its shape / pose time split.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from pipeline.schema.joints import FOOT_JOINTS
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.stages.fit import FitConfig
from pipeline.stages.fit import run as run_fit


def _scores(est: Keypoints3D, gt: Keypoints3D) -> dict[str, float]:
    from pipeline.evaluate.metrics import acceleration_error, bone_length_std, mpjpe

    foot = [est.joint_names.index(n) for n in FOOT_JOINTS if n in est.joint_names]
    z = est.xyz_m[:, :, foot, 2][est.valid[:, :, foot]]
    return {
        "mpjpe_mm": mpjpe(est, gt),
        "accel_err_mm": acceleration_error(est, gt),
        "bone_std_mm": bone_length_std(est),
        "min_foot_z_mm": float(z.min() * 1000) if z.size else float("nan"),
    }


def run_bench(
    n_frames: int = 300,
    cameras: int | tuple[int, ...] = (4, 2),
    seed: int = 0,
    threads: int = 1,
    **fit_overrides: Any,
) -> list[dict]:
    """Rows: one per (camera count, method) with the scores; fit rows add the timings."""
    from pipeline.stages.triangulate import TriangulateConfig
    from pipeline.stages.triangulate import run as run_triangulate
    from pipeline.synthetic.bout import make_bout
    from pipeline.synthetic.config import SyntheticConfig

    rows: list[dict] = []
    cfg = FitConfig(threads=threads, **fit_overrides)
    # The body model is loaded once per process (a job worker too): time it on its own, so
    # that every row's fit time is the fit's.
    t0 = time.perf_counter()
    if cfg.body_model == "anny":
        from pipeline.backends.anny.model import anny_fit_body

        anny_fit_body(cfg.rig, cfg.precision)
    load_s = time.perf_counter() - t0
    for n_cams in (cameras,) if isinstance(cameras, int) else tuple(cameras):
        bout = make_bout(SyntheticConfig(seed=seed, n_cameras=n_cams, n_frames=n_frames))
        assoc = bout.gt_association()
        t0 = time.perf_counter()
        raw, tri = run_triangulate(bout.tracks, assoc, bout.rig, TriangulateConfig())
        t_tri = time.perf_counter() - t0
        rows.append({"cameras": n_cams, "method": "triangulation (raw)", **_scores(raw, bout.gt)})
        rows.append(
            {
                "cameras": n_cams,
                "method": "triangulation (filtered)",
                **_scores(tri, bout.gt),
                "time_s": t_tri,
            }
        )
        res = run_fit(tri, bout.tracks, assoc, bout.rig, cfg)
        m = res.metrics
        fit_row = {"cameras": n_cams, "method": "fit (anny)", **_scores(res.keypoints3d, bout.gt)}
        total = m.get("time_total_s", float("nan"))
        fit_row.update(
            time_s=total,
            shape_s=m.get("time_shape_s", float("nan")),
            pose_s=m.get("time_pose_s", float("nan")),
            load_s=load_s,
            cpu_s=float(m.get("time_shape_cpu_s", float("nan"))) + float(m.get("time_pose_cpu_s", float("nan"))),
            fps_per_person=n_frames / max(total / max(res.bodyfit.person_ids.shape[0], 1), 1e-9),
            reproj_px=m.get("reproj_median_px", float("nan")),
        )
        from pipeline.backends.anny.body import posed_mesh

        bf = res.bodyfit
        mesh_z = [
            float(posed_mesh(bf, p, np.flatnonzero(bf.valid[:, p]))[0][..., 2].min())
            for p in range(bf.person_ids.shape[0])
            if bf.valid[:, p].any()
        ]
        fit_row["min_mesh_z_mm"] = min(mesh_z) * 1000 if mesh_z else float("nan")
        tri_acc = rows[-1]["accel_err_mm"]
        fit_row["accel_vs_tri_pct"] = (
            100.0 * (fit_row["accel_err_mm"] / tri_acc - 1.0) if tri_acc > 0 else float("nan")
        )
        fit_row["mpjpe_vs_tri_pct"] = 100.0 * (fit_row["mpjpe_mm"] / rows[-1]["mpjpe_mm"] - 1.0)
        fit_row["prior"] = cfg.pose_prior_path or "none"
        rows.append(fit_row)
    return rows


def print_table(rows: list[dict]) -> None:
    from rich.console import Console
    from rich.table import Table

    cols = [
        ("mpjpe_mm", "MPJPE mm", "{:.1f}"),
        ("accel_err_mm", "accel err mm/f²", "{:.2f}"),
        ("mpjpe_vs_tri_pct", "ΔMPJPE %", "{:+.0f}"),
        ("accel_vs_tri_pct", "Δaccel %", "{:+.0f}"),
        ("bone_std_mm", "bone std mm", "{:.2f}"),
        ("min_foot_z_mm", "min foot z mm", "{:.1f}"),
        ("min_mesh_z_mm", "min mesh z mm", "{:.1f}"),
        ("reproj_px", "reproj px", "{:.2f}"),
        ("time_s", "time s", "{:.1f}"),
        ("shape_s", "shape s", "{:.2f}"),
        ("pose_s", "pose s", "{:.1f}"),
        ("load_s", "model load s", "{:.1f}"),
        ("prior", "prior", "{}"),
        ("fps_per_person", "frames/s/person", "{:.1f}"),
        ("cpu_s", "fit CPU s", "{:.1f}"),
    ]
    table = Table(
        title="fit vs triangulation (synthetic bout, GT identities)",
        caption="Δ % = fit vs filtered triangulation; time s = the fit stage's wall time: shape s (init "
        "from bone lengths) + pose s (init + both L-BFGS passes) + input gathering; the body model is "
        "loaded before (model load s, once per process); frames/s/person from time s; "
        "targets (4 cams): MPJPE <= tri, accel <= -30 % vs filtered tri, min foot z >= -10 mm",
    )
    table.add_column("cams", justify="right")
    table.add_column("method")
    for _, title, _ in cols:
        table.add_column(title, justify="right")
    for r in rows:
        cells = [fmt.format(r[k]) if k in r and r[k] == r[k] else "" for k, _, fmt in cols]  # NaN != NaN
        table.add_row(str(r["cameras"]), str(r["method"]), *cells)
    Console(width=220).print(table)
