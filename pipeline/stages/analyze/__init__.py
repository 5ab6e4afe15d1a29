"""analyze: boxing analytics (punches, defence, ring-craft, work rate) on a 3D result."""

from pipeline.stages.analyze.config import (
    AnalyzeConfig,
    DefenceConfig,
    OutcomeConfig,
    PunchConfig,
    RingConfig,
    TypeConfig,
    WorkRateConfig,
)
from pipeline.stages.analyze.stage import REQUIRED_JOINTS, AnalyzeInputs, AnalyzeOutput, run
from pipeline.stages.analyze.summary import athlete_summary, summarize

__all__ = [
    "REQUIRED_JOINTS",
    "AnalyzeConfig",
    "AnalyzeInputs",
    "AnalyzeOutput",
    "DefenceConfig",
    "OutcomeConfig",
    "PunchConfig",
    "RingConfig",
    "TypeConfig",
    "WorkRateConfig",
    "athlete_summary",
    "run",
    "summarize",
]
