"""The analyze step hands the stage the 2D tracks and their association when
``AnalyzeConfig.views`` is on (``pipeline.stages.analyze.evidence2d``), and the stage runs on a
real session's tracks through the runner."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

import pipeline.runner.steps.analyze as step
from pipeline.artifacts import ArtifactStore
from pipeline.runner import run, stage_status
from pipeline.stages.analyze import AnalyzeConfig
from pipeline.stages.analyze.config import ViewEvidenceConfig
from tests.conftest import write_tiny_session

STAGES = ("detect2d", "track", "associate", "triangulate", "analyze")


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    s = write_tiny_session(tmp_path_factory.mktemp("views") / "s", stages=STAGES, n_frames=30)
    run(s)
    return s


def test_the_views_option_hands_the_tracks_to_the_stage(
    session: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = ArtifactStore(session)
    ctx: Any = SimpleNamespace(
        session=SimpleNamespace(stages=list(STAGES)),
        annotations=[],
        metrics={},
        session_dir=session,
        has=store.has,
        load=store.load,
    )
    seen: list[Any] = []
    real = step.run

    def spy(inputs: Any, cfg: AnalyzeConfig) -> Any:
        seen.append(inputs)
        return real(inputs, cfg)

    monkeypatch.setattr(step, "run", spy)
    step._execute(ctx, AnalyzeConfig(views=ViewEvidenceConfig(enabled=True)))
    tracks, assoc = seen[-1].tracks, seen[-1].association
    assert tracks is not None and assoc is not None
    assert tracks.n_dets == assoc.person_of_det.shape[0] == store.load("track", "tracks", type(tracks)).n_dets
    # The default (punches from the views off, the speed lift on) needs the tracks too.
    step._execute(ctx, AnalyzeConfig(views=ViewEvidenceConfig(enabled=False)))
    assert seen[-1].tracks is not None and seen[-1].association is not None
    step._execute(ctx, AnalyzeConfig(views=ViewEvidenceConfig(enabled=False, lift_speed=False)))
    assert seen[-1].tracks is None and seen[-1].association is None


def test_the_stage_runs_with_the_views_on_and_depends_on_the_tracks(session: Path) -> None:
    cfg = json.loads((session / "session.json").read_text())
    cfg["stage_config"] = {"analyze": {"views": {"enabled": True}}}
    (session / "session.json").write_text(json.dumps(cfg))
    assert stage_status(session)["analyze"] == "stale"  # another config
    reports = run(session)
    assert [r.action for r in reports] == ["skipped"] * 4 + ["ran"]
    manifest = ArtifactStore(session).manifest("analyze")
    assert manifest is not None
    assert {"artifact:track", "artifact:associate"} <= set(manifest.inputs)
