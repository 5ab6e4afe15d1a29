"""fit step: body-model shape and pose per athlete from the filtered 3D and the 2D keypoints.

Depends on the triangulate, associate and track artifacts, so an identity fix upstream
(annotations consumed by track/associate) makes this stage stale automatically.
"""

from __future__ import annotations

from typing import Any

from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.association import Association
from pipeline.schema.detections import Tracks2D
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.stages.fit import FitConfig
from pipeline.stages.fit import run as run_fit


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
    ctx.progress(0, 1, _loading_message(cfg))
    res = run_fit(kp3d, tracks, assoc, ctx.rig, cfg, progress=ctx.progress)
    ctx.progress(1, 1, "done")
    ctx.metrics.update(res.metrics)
    return {"bodyfit": res.bodyfit, "keypoints3d": res.keypoints3d}


SPEC = StageSpec(
    name="fit",
    deps=("triangulate", "associate", "track"),
    optional_deps=("calibrate",),
    config_cls=FitConfig,
    execute=_execute,
    description="kinematic body-model fit (anny shape + per-frame pose, L-BFGS on 2D/3D keypoints)",
)
