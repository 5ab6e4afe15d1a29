"""The ordered list of stages and their specs (one step module per stage)."""

from __future__ import annotations

import importlib
from functools import cache

from pipeline.runner.spec import StageSpec

STAGE_ORDER: tuple[str, ...] = (
    "detect2d",
    "track",
    "associate",
    "calibrate",
    "triangulate",
    "fit",
    "physics",
    "analyze",
    "evaluate",
)


@cache
def get_specs() -> dict[str, StageSpec]:
    """Stage name -> spec, in pipeline order (importing a step module imports no heavy backend)."""
    specs: dict[str, StageSpec] = {}
    for name in STAGE_ORDER:
        spec = importlib.import_module(f"pipeline.runner.steps.{name}").SPEC
        if spec.name != name:
            raise ValueError(f"pipeline.runner.steps.{name}.SPEC.name is {spec.name!r}, expected {name!r}")
        specs[name] = spec
    return specs
