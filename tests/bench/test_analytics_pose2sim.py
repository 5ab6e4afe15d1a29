"""``bench analytics``' Pose2Sim row: where its session comes from (``pose2sim_session``; the
``bench footage`` folder in the system temp dir, here redirected to tmp_path) and its count."""

from __future__ import annotations

import logging
import tempfile
from pathlib import Path

import numpy as np
import pytest

from pipeline.artifacts import ArtifactStore, Manifest
from pipeline.bench import analytics, footage
from pipeline.bench.footage import SESSION_NAME
from pipeline.schema.session import SessionConfig
from tests.conftest import write_tiny_session
from tests.stages.analyze_fixtures import keypoints, profile, straight, throw, two_boxers

CAMERA = """    <camera active="1" avg-residual="0.4" model="none" point-count="1" serial="{name}" viewrotation="0">
      <fov_marker bottom="1919" left="0" right="1087" top="0"/>
      <fov_marker_max bottom="1919" left="0" right="1087" top="0"/>
      <fov_video bottom="1919" left="0" right="1087" top="0"/>
      <fov_video_max bottom="1919" left="0" right="1087" top="0"/>
      <transform r11="1" r12="0" r13="0" r21="0" r22="0" r23="1" r31="0" r32="-1" r33="0" x="{x}" y="-3000" z="1500"/>
      <intrinsic centerPointU="34110" centerPointV="60680" focalLengthU="107599" focalLengthV="107588"
        focallength="9.3" radialDistortion1="0" radialDistortion2="0" radialDistortion3="0" sensorMaxU="69568"
        sensorMaxV="122816" sensorMinU="0" sensorMinV="0" skew="0" tangentalDistortion1="0" tangentalDistortion2="0"/>
    </camera>
"""


@pytest.fixture
def elsewhere(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The system temp dir, the shared data, the models and the cache, all under tmp_path."""
    for name in ("tmp", "data", "models", "cache"):
        (tmp_path / name).mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    monkeypatch.delenv("CORNERMAN_SHARED_DIR", raising=False)
    monkeypatch.setenv("CORNERMAN_TEST_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setenv("CORNERMAN_MODELS_DIR", str(tmp_path / "models"))
    monkeypatch.setenv("CORNERMAN_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path


def _fake_sample(data: Path) -> None:
    """A Pose2Sim-like sample: a 2-camera Qualisys calibration and (empty) videos."""
    root = data / "pose2sim_multiperson"
    (root / "calibration").mkdir(parents=True)
    (root / "videos").mkdir()
    cams = "".join(CAMERA.format(name=n, x=x) for n, x in (("cam01", -1000), ("cam02", 1000)))
    (root / "calibration" / "Calib.qca.txt").write_text(
        f"<?xml version='1.0' encoding='ASCII'?>\n<calibration type=\"regular\">\n  <cameras>\n{cams}  </cameras>\n</calibration>\n"
    )
    for n in ("cam01", "cam02"):
        (root / "videos" / f"{n}.mp4").write_bytes(b"")


def test_the_footage_folder_is_looked_up_in_the_system_temp_dir(elsewhere: Path) -> None:
    assert analytics.footage_work_dir() == elsewhere / "tmp" / footage.DEFAULT_DIR_NAME


def test_no_sample_skips_the_row_with_the_reason(elsewhere: Path, caplog: pytest.LogCaptureFixture) -> None:
    folder, why = analytics.pose2sim_session()
    assert folder is None and "pose2sim_multiperson" in why and str(elsewhere / "data") in why
    with caplog.at_level(logging.WARNING, logger="pipeline.bench.analytics"):
        assert analytics.run_bench(seeds=[], cameras=4, sources="gt") == []
    assert "Pose2Sim row skipped" in caplog.text and "pose2sim_multiperson" in caplog.text
    assert not (elsewhere / "tmp" / footage.DEFAULT_DIR_NAME).exists()


def test_no_models_skips_the_row_after_setting_up_the_footage_session(elsewhere: Path) -> None:
    _fake_sample(elsewhere / "data")
    folder, why = analytics.pose2sim_session()
    assert folder is None and "2D models" in why and "rtmdet_nano" in why
    made = elsewhere / "tmp" / footage.DEFAULT_DIR_NAME
    assert SessionConfig.load(made).name == SESSION_NAME  # the session bench footage would make, in temp
    assert not list(made.glob("artifacts/*/manifest.json"))  # no stage ran


def test_a_folder_holding_another_session_is_refused(elsewhere: Path) -> None:
    _fake_sample(elsewhere / "data")
    other = elsewhere / "tmp" / footage.DEFAULT_DIR_NAME
    other.mkdir()
    SessionConfig(name="my bout", source="tracks", calibration="calib.toml", tracks="t.npz").save(other)
    with pytest.raises(ValueError, match="my bout"):
        analytics.pose2sim_session()
    with pytest.raises(ValueError, match="no session.json"):
        analytics.pose2sim_session(str(elsewhere / "nowhere"))


def test_a_given_session_is_read_as_it_is(tmp_path: Path) -> None:
    """Two boxers 1 m apart for 4 s: a fist swinging up from the hip and one jab at the head:
    one punch in 4 s = 15 / min, from the fit."""
    n = 200
    xyz = two_boxers(n, distance_m=1.0)
    throw(xyz, 0, "left", profile(n, 0.6, 0.12), straight(np.array([0.05, 0.2, 1.0]), np.array([0.45, 0.15, 1.3])))
    throw(xyz, 0, "right", profile(n, 2.5, 0.1), straight(np.array([0.2, -0.1, 1.48]), np.array([0.62, -0.02, 1.6])))
    given = write_tiny_session(tmp_path / "given")  # a 3-camera rig
    kp = keypoints(xyz)
    ArtifactStore(given).write(
        Manifest(stage="fit", code_version="test", config={}, config_hash="0", inputs={}), {"keypoints3d": kp}
    )
    folder, why = analytics.pose2sim_session(str(given))
    assert folder == given and why == ""
    row = analytics.pose2sim_row(folder)
    assert row is not None and row["data"] == "Pose2Sim sample (fit)" and row["frames"] == n
    assert row["cameras"] == 3
    assert row["detected"] == 1 and row["false_per_min"] == pytest.approx(1 / (n / kp.fps / 60.0))
