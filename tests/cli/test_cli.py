"""The typer CLI on a tiny session: run, status, export, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app
from tests.conftest import write_tiny_session

runner = CliRunner()


def test_run_status_and_errors(tmp_path: Path) -> None:
    s = write_tiny_session(tmp_path / "s", stages=("detect2d", "track", "associate", "triangulate"))
    r = runner.invoke(app, ["run", str(s)])
    assert r.exit_code == 0, r.output
    assert "cornerman pipeline summary" in r.output and "triangulate" in r.output
    r = runner.invoke(app, ["status", str(s)])
    assert r.exit_code == 0 and r.output.count("fresh") == 4
    r = runner.invoke(app, ["export", str(s), "--format", "json", "-o", str(tmp_path / "kp.json")])
    assert r.exit_code == 0, r.output
    d = json.loads((tmp_path / "kp.json").read_text())
    assert d["source"] == "filtered" and len(d["persons"]) == 2 and len(d["persons"][0]["joints"]) == 20
    r = runner.invoke(app, ["export", str(s), "--source", "physics"])
    assert r.exit_code == 2 and "no 3D keypoints" in r.output
    r = runner.invoke(app, ["run", str(tmp_path / "nowhere")])
    assert r.exit_code == 2 and "no session.json" in r.output


def test_new_session_validates_paths(tmp_path: Path) -> None:
    r = runner.invoke(app, ["new", str(tmp_path / "b"), "--calibration", str(tmp_path / "missing.toml"), "--video", "c1=x.mp4"])
    assert r.exit_code == 2 and "calibration not found" in r.output
    calib = tmp_path / "c.toml"
    calib.write_text("")
    r = runner.invoke(app, ["new", str(tmp_path / "b"), "--calibration", str(calib), "--video", "c1=nope.mp4"])
    assert r.exit_code == 2 and "nope.mp4 does not exist" in r.output


def test_bench_unknown_name() -> None:
    r = runner.invoke(app, ["bench", "quantum"])
    assert r.exit_code == 2 and "unknown benchmark" in r.output


def test_bench_writes_its_rows_as_json(tmp_path: Path) -> None:
    out = tmp_path / "rows.json"
    opts = ["--opt", "n_frames=20", "--opt", "scenarios=2 cams", "--opt", "baselines=false", "--opt", "repeats=1"]
    r = runner.invoke(app, ["bench", "triangulation", *opts, "--json", str(out)])
    assert r.exit_code == 0, r.output
    rows = json.loads(out.read_text())
    assert rows and all(isinstance(row, dict) for row in rows)
    assert {row["scenario"] for row in rows} == {"2 cams"} and all(row["mpjpe_mm"] > 0 for row in rows)
    env = json.loads((tmp_path / "rows.env.json").read_text())
    assert env["packages"]["numpy"] == np.__version__ and env["cpus"] >= 1
    (tmp_path / "blocked.env.json").mkdir()  # the sidecar cannot be written: said, rows kept
    r = runner.invoke(app, ["bench", "triangulation", *opts, "--json", str(tmp_path / "blocked.json")])
    assert r.exit_code == 2 and "could not write what they were measured with" in r.output
    kept = json.loads((tmp_path / "blocked.json").read_text())
    assert [(k["method"], k["mpjpe_mm"]) for k in kept] == [(k["method"], k["mpjpe_mm"]) for k in rows]
    r = runner.invoke(app, ["bench", "triangulation", *opts, "--json", str(tmp_path / "no" / "rows.json")])
    assert r.exit_code == 2 and "does not exist" in r.output
    r = runner.invoke(app, ["bench", "triangulation", *opts, "--json", str(tmp_path)])
    assert r.exit_code == 2 and "is a folder" in r.output


def test_export_calibration_and_bad_out_paths(tmp_path: Path) -> None:
    from pipeline.io.calibration import load_calibration

    s = write_tiny_session(tmp_path / "s", stages=("detect2d", "track", "associate", "calibrate", "triangulate"))
    assert runner.invoke(app, ["run", str(s)]).exit_code == 0
    out = tmp_path / "calib.toml"
    r = runner.invoke(app, ["export", str(s), "--calibration", "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert "wrote" in r.output and ("adopted" in r.output or "not" in r.output)
    assert "floor" in r.output and "world" in r.output  # which way is up, where the floor was found, whether the world moved
    rig = load_calibration(out)
    assert rig.names == load_calibration(s / "inputs" / "calibration.toml").names
    for bad, why in ((tmp_path / "missing" / "c.toml", "does not exist"), (tmp_path, "is a folder")):
        r = runner.invoke(app, ["export", str(s), "--calibration", "--out", str(bad)])
        assert r.exit_code == 2 and why in r.output
        r = runner.invoke(app, ["export", str(s), "--out", str(bad)])
        assert r.exit_code == 2 and why in r.output
    assert not list(tmp_path.glob("*.tmp")) and not (tmp_path / "missing").exists()


def _artifacts(session: Path) -> list[Path]:
    return sorted((session / "artifacts").glob("*/manifest.json")) if (session / "artifacts").exists() else []


def test_run_refuses_a_reversed_stage_range_before_any_work(tmp_path: Path) -> None:
    s = write_tiny_session(tmp_path / "s", stages=("detect2d", "track", "associate", "triangulate"))
    r = runner.invoke(app, ["run", str(s), "--from-stage", "triangulate", "--to-stage", "track"])
    assert r.exit_code == 2, r.output
    assert "from-stage 'triangulate' comes after to-stage 'track'" in r.output and "Traceback" not in r.output
    assert _artifacts(s) == []
    from pipeline.runner import run

    with pytest.raises(ValueError, match="nothing would run"):
        run(s, from_stage="triangulate", to_stage="track")


def test_run_with_one_camera_fails_before_the_2d_stages(tmp_path: Path) -> None:
    from pipeline.io.calibration import save_toml
    from tests.conftest import make_rig

    s = write_tiny_session(tmp_path / "s", stages=("detect2d", "track", "associate", "triangulate"))
    save_toml(make_rig(1), s / "inputs" / "calibration.toml")
    r = runner.invoke(app, ["run", str(s)])
    assert r.exit_code == 2, r.output
    assert "a 3D reconstruction needs >= 2 views" in r.output and "--cameras" in r.output
    assert _artifacts(s) == []


def test_run_stores_models_dir_in_session_json(tmp_path: Path) -> None:
    s = write_tiny_session(tmp_path / "s", stages=("detect2d",))
    before = (s / "session.json").read_text()
    r = runner.invoke(app, ["run", str(s), "--models-dir", str(tmp_path / "missing")])
    assert r.exit_code == 2 and "--models-dir" in r.output and "not a folder" in r.output
    assert (s / "session.json").read_text() == before
    models = tmp_path / "models"
    models.mkdir()
    r = runner.invoke(app, ["run", str(s), "--models-dir", str(models)])
    assert r.exit_code == 0, r.output
    d = json.loads((s / "session.json").read_text())
    assert d["stage_config"]["detect2d"]["models_dir"] == str(models.resolve())


def test_a_tracks_session_can_use_a_subset_of_the_cameras(tmp_path: Path) -> None:
    import dataclasses

    from pipeline.artifacts import ArtifactStore
    from pipeline.schema import Detections2D, SessionConfig

    s = write_tiny_session(tmp_path / "s", stages=("detect2d", "track", "associate", "triangulate"))
    cfg = SessionConfig.load(s)
    dataclasses.replace(cfg, cameras=("cam3", "cam1")).save(s)
    r = runner.invoke(app, ["run", str(s)])
    assert r.exit_code == 0, r.output
    dets = ArtifactStore(s).load("detect2d", "detections", Detections2D)
    assert dets.n_views == 2 and set(np.unique(dets.view)) == {0, 1}
    # same number of rows per kept camera as the tracks file has for cam3 and cam1
    from pipeline.schema import Tracks2D, load_npz

    full = load_npz(s / "inputs" / "tracks2d.npz", Tracks2D)
    assert (dets.view == 0).sum() == (full.view == 2).sum() and (dets.view == 1).sum() == (full.view == 0).sum()
    # another selection (even another order) makes every stage stale
    from pipeline.runner import stage_status

    assert set(stage_status(s).values()) == {"fresh"}
    dataclasses.replace(cfg, cameras=("cam1", "cam3")).save(s)
    assert set(stage_status(s).values()) == {"stale"}
