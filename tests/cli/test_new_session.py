"""``cornerman new`` checks every input before it writes anything, and prints what it found."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.io.calibration import save_toml
from tests.conftest import make_rig

runner = CliRunner()


def _calibration(tmp_path: Path, n_views: int = 3) -> Path:
    path = tmp_path / f"calib{n_views}.toml"
    save_toml(make_rig(n_views, fps=50.0), path)  # cameras cam1..camN
    return path


def _video(path: Path, n_frames: int = 5, fps: float = 50.0) -> Path:
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (64, 48))
    for i in range(n_frames):
        vw.write(np.full((48, 64, 3), 30 * i, np.uint8))
    vw.release()
    return path


def _coco(path: Path, n_images: int = 4, with_people: bool = True) -> Path:
    rng = np.random.default_rng(0)
    images = [{"id": i, "file_name": f"frame_{i:04d}.jpg"} for i in range(n_images)]
    anns = []
    if with_people:
        for i in range(n_images):
            kp = np.column_stack([rng.uniform(100, 500, 17), rng.uniform(100, 400, 17), np.full(17, 0.9)])
            anns.append({"image_id": i, "keypoints": kp.ravel().tolist(), "category_id": 1})
    path.write_text(json.dumps({"images": images, "annotations": anns}))
    return path


def _videos(tmp_path: Path, cams: tuple[str, ...] = ("cam1", "cam2", "cam3")) -> list[str]:
    out = []
    for c in cams:
        out += ["--video", f"{c}={_video(tmp_path / f'{c}.avi')}"]
    return out


def test_video_session_with_a_camera_subset_athletes_and_models_dir(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    calib, models = _calibration(tmp_path), tmp_path / "models"
    models.mkdir()
    monkeypatch.setenv("CORNERMAN_MODELS_DIR", str(models))  # no shared models: the summary says what is missing
    monkeypatch.setenv("CORNERMAN_CACHE_DIR", str(tmp_path / "cache"))
    s = tmp_path / "bout"
    r = runner.invoke(app, ["new", str(s), "--calibration", str(calib), *_videos(tmp_path), "--cameras", "cam1,cam3",
                            "--athlete", "Ana", "--athlete", "Bea", "--athlete", "Cy", "--models-dir", str(models)])
    assert r.exit_code == 0, r.output
    d = json.loads((s / "session.json").read_text())
    assert d["cameras"] == ["cam1", "cam3"] and d["athletes"] == ["Ana", "Bea", "Cy"]
    assert d["stage_config"]["detect2d"]["models_dir"] == str(models.resolve())
    assert set(d["videos"]) == {"cam1", "cam2", "cam3"}  # kept; only the listed cameras are read
    assert "cameras: cam1, cam3 (2)" in r.output and "not used (--cameras): cam2" in r.output
    assert "frames: 5; fps: 50 (from the calibration)" in r.output
    assert "athletes: Ana, Bea, Cy (3 persons)" in r.output
    assert "deg apart" not in r.output  # cam1 and cam3 stand a third of a turn apart: no layout advice
    from pipeline.stages.detect2d import Detect2DConfig

    assert f"missing person detector (detector): {Detect2DConfig().detector}" in r.output

    from pipeline.io.session_rig import session_rig
    from pipeline.schema.session import SessionConfig

    rig = session_rig(s, SessionConfig.load(s))
    assert rig.names == ("cam1", "cam3")


def test_keypoint_session_summary(tmp_path: Path) -> None:
    calib = _calibration(tmp_path, 2)
    kps = [a for c in ("cam1", "cam2") for a in ("--keypoints", f"{c}={_coco(tmp_path / f'{c}.json')}")]
    s = tmp_path / "bout"
    r = runner.invoke(app, ["new", str(s), "--calibration", str(calib), *kps, "--keypoint-format", "coco"])
    assert r.exit_code == 0, r.output
    assert json.loads((s / "session.json").read_text())["athletes"] == ["Red", "Blue"]
    assert "frames: 4" in r.output and "athletes: Red, Blue (2 persons)" in r.output
    # The two calibrated cameras stand on opposite sides of the ring: the summary says so.
    assert "cam1 and cam2 look" in r.output and "(facing each other)" in " ".join(r.output.split())


def _bad_cases(tmp_path: Path) -> dict[str, tuple[list[str], list[str]]]:
    """name -> (arguments after the session folder, fragments the error must contain)."""
    calib = str(_calibration(tmp_path))
    a, b = _video(tmp_path / "a.avi"), _video(tmp_path / "b.avi")
    broken = tmp_path / "broken.avi"
    broken.write_text("not a video")
    empty_calib = tmp_path / "empty.toml"
    empty_calib.write_text("")
    empty_coco = tmp_path / "empty.json"
    empty_coco.write_text(json.dumps({"images": [], "annotations": []}))
    nobody = _coco(tmp_path / "nobody.json", with_people=False)
    good = _coco(tmp_path / "good.json")
    return {
        "duplicate camera": (["--calibration", calib, "--video", f"cam1={a}", "--video", f"cam1={b}"], ["cam1", "given twice"]),
        "unknown --cameras": ([*_videos(tmp_path), "--calibration", calib, "--cameras", "cam1,camX"],
                              ["camX", "not in the calibration", "'cam1', 'cam2', 'cam3'"]),
        "one camera selected": ([*_videos(tmp_path), "--calibration", calib, "--cameras", "cam1"], [">= 2 views"]),
        "one-camera calibration": (["--calibration", str(_calibration(tmp_path, 1)), "--video", f"cam1={a}"],
                                   [">= 2 views", "--cameras"]),
        "camera not calibrated": ([*_videos(tmp_path), "--video", f"camZ={a}", "--calibration", calib],
                                  ["camZ", "does not have"]),
        "camera without video": ([*_videos(tmp_path, ("cam1", "cam2")), "--calibration", calib],
                                 ["cam3", "no --video", "--cameras cam1,cam2"]),
        "broken video": ([*_videos(tmp_path, ("cam1", "cam2")), "--video", f"cam3={broken}", "--calibration", calib],
                         [str(broken)]),
        "unreadable calibration": (["--calibration", str(empty_calib), *_videos(tmp_path)], [str(empty_calib)]),
        "empty COCO file": (["--calibration", calib, "--keypoint-format", "coco", "--keypoints", f"cam1={good}",
                             "--keypoints", f"cam2={empty_coco}", "--keypoints", f"cam3={good}"],
                            [str(empty_coco), "no frames"]),
        "COCO file without persons": (["--calibration", calib, "--keypoint-format", "coco", "--keypoints", f"cam1={good}",
                                       "--keypoints", f"cam2={nobody}", "--keypoints", f"cam3={good}"],
                                      [str(nobody), "no person"]),
        "same athlete twice": (["--calibration", calib, *_videos(tmp_path), "--athlete", "A", "--athlete", "A"],
                               ["--athlete"]),
        "models dir missing": (["--calibration", calib, *_videos(tmp_path), "--models-dir", str(tmp_path / "nope")],
                               ["--models-dir", "not a folder"]),
        "folder of several calibrations": (["--calibration", str(tmp_path), *_videos(tmp_path)],
                                       [str(tmp_path), "several calibration files (calib1.toml, calib3.toml, empty.toml)"]),
    }


CASES = (
    "duplicate camera", "unknown --cameras", "one camera selected", "one-camera calibration", "camera not calibrated",
    "camera without video", "broken video", "unreadable calibration", "empty COCO file", "COCO file without persons",
    "same athlete twice", "models dir missing", "folder of several calibrations",
)  # fmt: skip


@pytest.mark.parametrize("case", CASES)
def test_bad_input_is_a_clear_error_and_nothing_is_written(tmp_path: Path, case: str) -> None:
    args, fragments = _bad_cases(tmp_path)[case]
    s = tmp_path / "bout"
    r = runner.invoke(app, ["new", str(s), *args])
    assert r.exit_code == 2, r.output
    assert r.output.startswith("error:") and "Traceback" not in r.output
    for f in fragments:
        assert f in r.output, (f, r.output)
    assert not s.exists()


def test_an_existing_session_is_not_overwritten(tmp_path: Path) -> None:
    calib = str(_calibration(tmp_path))
    s = tmp_path / "bout"
    assert runner.invoke(app, ["new", str(s), "--calibration", calib, *_videos(tmp_path)]).exit_code == 0
    before = (s / "session.json").read_text()
    r = runner.invoke(app, ["new", str(s), "--calibration", calib, *_videos(tmp_path), "--athlete", "X"])
    assert r.exit_code == 2 and "exists already" in r.output
    assert (s / "session.json").read_text() == before


def test_a_folder_holding_one_calibration_file_stands_for_it(tmp_path: Path) -> None:
    """As the Pose2Sim sample ships it: ``calibration/Calib.qca.txt``; session.json names the file."""
    folder = tmp_path / "calibration"
    folder.mkdir()
    calib = _calibration(folder)
    s = tmp_path / "bout"
    r = runner.invoke(app, ["new", str(s), "--calibration", str(folder), *_videos(tmp_path)])
    assert r.exit_code == 0, r.output
    assert json.loads((s / "session.json").read_text())["calibration"] == str(calib.resolve())


def test_a_folder_of_videos_named_after_the_cameras(tmp_path: Path) -> None:
    """As a Pose2Sim project keeps them (``videos/cam01.mp4`` ...): one video per calibrated camera."""
    calib, videos = _calibration(tmp_path), tmp_path / "videos"
    videos.mkdir()
    for c in ("cam1", "cam2", "cam3"):
        _video(videos / f"{c}.avi")
    (videos / "notes.txt").write_text("not a video")
    s = tmp_path / "bout"
    r = runner.invoke(app, ["new", str(s), "--calibration", str(calib), "--video", str(videos)])
    assert r.exit_code == 0, r.output
    d = json.loads((s / "session.json").read_text())
    assert d["videos"] == {c: str((videos / f"{c}.avi").resolve()) for c in ("cam1", "cam2", "cam3")}
    assert "cameras: cam1, cam2, cam3 (3)" in r.output


def test_a_folder_of_keypoints_matches_cameras_by_loose_name(tmp_path: Path) -> None:
    """As Shelf ships them: ``keypoints2d/cam0`` ... for calibrated cameras ``cam_0`` ...; here COCO
    files ``CAM_01.json`` and ``cam-2.json`` stand for calibrated ``cam1`` and ``cam2``."""
    calib, folder = _calibration(tmp_path, 2), tmp_path / "coco"
    folder.mkdir()
    _coco(folder / "CAM_01.json")
    _coco(folder / "cam-2.json")
    s = tmp_path / "bout"
    r = runner.invoke(app, ["new", str(s), "--calibration", str(calib), "--keypoints", str(folder),
                            "--keypoint-format", "coco", "--fps", "25"])  # fmt: skip
    assert r.exit_code == 0, r.output
    assert "fps: 25 (from --fps)" in r.output
    d = json.loads((s / "session.json").read_text())
    assert d["keypoints"] == {"cam1": str(folder / "CAM_01.json"), "cam2": str(folder / "cam-2.json")}


@pytest.mark.parametrize(
    "case", ["empty folder", "camera missing", "unknown camera", "folder and pairs", "ambiguous", "twice"]
)
def test_a_bad_input_folder_is_a_clear_error(tmp_path: Path, case: str) -> None:
    calib, videos = _calibration(tmp_path), tmp_path / "videos"
    videos.mkdir()
    cams = {"empty folder": (), "camera missing": ("cam1", "cam2"), "unknown camera": ("cam1", "cam2", "cam3", "side"),
            "folder and pairs": ("cam1", "cam2", "cam3"), "ambiguous": ("cam1", "cam2", "cam3"),
            "twice": ("cam1", "cam2", "cam3", "cam_03")}[case]  # fmt: skip
    for c in cams:
        _video(videos / f"{c}.avi")
    if case == "ambiguous":  # a calibration with cameras cam1 and cam_1: "CAM1" could be either
        rig = make_rig(2, fps=50.0)
        save_toml(replace(rig, names=("cam1", "cam_1")), calib)
        (videos / "cam1.avi").rename(videos / "CAM1.avi")
    extra = ["--video", f"cam1={videos / 'cam1.avi'}"] if case == "folder and pairs" else []
    s = tmp_path / "bout"
    r = runner.invoke(app, ["new", str(s), "--calibration", str(calib), "--video", str(videos), *extra])
    assert r.exit_code == 2, r.output
    where = str(videos.resolve())
    expected = {"empty folder": ["no video (.mp4", where],
                "camera missing": ["['cam3']", f"no input in --video {where}", "--cameras cam1,cam2"],
                "unknown camera": ["['side']", "named after no camera", "'cam1', 'cam2', 'cam3'"],
                "folder and pairs": ["only --video value"],
                "ambiguous": ["'CAM1' could stand for cameras ['cam1', 'cam_1']"],
                "twice": ["two inputs for camera 'cam3'", "cam_03"]}[case]  # fmt: skip
    for f in expected:
        assert f in " ".join(r.output.split()), (f, r.output)
    assert "Traceback" not in r.output and not s.exists()
