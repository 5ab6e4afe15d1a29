"""The analyze stage in the runner: registered after physics, artifacts written and read back,
re-run when its input or config changes."""

from __future__ import annotations

import json
from pathlib import Path

from pipeline.io.events_export import load_analytics
from pipeline.runner import STAGE_ORDER, run, stage_status
from tests.conftest import write_tiny_session

STAGES = ("detect2d", "track", "associate", "triangulate", "analyze")


def test_analyze_is_registered_between_physics_and_evaluate() -> None:
    assert (
        STAGE_ORDER.index("physics") + 1 == STAGE_ORDER.index("analyze") == STAGE_ORDER.index("evaluate") - 1
    )


def test_analyze_step_writes_events_and_series(tmp_path: Path) -> None:
    s = write_tiny_session(tmp_path / "s", stages=STAGES, n_frames=30)
    reports = run(s)
    last = reports[-1]
    assert last.stage == "analyze" and last.action == "ran"
    assert last.metrics["source"] == "filtered" and "punches" in last.metrics and "clinches" in last.metrics
    events, series, source = load_analytics(s)
    assert source == "filtered" and events.person_ids.tolist() == [0, 1]
    assert series.n_frames == 30 and series.guard_height_m.shape == (30, 2, 2)
    assert stage_status(s)["analyze"] == "fresh"
    cfg = json.loads((s / "session.json").read_text())
    cfg["stage_config"] = {"analyze": {"punch": {"min_excursion_m": 0.3}}}
    (s / "session.json").write_text(json.dumps(cfg))
    assert stage_status(s) == {**{k: "fresh" for k in STAGES[:-1]}, "analyze": "stale"}
    assert [r.action for r in run(s)] == ["skipped"] * 4 + ["ran"]


def test_the_flattened_option_hands_the_filtered_triangulation_to_the_stage(
    tmp_path: Path, monkeypatch
) -> None:
    """With ``punch.flattened`` the step loads the filtered triangulation beside the analysed
    fit; without it, it does not (a stand-in context whose fit is the filtered result)."""
    from types import SimpleNamespace

    import pipeline.runner.steps.analyze as step
    from pipeline.artifacts import ArtifactStore
    from pipeline.stages.analyze import AnalyzeConfig
    from pipeline.stages.analyze.config import PunchConfig

    s = write_tiny_session(tmp_path / "s", stages=STAGES, n_frames=30)
    run(s)
    store = ArtifactStore(s)
    artifacts = {
        "fit/keypoints3d.npz": ("triangulate", "keypoints3d"),
        "triangulate/keypoints3d.npz": ("triangulate", "keypoints3d"),
        "triangulate/raw.npz": ("triangulate", "raw"),
    }
    ctx = SimpleNamespace(
        session=SimpleNamespace(stages=list(STAGES) + ["fit"]),
        annotations=[],
        metrics={},
        session_dir=s,
        has=lambda st, f: f"{st}/{f}" in artifacts,
        load=lambda st, art, cls: store.load(*artifacts[f"{st}/{art}.npz"], cls),
    )
    seen: list = []
    real = step.run
    monkeypatch.setattr(step, "run", lambda inputs, cfg: seen.append(inputs) or real(inputs, cfg))
    step._execute(ctx, AnalyzeConfig(punch=PunchConfig(flattened=True)))
    assert (
        ctx.metrics["source"] == "fit"
        and seen[-1].filtered is not None
        and seen[-1].filtered.source == "filtered"
    )
    step._execute(ctx, AnalyzeConfig())
    assert seen[-1].filtered is None
