"""The ordered list of stages and their specs (one step module per stage)."""

from __future__ import annotations

import importlib
import importlib.util
from functools import cache

from pipeline.runner.spec import StageSpec

STAGE_ORDER: tuple[str, ...] = ("detect2d", "track", "associate", "triangulate", "fit", "physics", "evaluate")


@cache
def get_specs() -> dict[str, StageSpec]:
    """Stage name -> spec, in pipeline order, for every step module present."""
    specs: dict[str, StageSpec] = {}
    for name in STAGE_ORDER:
        modname = f"pipeline.runner.steps.{name}"
        if importlib.util.find_spec(modname) is None:
            continue
        spec = importlib.import_module(modname).SPEC
        if spec.name != name:
            raise ValueError(f"{modname}.SPEC.name is {spec.name!r}, expected {name!r}")
        specs[name] = spec
    return specs
