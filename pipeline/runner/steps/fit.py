"""fit step: body-model shape and pose per athlete from the filtered 3D and the 2D keypoints.

Depends on the triangulate, associate and track artifacts, so an identity fix upstream
(annotations consumed by track/associate) makes this stage stale automatically. With
``FitConfig.incremental`` the stage's previous fit is passed back in and only the frames
whose inputs changed are re-optimised (``pipeline.stages.fit_incremental``).
"""

from __future__ import annotations

from typing import Any

from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.association import Association
from pipeline.schema.detections import Tracks2D
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit
from pipeline.stages.fit import FitConfig
from pipeline.stages.fit import run as run_fit
from pipeline.stages.fit_incremental import FitCheckpoints, FitPrevious

CHECKPOINTS = "checkpoints"
"""Name of the stage's checkpoints output (``checkpoints.npz``)."""


def _previous(ctx: StageContext, cfg: FitConfig) -> FitPrevious | None:
    if ctx.reusable_with(cfg.incremental, f"{CHECKPOINTS}.npz", "checkpoints") is None:
        return None
    return FitPrevious(
        bodyfit=ctx.load_previous("bodyfit", BodyFit),
        keypoints3d=ctx.load_previous("keypoints3d", Keypoints3D),
        checkpoints=ctx.load_previous(CHECKPOINTS, FitCheckpoints),
    )


def _loading_message(cfg: FitConfig) -> str:
    """What the fit does before its first iteration: anny's first build writes a cache of
    ~0.8 GB and takes a minute or two, which must not look like a hang at 0 %."""
    if cfg.body_model != "anny":
        return f"loading the {cfg.body_model} body model"
    from pipeline.backends.anny.cache import CACHE_SIZE_GB, anny_cache_built, anny_cache_dir

    if anny_cache_built():
        return "loading the anny body model"
    return (
        f"first fit: building the anny model cache (~{CACHE_SIZE_GB:g} GB in {anny_cache_dir()}, "
        "1-2 min, once)"
    )


def _execute(ctx: StageContext, cfg: FitConfig) -> dict[str, Any]:
    kp3d = ctx.load("triangulate", "keypoints3d", Keypoints3D)
    tracks = ctx.load("track", "tracks", Tracks2D)
    assoc = ctx.load("associate", "association", Association)
    previous = _previous(ctx, cfg)
    ctx.progress(0, 1, _loading_message(cfg))
    res = run_fit(kp3d, tracks, assoc, ctx.rig, cfg, progress=ctx.progress, previous=previous)
    ctx.progress(1, 1, "done")
    metrics = dict(res.metrics)
    if previous is None and "incremental" in ctx.metrics:  # the runner's reason wins over the stage's
        metrics["incremental"] = ctx.metrics["incremental"]
    ctx.metrics.update(metrics)
    if previous is not None and res.metrics.get("reused_frames", 0):
        assert ctx.previous is not None
        ctx.metrics["previous_outputs_hash"] = ctx.previous.manifest.outputs_hash
    outputs: dict[str, Any] = {"bodyfit": res.bodyfit, "keypoints3d": res.keypoints3d}
    if res.checkpoints is not None:
        outputs[CHECKPOINTS] = res.checkpoints
    return outputs


SPEC = StageSpec(
    name="fit",
    deps=("triangulate", "associate", "track"),
    optional_deps=("calibrate",),
    config_cls=FitConfig,
    execute=_execute,
    description="kinematic body-model fit (anny shape + per-frame pose, L-BFGS on 2D/3D keypoints)",
)
