"""Runs a session's stages: skips fresh ones, re-runs stale ones."""

from pipeline.runner.core import StageReport, first_stale_stage, run, stage_status
from pipeline.runner.registry import STAGE_ORDER, get_specs
from pipeline.runner.spec import NullProgress, ProgressSink, StageContext, StageSpec

__all__ = [
    "NullProgress",
    "ProgressSink",
    "STAGE_ORDER",
    "StageContext",
    "StageReport",
    "StageSpec",
    "first_stale_stage",
    "get_specs",
    "run",
    "stage_status",
]
