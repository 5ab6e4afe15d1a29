"""Calibration importers on real files (tests/data/io, see SOURCES.md), TOML round trips,
cross-format consistency and the error cases."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.geometry import project
from pipeline.io.calibration import calibration_format, load_calibration, rotate_images_cw, save_toml
from pipeline.io.calibration_easymocap import load_easymocap, save_easymocap
from pipeline.io.calibration_json import load_json_calibration
from pipeline.io.calibration_toml import load_toml
from pipeline.schema.camera import CameraRig

DATA = Path(__file__).resolve().parents[1] / "data" / "io"
TOML = DATA / "pose2sim" / "Calib_qualisys.toml"
QCA = DATA / "qualisys" / "Calib.qca.txt"
EASYMOCAP = DATA / "easymocap"
SHELF = DATA / "shelf" / "calibration.json"
ALL_FILES = [TOML, QCA, EASYMOCAP, SHELF]


def assert_same_rig(a: CameraRig, b: CameraRig, tol: float = 1e-9) -> None:
    assert a.names == b.names
    np.testing.assert_allclose(a.K, b.K, atol=tol, rtol=0)
    np.testing.assert_allclose(a.dist, b.dist, atol=tol, rtol=0)
    np.testing.assert_allclose(a.T_world_cam, b.T_world_cam, atol=tol, rtol=0)
    np.testing.assert_array_equal(a.image_size_wh, b.image_size_wh)
    assert a.fps == pytest.approx(b.fps)


def test_pose2sim_toml_real_file() -> None:
    rig = load_calibration(TOML)
    assert rig.names == ("cam_01", "cam_02", "cam_03", "cam_04")
    np.testing.assert_array_equal(rig.image_size_wh, [[1088, 1920]] * 4)
    assert rig.K[0, 0, 0] == pytest.approx(1681.244873046875)
    # Pose2Sim stores 4 distortion coefficients; k3 is padded with 0.
    np.testing.assert_allclose(rig.dist[0], [-0.000721609375, 0.002187234375, 9.5e-06, 1.078125e-05, 0.0])
    # Camera centres 1.7-2.1 m above the floor (z up, metres), 2.5-4.5 m from the origin.
    c = rig.centers_world_m
    assert np.all((c[:, 2] > 1.5) & (c[:, 2] < 2.2)), c
    assert np.all((np.linalg.norm(c[:, :2], axis=1) > 2.0) & (np.linalg.norm(c[:, :2], axis=1) < 4.5)), c


def test_qualisys_fixture_matches_pose2sims_own_conversion() -> None:
    """The Qualisys file of Pose2Sim's demo and the TOML Pose2Sim converted it to agree."""
    a, b = load_calibration(QCA), load_calibration(TOML)
    assert_same_rig(a, b, tol=1e-9)
    X = np.array([[0.3, -0.2, 1.0], [-1.0, 0.5, 0.1], [0.0, 0.0, 1.8]])
    uv_a, _ = project(a, X)
    uv_b, _ = project(b, X)
    assert np.abs(uv_a - uv_b).max() < 1e-6


def test_easymocap_real_files_folder_and_either_file() -> None:
    rigs = [load_calibration(p) for p in (EASYMOCAP, EASYMOCAP / "intri.yml", EASYMOCAP / "extri.yml")]
    for r in rigs[1:]:
        assert_same_rig(rigs[0], r, tol=0.0)
    rig = rigs[0]
    assert rig.names == ("2", "3", "4", "5", "6", "7")
    assert rig.K[0, 0, 0] == pytest.approx(1270.5470221290213)
    # No size in EasyMocap files: estimated from the principal point (960, 540).
    np.testing.assert_array_equal(rig.image_size_wh, [[1920, 1080]] * 6)
    # R_ (Rodrigues) and Rot_ agree; the loader uses Rot_: check against R_ here.
    fs = cv2.FileStorage(str(EASYMOCAP / "extri.yml"), cv2.FILE_STORAGE_READ)
    R2, _ = cv2.Rodrigues(fs.getNode("R_2").mat())
    T2 = fs.getNode("T_2").mat().ravel()
    fs.release()
    np.testing.assert_allclose(rig.T_cam_world[0, :3, :3], R2, atol=1e-6)
    np.testing.assert_allclose(rig.T_cam_world[0, :3, 3], T2, atol=1e-12)
    assert np.all((rig.centers_world_m[:, 2] > 1.0) & (rig.centers_world_m[:, 2] < 2.0))


def test_easymocap_image_size_argument(tmp_path: Path) -> None:
    rig = load_easymocap(EASYMOCAP, image_size_wh=(1280, 720))
    np.testing.assert_array_equal(rig.image_size_wh, [[1280, 720]] * 6)
    with pytest.raises(ValueError, match="no entry for camera '2'"):
        load_easymocap(EASYMOCAP, image_size_wh={"3": (1920, 1080)})


def test_shelf_json_real_file() -> None:
    rig = load_calibration(SHELF)
    assert rig.names == ("0", "1", "2", "3", "4")
    np.testing.assert_array_equal(rig.image_size_wh, [[1032, 776]] * 5)
    raw = json.loads(SHELF.read_text())["0"]
    RT = np.array(raw["RT"]).reshape(3, 4)
    # The file's float32 rotation is projected onto SO(3): within 1e-6 of the stored numbers.
    np.testing.assert_allclose(rig.T_cam_world[0, :3, :], RT, atol=2e-6)
    assert np.all((rig.centers_world_m[:, 2] > 0.8) & (rig.centers_world_m[:, 2] < 3.0))
    # Shelf is z-up: every camera's image "down" (+y) points down in the world.
    assert np.all(rig.T_world_cam[:, 2, 1] < -0.3)


def test_json_r_t_rodrigues_and_list_variants_match_rt(tmp_path: Path) -> None:
    ref = load_calibration(SHELF)
    T_cw = ref.T_cam_world
    cams = []
    for v, n in enumerate(ref.names):
        cam = {
            "name": n,
            "K": ref.K[v].tolist(),
            "width": 1032,
            "height": 776,
            "dist": [0.1, -0.05, 0.001, 0.0],
        }
        if v % 2:
            cam |= {"R": T_cw[v, :3, :3].tolist(), "t": T_cw[v, :3, 3].tolist()}
        else:
            cam |= {"R": cv2.Rodrigues(T_cw[v, :3, :3])[0].ravel().tolist(), "T": T_cw[v, :3, 3].tolist()}
        cams.append(cam)
    p = tmp_path / "cams.json"
    p.write_text(json.dumps(cams))
    rig = load_calibration(p)
    assert rig.names == ref.names
    np.testing.assert_allclose(rig.T_world_cam, ref.T_world_cam, atol=1e-12)
    np.testing.assert_allclose(rig.dist[:, :4], [[0.1, -0.05, 0.001, 0.0]] * 5)


@pytest.mark.parametrize("path", ALL_FILES, ids=lambda p: p.name)
def test_toml_round_trip(path: Path, tmp_path: Path) -> None:
    rig = load_calibration(path)
    out = tmp_path / "rig.toml"
    save_toml(rig, out)
    assert_same_rig(rig, load_calibration(out), tol=1e-9)


@pytest.mark.parametrize("path", ALL_FILES, ids=lambda p: p.name)
def test_easymocap_writer_round_trip_reprojects_the_same(path: Path, tmp_path: Path) -> None:
    """Format X -> EasyMocap YAML (written with cv2.FileStorage) -> load: same pixels."""
    rig = load_calibration(path)
    save_easymocap(rig, tmp_path / "em")
    back = load_calibration(tmp_path / "em" / "intri.yml")
    assert_same_rig(rig, back, tol=1e-9)
    X = np.array([[0.2, 0.1, 1.0], [-0.5, 0.4, 0.2]])
    np.testing.assert_allclose(project(rig, X)[0], project(back, X)[0], atol=1e-6)


def test_fps_override() -> None:
    assert load_calibration(SHELF, fps=50.0).fps == 50.0
    assert load_calibration(SHELF).fps == 30.0
    with pytest.raises(ValueError, match="fps must be positive"):
        load_calibration(SHELF, fps=0.0)


def test_rotate_images_cw_matches_rotated_pixels() -> None:
    rig = load_calibration(TOML)
    rig = CameraRig(
        names=rig.names,
        K=rig.K,
        dist=rig.dist + np.array([0.05, -0.02, 0.003, -0.002, 0.01]),
        T_world_cam=rig.T_world_cam,
        image_size_wh=rig.image_size_wh,
        fps=rig.fps,
    )
    rng = np.random.default_rng(0)
    X = rng.uniform([-0.8, -0.8, 0.0], [0.8, 0.8, 1.8], size=(20, 3))
    uv, _ = project(rig, X)
    for k in range(4):
        rot = rotate_images_cw(rig, {"cam_01": k})
        uv2, _ = project(rot, X)
        w, h = rig.image_size_wh[0]
        u, v = uv[0, :, 0], uv[0, :, 1]
        expect = [np.stack([u, v], 1), np.stack([h - 1 - v, u], 1), np.stack([w - 1 - u, h - 1 - v], 1)]
        expect.append(np.stack([v, w - 1 - u], 1))
        np.testing.assert_allclose(uv2[0], expect[k], atol=1e-6)
        np.testing.assert_allclose(uv2[1:], uv[1:], atol=1e-9)
        assert tuple(rot.image_size_wh[0]) == ((w, h) if k % 2 == 0 else (h, w))
        np.testing.assert_allclose(rot.centers_world_m, rig.centers_world_m, atol=1e-12)


# ---------------------------------------------------------------- dispatch and errors


def test_dispatch_by_extension_and_content(tmp_path: Path) -> None:
    assert calibration_format(TOML) == "toml"
    assert calibration_format(QCA) == "qualisys"
    assert calibration_format(EASYMOCAP) == "easymocap"
    assert calibration_format(SHELF) == "json"
    # Content sniffing for files without a telling extension.
    for src, fmt in ((TOML, "toml"), (QCA, "qualisys"), (SHELF, "json")):
        p = tmp_path / f"calib_{fmt}.dat"
        shutil.copy(src, p)
        assert calibration_format(p) == fmt
        assert_same_rig(load_calibration(p), load_calibration(src), tol=0.0)


def test_unrecognised_format_names_file_and_lists_formats(tmp_path: Path) -> None:
    p = tmp_path / "calib.xyz"
    p.write_text("hello\n")
    with pytest.raises(
        ValueError, match=r"calib\.xyz: unrecognised calibration format.*toml.*qca.*EasyMocap.*json"
    ):
        load_calibration(p)
    with pytest.raises(ValueError, match="not found"):
        load_calibration(tmp_path / "missing.toml")
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(ValueError, match="unrecognised"):
        load_calibration(tmp_path / "empty_dir")


def test_toml_errors(tmp_path: Path) -> None:
    text = TOML.read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("fisheye = false", "fisheye = true", 1))
    with pytest.raises(ValueError, match=r"bad\.toml \[cam_01\]: fisheye"):
        load_calibration(bad)
    bad.write_text(text.replace("matrix = [ [ 1681.244873046875", "matrix = [ [ nan", 1))
    with pytest.raises(ValueError, match=r"cam_01.*NaN"):
        load_calibration(bad)
    bad.write_text(text.replace("rotation = [ 1.6882754799999993,", "rotation = [", 1))
    with pytest.raises(ValueError, match=r"cam_01.*rotation"):
        load_calibration(bad)
    bad.write_text("[cam_1\nname =")
    with pytest.raises(ValueError, match="malformed TOML"):
        load_toml(bad)


def test_json_errors(tmp_path: Path) -> None:
    p = tmp_path / "c.json"
    p.write_text('{\n "0": {"K": [1, 0, 0,\n 0, 1, 0, 0, 0, 1], "RT": [1, 2\n}')
    with pytest.raises(ValueError, match=r"c\.json: malformed JSON at line 4, column 1"):
        load_json_calibration(p)
    base = json.loads(SHELF.read_text())["0"]
    cases = {
        "missing intrinsics 'K'": {k: v for k, v in base.items() if k != "K"},
        "needs extrinsics": {k: v for k, v in base.items() if k != "RT"},
        "needs the image size": {k: v for k, v in base.items() if k != "imgSize"},
        "not a proper rotation": base | {"RT": [2, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0]},
        "NaN": base | {"K": [float("nan")] + base["K"][1:]},
        "VoxelPose-style": {
            "fx": 1000,
            "fy": 1000,
            "cx": 500,
            "cy": 400,
            "R": np.eye(3).tolist(),
            "T": [0, 0, 0],
        },
        "distortion must be 4 or 5": base | {"distCoeff": [0.1, 0.2]},
    }
    for msg, cam in cases.items():
        p.write_text(json.dumps({"cam7": cam}))
        with pytest.raises(ValueError, match=rf"c\.json \[camera cam7\].*{msg}"):
            load_json_calibration(p)


def test_easymocap_errors(tmp_path: Path) -> None:
    d = tmp_path / "em"
    d.mkdir()
    shutil.copy(EASYMOCAP / "intri.yml", d / "intri.yml")
    with pytest.raises(ValueError, match="missing.*extri.yml"):
        load_calibration(d)
    text = (EASYMOCAP / "extri.yml").read_text()
    (d / "extri.yml").write_text(
        text.replace('   - "7"\n', "", 1).replace("R_7:", "X_7:").replace("Rot_7:", "Y_7:")
    )
    with pytest.raises(ValueError, match=r"extri\.yml: cameras \['7'\].*no extrinsics"):
        load_calibration(d)
    # Rot_ and R_ disagreeing is an error (the file contradicts itself).
    (d / "extri.yml").write_text(text.replace("1.7333808154182149e+00", "1.2333808154182149e+00", 1))
    with pytest.raises(ValueError, match="Rot_2 and R_2 disagree"):
        load_calibration(d)
    (d / "extri.yml").write_text(text)
    (d / "intri.yml").write_text((EASYMOCAP / "intri.yml").read_text().replace("K_3:", "Q_3:"))
    with pytest.raises(ValueError, match=r"intri\.yml: missing 'K_3'"):
        load_calibration(d)


def test_toml_metadata_and_offset_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(TOML.read_text().replace("error = 0.0", 'error = 0.0\nfps = "fast"'))
    with pytest.raises(ValueError, match=r"bad\.toml \[metadata\]: fps must be a positive number"):
        load_calibration(bad)
    bad.write_text(TOML.read_text().replace("fisheye = false", 'fisheye = false\ntime_offset_s = "x"', 1))
    with pytest.raises(ValueError, match=r"\[cam_01\]: time_offset_s must be a finite number"):
        load_calibration(bad)
    bad.write_text(TOML.read_text().replace("error = 0.0", "error = 0.0\nfps = 60.0"))
    assert load_calibration(bad).fps == 60.0


def test_resolve_calibration_finds_the_one_file_in_a_folder(tmp_path: Path) -> None:
    from pipeline.io.calibration import resolve_calibration

    assert resolve_calibration(QCA) == QCA and resolve_calibration(EASYMOCAP) == EASYMOCAP
    inputs = tmp_path / "calibration"
    inputs.mkdir()
    shutil.copy(QCA, inputs / QCA.name)
    (inputs / "notes.json").write_text("{}")  # JSON in an inputs folder is not taken for a calibration
    assert resolve_calibration(inputs) == inputs / QCA.name
    shutil.copy(TOML, inputs / TOML.name)
    with pytest.raises(ValueError, match=r"calibration: a folder, .* several calibration files \(Calib\.qca\.txt, Calib_qualisys\.toml\)"):
        resolve_calibration(inputs)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match=r"empty: a folder, .* no calibration file"):
        resolve_calibration(tmp_path / "empty")
    with pytest.raises(ValueError, match="calibration not found"):
        resolve_calibration(tmp_path / "missing.toml")
