"""calibrate step: refine the camera rig on the associated keypoints (bundle adjustment).

Stores the rig every later stage uses (``rig.npz``: the refined rig when adopted, the input
rig otherwise, in the levelled floor world; ``pipeline.runner.rig``), ``world.json`` (that
world against the input calibration's) and ``report.json`` with the decisions and the
per-camera reprojection before and after.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.geometry.world import transform_world, turn_deg
from pipeline.runner.rig import RIG_ARTIFACT, WORLD_ARTIFACT, world_from_input
from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.association import Association
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.stages.calibrate import CalibrateConfig, CalibrationResult, holds, rig_change, summary
from pipeline.stages.calibrate import run as run_calibrate


def _input_files(ctx: StageContext) -> list[Path]:
    return [ctx.resolve(ctx.session.calibration)]


def report(result: CalibrationResult) -> dict[str, Any]:
    """JSON-ready report: the decision, then per camera the reprojection (undistorted px,
    median and p95 over every associated keypoint) before and after, and the change."""

    def num(x: float) -> float | None:
        return round(float(x), 3) if np.isfinite(x) else None

    cams = []
    for v, name in enumerate(result.rig.names):
        row: dict[str, Any] = {
            "camera": name,
            "center_shift_mm": num(1000.0 * result.center_shift_m[v]),
            "rotation_change_deg": num(result.rotation_change_deg[v]),
            "focal_scale": num(result.focal_scale[v]),
        }
        for label, st in (("before", result.before), ("after", result.after)):
            if st is not None:
                row[f"median_{label}_px"] = num(st.median_px[v])
                row[f"p95_{label}_px"] = num(st.p95_px[v])
                row[f"n_obs_{label}"] = int(st.n_obs[v])
        cams.append(row)
    return {**summary(result), "cameras": cams}


def _execute(ctx: StageContext, cfg: CalibrateConfig) -> dict[str, Any]:
    tracks = ctx.load("track", "tracks", Tracks2D)
    assoc = ctx.load("associate", "association", Association)
    ctx.progress(0, 1, "bundle adjustment on the athletes' keypoints")
    result = run_calibrate(tracks, assoc, ctx.input_rig, cfg)
    ctx.progress(1, 1, "adopted" if result.adopted else "input calibration kept")
    ctx.metrics.update({k: v for k, v in summary(result).items() if v is not None})
    rig, world = result.rig, result.world_from_input
    prev = ctx.reusable_previous(cfg.incremental)
    if prev is not None:
        old = ctx.load_previous(RIG_ARTIFACT, CameraRig)
        old_adopted = bool(prev.manifest.metrics.get("adopted"))
        old_world = world_from_input(ctx.session_dir, ctx.session)
        # The refinement and the floor are held separately: each is compared in its own terms.
        floor_moved = abs(world[2, 3] - old_world[2, 3])
        floor_turned = turn_deg(world[:3, :3] @ old_world[:3, :3].T)
        same_floor = floor_moved <= cfg.floor.hold_m and floor_turned <= cfg.floor.hold_deg
        old_input = transform_world(old, np.linalg.inv(old_world))
        new_input = transform_world(rig, np.linalg.inv(world))
        if old_adopted == result.adopted and same_floor and holds(old_input, new_input, cfg):
            centre, rot, _ = rig_change(old_input, new_input)
            rig, world = old, old_world
            ctx.metrics["floor_shift_m"] = float(prev.manifest.metrics.get("floor_shift_m", 0.0))
            ctx.metrics["world_turn_deg"] = round(turn_deg(old_world[:3, :3]), 2)
            ctx.metrics["incremental"] = (
                f"previous rig kept (the new one is within {centre.max():.2f} mm, {rot.max():.3f} deg of it, "
                f"the floor within {1000 * floor_moved:.1f} mm, {floor_turned:.2f} deg)"
            )
        else:
            ctx.metrics["incremental"] = (
                "new rig: it moved beyond the hold thresholds, the floor moved, or the decision changed"
            )
    return {
        RIG_ARTIFACT: rig,
        WORLD_ARTIFACT: json.dumps({"world_from_input": np.round(world, 12).tolist()}, indent=2),
        "report.json": json.dumps(report(result), indent=2),
    }


SPEC = StageSpec(
    name="calibrate",
    deps=("track", "associate"),
    config_cls=CalibrateConfig,
    execute=_execute,
    input_files=_input_files,
    uses_rig_fps=True,
    description="calibration refinement from the athletes (bundle adjustment; kept only when it helps)",
)
