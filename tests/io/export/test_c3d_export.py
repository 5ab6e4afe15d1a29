"""The ``c3d`` export, read back with ezc3d and with the independent pure-Python ``c3d`` package."""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import ezc3d
import numpy as np
import pytest

from pipeline.io.export import ExportSelection, export_files
from tests.io.export.export_session import FIRST_FRAME, FPS, INVALID, write_export_session


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, ExportSelection]:
    root = tmp_path_factory.mktemp("c3d")
    sel = ExportSelection(write_export_session(root / "s", physics=False), names={0: "Red", 1: "Blue"})
    files = export_files(sel, "c3d")
    assert list(files) == ["keypoints3d_fit.c3d"]
    path = root / "kp.c3d"
    path.write_bytes(files["keypoints3d_fit.c3d"])
    return path, sel


def test_c3d_reads_back_with_ezc3d(exported: tuple[Path, ExportSelection]) -> None:
    path, sel = exported
    kp, _ = sel.keypoints()
    c = ezc3d.c3d(str(path))
    point = c["parameters"]["POINT"]
    assert point["LABELS"]["value"] == [f"{who}_{j}" for who in ("Red", "Blue") for j in kp.joint_names]
    assert point["UNITS"]["value"] == ["mm"] and point["RATE"]["value"][0] == FPS
    assert c["header"]["points"]["first_frame"] == FIRST_FRAME and c["header"]["points"]["frame_rate"] == FPS
    assert c["parameters"]["ANALOG"]["USED"]["value"][0] == 0 and c["data"]["analogs"].size == 0
    pts = c["data"]["points"][:3].transpose(2, 1, 0)  # (frames, markers, 3) mm
    res = c["data"]["meta_points"]["residuals"][0].T
    valid = kp.valid.reshape(kp.n_frames, -1)
    assert pts.shape == (kp.n_frames, valid.shape[1], 3)
    assert np.abs(pts[valid] / 1000.0 - kp.xyz_m.reshape(kp.n_frames, -1, 3)[valid]).max() <= 1e-6
    np.testing.assert_array_equal(res < 0, ~valid)
    assert np.isnan(pts[~valid]).all() and (~valid).sum() == len(INVALID)


def test_c3d_reads_back_with_the_c3d_package(exported: tuple[Path, ExportSelection]) -> None:
    import c3d

    path, sel = exported
    kp, _ = sel.keypoints()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "No analog data found in file."
        reader = c3d.Reader(io.BytesIO(path.read_bytes()))
        frames = list(reader.read_frames())
    assert [s.strip() for s in reader.point_labels][:2] == ["Red_nose", "Red_left_eye"]
    assert reader.point_rate == FPS and reader.analog_used == 0
    assert reader.get("POINT:UNITS").string_value.strip() == "mm"
    assert [i for i, _, _ in frames] == list(kp.frame_indices + 1)  # C3D frame numbers are 1-based
    pts = np.array([p for _, p, _ in frames])  # (frames, markers, 5): x, y, z, residual, cameras
    valid = kp.valid.reshape(kp.n_frames, -1)
    np.testing.assert_array_equal(pts[..., 3] < 0, ~valid)
    assert np.abs(pts[..., :3][valid] / 1000.0 - kp.xyz_m.reshape(kp.n_frames, -1, 3)[valid]).max() <= 1e-6


def test_c3d_of_a_frame_range_and_one_athlete(exported: tuple[Path, ExportSelection], tmp_path: Path) -> None:
    _, sel = exported
    one = ExportSelection(
        sel.session_dir, athletes=(1,), frames=(FIRST_FRAME + 4, FIRST_FRAME + 7), names=sel.names
    )
    path = tmp_path / "blue.c3d"
    path.write_bytes(export_files(one, "c3d")["keypoints3d_fit.c3d"])
    c = ezc3d.c3d(str(path))
    kp, _ = one.keypoints()
    assert c["parameters"]["POINT"]["LABELS"]["value"] == list(kp.joint_names)
    assert c["header"]["points"]["first_frame"] == FIRST_FRAME + 4 and c["data"]["points"].shape[2] == 3
    assert np.abs(c["data"]["points"][:3, :, 2].T / 1000.0 - kp.xyz_m[2, 0]).max() <= 1e-6


def test_c3d_from_physics_carries_the_floor_forces_as_analogs(tmp_path: Path) -> None:
    from pipeline.backends.mujoco.forces import ground_reaction_forces

    sel = ExportSelection(
        write_export_session(tmp_path / "s"),
        source="physics",
        names={0: "Red", 1: "Blue"},
        frames=(FIRST_FRAME + 1, FIRST_FRAME + 6),
    )
    files = export_files(sel, "c3d")
    path = tmp_path / "phys.c3d"
    path.write_bytes(files["keypoints3d_physics.c3d"])
    c = ezc3d.c3d(str(path))
    analog = c["parameters"]["ANALOG"]
    assert analog["LABELS"]["value"] == [f"{who}_GRF_{ax}" for who in ("Red", "Blue") for ax in "xyz"]
    assert analog["UNITS"]["value"] == ["N"] * 6 and analog["RATE"]["value"][0] == FPS
    res, xml = sel.physics()
    expected = ground_reaction_forces(xml, res)  # (frames, persons, 3)
    got = c["data"]["analogs"][0]  # (channels, frames)
    assert got.shape == (6, res.qpos.shape[0])
    np.testing.assert_allclose(got.T.reshape(-1, 2, 3), expected, atol=1e-3)
    assert expected[..., 2].mean() > 100.0  # the standing athletes press on the floor
