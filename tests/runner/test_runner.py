"""Runner: skips fresh stages, re-runs stale ones, resumes after a kill."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipeline.artifacts import ArtifactStore
from pipeline.runner import run, stage_status
from pipeline.schema import SplitTrack, save_annotations


def test_first_run_then_all_fresh(tiny_session: Path) -> None:
    assert set(stage_status(tiny_session).values()) == {"missing"}
    reports = run(tiny_session)
    assert [r.action for r in reports] == ["ran", "ran"]
    assert set(stage_status(tiny_session).values()) == {"fresh"}
    reports = run(tiny_session)
    assert [r.action for r in reports] == ["skipped", "skipped"]


def test_annotation_makes_consumer_stale_only(tiny_session: Path) -> None:
    run(tiny_session)
    save_annotations(tiny_session / "annotations.json", [SplitTrack(view="cam1", track=0, frame=5)])
    st = stage_status(tiny_session)
    assert st == {"detect2d": "fresh", "track": "stale"}
    reports = run(tiny_session)
    assert [(r.stage, r.action) for r in reports] == [("detect2d", "skipped"), ("track", "ran")]


def test_config_change_and_input_change_make_stale(tiny_session: Path) -> None:
    run(tiny_session)
    cfg = json.loads((tiny_session / "session.json").read_text())
    cfg["stage_config"] = {"track": {"use_source_ids": True}}  # same as default -> same hash
    (tiny_session / "session.json").write_text(json.dumps(cfg))
    assert set(stage_status(tiny_session).values()) == {"fresh"}
    cfg["stage_config"] = {"detect2d": {"min_keypoint_conf": 0.5}}
    (tiny_session / "session.json").write_text(json.dumps(cfg))
    assert stage_status(tiny_session) == {"detect2d": "stale", "track": "stale"}
    run(tiny_session)
    # Touching the input file with different bytes makes detect2d stale.
    calib = tiny_session / "inputs/calibration.toml"
    calib.write_text(calib.read_text() + "\n# edited\n")
    assert stage_status(tiny_session)["detect2d"] == "stale"


def test_a_new_frame_rate_makes_the_tracking_stale(tiny_session: Path) -> None:
    """The resolved frame rate is an input of track (it can change with no file changing)."""
    run(tiny_session)
    cfg = json.loads((tiny_session / "session.json").read_text())
    cfg["fps"] = 25.0
    (tiny_session / "session.json").write_text(json.dumps(cfg))
    assert stage_status(tiny_session) == {"detect2d": "fresh", "track": "stale"}
    reports = run(tiny_session)
    assert [(r.stage, r.action) for r in reports] == [("detect2d", "skipped"), ("track", "ran")]
    assert ArtifactStore(tiny_session).manifest("track").inputs["rig_fps"] == "25.0"


def test_from_stage_forces_rerun(tiny_session: Path) -> None:
    run(tiny_session)
    reports = run(tiny_session, from_stage="track")
    assert [(r.stage, r.action) for r in reports] == [("detect2d", "skipped"), ("track", "ran")]
    with pytest.raises(ValueError, match="not an enabled stage"):
        run(tiny_session, from_stage="physics")


def test_force_with_from_stage_forces_that_stage_on_only(tiny_session: Path) -> None:
    run(tiny_session)
    reports = run(tiny_session, from_stage="track", force=True)
    assert [(r.stage, r.action) for r in reports] == [("detect2d", "skipped"), ("track", "ran")]
    reports = run(tiny_session, force=True)
    assert [(r.stage, r.action) for r in reports] == [("detect2d", "ran"), ("track", "ran")]


def test_bad_stage_config_is_a_clear_error(tiny_session: Path) -> None:
    cfg = json.loads((tiny_session / "session.json").read_text())
    cfg["stage_config"] = {"track": {"nonsense": 1}}
    (tiny_session / "session.json").write_text(json.dumps(cfg))
    where = re.escape(str(tiny_session / "session.json"))
    with pytest.raises(ValueError, match=rf"^{where}: stage_config.track has unknown keys"):
        run(tiny_session)


def test_a_wrong_type_in_stage_config_names_the_key_before_any_stage_runs(tiny_session: Path) -> None:
    run(tiny_session)
    store = ArtifactStore(tiny_session)
    before = {s: store.manifest(s) for s in ("detect2d", "track")}
    cfg = json.loads((tiny_session / "session.json").read_text())
    # detect2d goes stale (new threshold), and track, the later stage, holds a string for a number:
    # the error comes first, so detect2d is not re-run and nothing is rewritten.
    cfg["stage_config"] = {"detect2d": {"min_keypoint_conf": 0.5}, "track": {"sync_tolerance_frames": "two"}}
    (tiny_session / "session.json").write_text(json.dumps(cfg))
    with pytest.raises(ValueError, match=r"session\.json: stage_config\.track\.sync_tolerance_frames must be float, "
                                         r"got 'two' \(str\)"):  # fmt: skip
        run(tiny_session)
    assert {s: store.manifest(s) for s in ("detect2d", "track")} == before
    # Only the stages up to to_stage are built: the same session runs to detect2d.
    assert [r.stage for r in run(tiny_session, to_stage="detect2d")] == ["detect2d"]
    cfg["stage_config"] = {"trak": {"use_source_ids": True}}  # a typo must not be ignored silently
    (tiny_session / "session.json").write_text(json.dumps(cfg))
    where = re.escape(str(tiny_session / "session.json"))  # the file is named, not just "session.json"
    with pytest.raises(ValueError, match=rf"^{where}: stage_config has unknown stages \['trak'\]"):
        run(tiny_session)
    with pytest.raises(ValueError, match=rf"^{where}: stage_config has unknown stages \['trak'\]"):
        stage_status(tiny_session)


def test_missing_input_file_names_it(tiny_session: Path) -> None:
    (tiny_session / "inputs/tracks2d.npz").unlink()
    with pytest.raises(ValueError, match="tracks2d.npz"):
        run(tiny_session)


KILLER = r"""
import sys, time
from pipeline.runner import run
class Sink:
    def stage_started(self, stage, total):
        if stage == "track":
            print("TRACK", flush=True)
            time.sleep(60)
    def stage_progress(self, *a): pass
    def stage_finished(self, *a): pass
run(sys.argv[1], progress=Sink())
"""


def test_kill_mid_pipeline_then_resume(tiny_session: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-c", KILLER, str(tiny_session)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    deadline, line = time.time() + 120, ""
    while time.time() < deadline and "TRACK" not in line:
        line = proc.stdout.readline()
    assert "TRACK" in line
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)
    store = ArtifactStore(tiny_session)
    before = store.manifest("detect2d")
    assert before is not None and store.manifest("track") is None
    reports = run(tiny_session)
    assert [(r.stage, r.action) for r in reports] == [("detect2d", "skipped"), ("track", "ran")]
    assert store.manifest("detect2d") == before


def test_evaluate_ignores_artifacts_of_a_stage_the_session_no_longer_runs(tmp_path: Path) -> None:
    import dataclasses

    from pipeline.schema import SessionConfig
    from tests.conftest import write_tiny_session

    s = write_tiny_session(tmp_path / "s", stages=("detect2d", "track", "associate", "triangulate", "evaluate"))
    run(s)
    store = ArtifactStore(s)
    metrics = json.loads(store.path("evaluate", "metrics.json").read_text())
    assert set(metrics["sources"]) == {"raw", "filtered"}
    # A physics artifact left over (here: a copy of the filtered keypoints) from a session
    # that ran physics once, then dropped it from its stages.
    from pipeline.artifacts import Manifest
    from pipeline.schema.keypoints3d import Keypoints3D

    kp = store.load("triangulate", "keypoints3d", Keypoints3D)
    store.write(Manifest(stage="physics", code_version="old", config={}, config_hash="0", inputs={}), {"keypoints3d": kp.replace(source="physics")})
    cfg = SessionConfig.load(s)
    dataclasses.replace(cfg, stage_config={"evaluate": {"penetration_high_mm": 25.0}}).save(s)  # evaluate goes stale
    run(s)
    metrics = json.loads(store.path("evaluate", "metrics.json").read_text())
    assert set(metrics["sources"]) == {"raw", "filtered"}
