"""evaluate step: metrics.json + problems.npz from every 3D result present."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.runner.registry import STAGE_ORDER
from pipeline.runner.rig import in_floor_world, world_from_input
from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.association import Association
from pipeline.schema.base import load_npz
from pipeline.schema.detections import Tracks2D
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import PhysicsResult
from pipeline.schema.sources import RESULT_ARTIFACTS
from pipeline.stages.evaluate import EvaluateConfig, EvaluateInputs, PhysicsEffortInputs, run

log = logging.getLogger(__name__)


def _input_files(ctx: StageContext) -> list[Path]:
    s = ctx.session
    files = [ctx.resolve(s.calibration)]
    files += [ctx.resolve(p) for p in (s.ground_truth, s.ground_truth_labels) if p]
    return files


def _physics_effort(ctx: StageContext) -> PhysicsEffortInputs | None:
    """The physics result with its scene's actuator names and body masses (MuJoCo); None
    when the physics stage left no result and scene."""
    if not (ctx.has("physics", "result.npz") and ctx.has("physics", "scene.xml")):
        return None
    from pipeline.backends.mujoco.forces import actuator_names, body_masses_kg

    result = ctx.load("physics", "result", PhysicsResult)
    xml = ctx.store.path("physics", "scene.xml").read_text()
    pids = [int(p) for p in result.person_ids]
    return PhysicsEffortInputs(result, tuple(actuator_names(xml)), body_masses_kg(xml, pids))


def _execute(ctx: StageContext, cfg: EvaluateConfig) -> dict[str, Any]:
    s = ctx.session
    # Only stages this session runs: an artifact left by a stage since disabled is stale.
    enabled = set(ctx.session.stages or STAGE_ORDER)
    sources = {
        name: ctx.load(stage, art, Keypoints3D)
        for name, (stage, art) in RESULT_ARTIFACTS.items()
        if stage in enabled and ctx.has(stage, f"{art}.npz")
    }
    gt = load_npz(ctx.resolve(s.ground_truth), Keypoints3D) if s.ground_truth else None
    if gt is not None:  # given in the input calibration's world; the results are in the floor world (levelled, lowered)
        gt = in_floor_world(gt, world_from_input(ctx.session_dir, s))
    labels = None
    if s.ground_truth_labels:
        path = ctx.resolve(s.ground_truth_labels)
        with np.load(path, allow_pickle=False) as z:
            if "person_of_det" not in z.files:
                raise ValueError(f"{path}: missing array 'person_of_det'")
            labels = z["person_of_det"]
    tracks = ctx.load("track", "tracks", Tracks2D)
    if labels is not None and labels.shape[0] != tracks.n_dets:
        # The labels refer to the input rows; a detector run (video source) has other rows.
        log.warning("%s: %d labels for %d detections; identity accuracy skipped", s.ground_truth_labels, labels.shape[0], tracks.n_dets)
        labels = None
    inp = EvaluateInputs(
        rig=ctx.rig,
        tracks=tracks,
        association=ctx.load("associate", "association", Association),
        sources=sources,
        gt=gt,
        gt_person_of_det=labels,
        physics=_physics_effort(ctx) if "physics" in enabled else None,
    )
    metrics, flags = run(inp, cfg)
    best = list(sources)[-1]
    for name, m in metrics["sources"].items():
        for k in ("mpjpe_mm", "pcp_pct", "accel_error_mm_per_frame2"):
            if m.get(k) is not None:
                ctx.metrics[f"{k}_{name}"] = m[k]
    if "identity_accuracy_pct" in metrics:
        ctx.metrics["identity_accuracy_pct"] = metrics["identity_accuracy_pct"]
    ctx.metrics["evaluated_source"] = best
    return {"metrics.json": json.dumps(metrics, indent=2), "problems": flags.to_arrays()}


SPEC = StageSpec(
    name="evaluate",
    deps=("track", "associate", "triangulate"),
    optional_deps=("calibrate", "fit", "physics"),
    config_cls=EvaluateConfig,
    execute=_execute,
    input_files=_input_files,
    consumes_annotations=True,
    description="metrics vs ground truth and per-frame problem flags",
)
