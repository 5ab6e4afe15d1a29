"""The session's frame rate: session.fps, else the calibration's stored rate, else the
videos' (Qualisys, EasyMocap and JSON calibrations store none), else 30 fps."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.artifacts import ArtifactStore
from pipeline.io.calibration import load_calibration, save_toml
from pipeline.io.session_rig import session_rig, stored_fps
from pipeline.runner.spec import StageContext
from pipeline.schema.session import SessionConfig

QCA = Path(__file__).resolve().parents[1] / "data" / "io" / "qualisys" / "Calib.qca.txt"


def _video(path: Path, fps: float) -> str:
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (64, 48))
    for i in range(3):
        vw.write(np.full((48, 64, 3), 40 * i, np.uint8))
    vw.release()
    return str(path)


def _session(tmp_path: Path, rates: list[float], calibration: Path = QCA, fps: float = 0.0) -> SessionConfig:
    videos = {f"cam{i + 1}": _video(tmp_path / f"cam{i + 1}.avi", r) for i, r in enumerate(rates)}
    return SessionConfig(name="s", source="video", calibration=str(calibration), videos=videos, fps=fps)


def test_videos_set_the_rate_when_the_calibration_stores_none(tmp_path: Path) -> None:
    assert stored_fps(QCA) is None
    assert load_calibration(QCA).fps == 30.0
    assert session_rig(tmp_path, _session(tmp_path, [60.0, 60.0])).fps == pytest.approx(60.0)


def test_session_fps_wins_and_disagreeing_videos_keep_the_default(tmp_path: Path) -> None:
    assert session_rig(tmp_path, _session(tmp_path, [60.0, 60.0], fps=25.0)).fps == 25.0
    assert session_rig(tmp_path, _session(tmp_path, [60.0, 50.0])).fps == 30.0
    kp = SessionConfig(name="k", source="keypoints", calibration=str(QCA), keypoints={"cam1": str(tmp_path)})
    assert session_rig(tmp_path, kp).fps == 30.0


def test_a_stored_calibration_rate_wins_over_the_videos(tmp_path: Path) -> None:
    toml = tmp_path / "calib.toml"
    save_toml(load_calibration(QCA, fps=50.0), toml)
    assert stored_fps(toml) == 50.0
    assert session_rig(tmp_path, _session(tmp_path, [60.0], calibration=toml)).fps == 50.0
    # The same file without the [metadata] rate: the videos' rate.
    bare = tmp_path / "bare.toml"
    bare.write_text("\n".join(ln for ln in toml.read_text().splitlines() if not ln.startswith("fps")))
    assert stored_fps(bare) is None
    assert session_rig(tmp_path, _session(tmp_path, [60.0], calibration=bare)).fps == pytest.approx(60.0)


def test_the_pipeline_runs_the_pose2sim_videos_at_their_60_fps(tmp_path: Path, test_data_dir: Path) -> None:
    data = test_data_dir / "pose2sim_multiperson"
    if not data.is_dir():
        pytest.skip(f"{data} not present in CORNERMAN_TEST_DATA_DIR")
    videos = {p.stem: str(p) for p in sorted((data / "videos").glob("*.mp4"))}
    cfg = SessionConfig(
        name="p2s", source="video", calibration=str(data / "calibration" / "Calib.qca.txt"), videos=videos
    )
    cfg.save(tmp_path)
    ctx = StageContext(session_dir=tmp_path, session=cfg, store=ArtifactStore(tmp_path), stage="detect2d")
    assert ctx.rig.fps == pytest.approx(60.0, rel=1e-3)


def test_session_cameras_select_and_order_a_subset(tmp_path: Path) -> None:
    from dataclasses import replace

    full = load_calibration(QCA)
    # the rate comes from the selected cameras' videos only (the unused one disagrees)
    videos = {n: _video(tmp_path / f"{n}.avi", r) for n, r in zip(full.names[:3], (60.0, 25.0, 60.0), strict=True)}
    cfg = SessionConfig(name="s", source="video", calibration=str(QCA), videos=videos)
    want = (full.names[2], full.names[0])
    rig = session_rig(tmp_path, replace(cfg, cameras=want))
    assert rig.names == want and np.allclose(rig.K[0], full.K[2]) and rig.fps == pytest.approx(60.0)
    with pytest.raises(ValueError) as e:
        session_rig(tmp_path, replace(cfg, cameras=(full.names[0], "nope")))
    assert "'nope'" in str(e.value) and str(QCA) in str(e.value) and all(n in str(e.value) for n in full.names)


def test_session_cameras_must_be_two_or_more_distinct_names() -> None:
    base = {"name": "s", "source": "tracks", "calibration": "c.toml", "tracks": "t.npz"}
    with pytest.raises(ValueError, match=">= 2 views"):
        SessionConfig(**base, cameras=("cam1",))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="more than once"):
        SessionConfig(**base, cameras=("cam1", "cam1"))  # type: ignore[arg-type]
    cfg = SessionConfig.from_dict({**base, "cameras": ["cam2", "cam1"]})
    assert cfg.cameras == ("cam2", "cam1") and SessionConfig.from_dict(json.loads(cfg.to_json())) == cfg
