"""``--format bvh``: read back with an independent parser (``bvhio``), its forward kinematics
reproduces anny's bone heads (≤ 1 mm), and the file has what Blender's importer reads."""

from __future__ import annotations

import io
import re
import zipfile
from pathlib import Path

import bvhio
import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from pipeline.backends.anny.fk import forward_kinematics
from pipeline.backends.anny.model import anny_body
from pipeline.backends.anny.skeleton import fit_skeleton
from pipeline.cli.main import app
from pipeline.io.export import ExportSelection, export_files
from pipeline.io.export.bvh import bvh_text
from pipeline.schema.results import BodyFit
from tests.io.export.fitted_session import ATHLETES, FPS, INVALID_ROWS, write_fitted_session

TOL_M = 1e-3


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, BodyFit]:
    s = tmp_path_factory.mktemp("bvh") / "bout"
    return s, write_fitted_session(s)


def _anny_heads(shape: np.ndarray, pose: np.ndarray, root: np.ndarray) -> np.ndarray:
    """(frames, bones, 3) world bone heads by anny's own FK (not through the exporter's skeleton)."""
    body = anny_body()
    with torch.no_grad():
        heads = body.rest_heads(body.shape_coeffs(torch.as_tensor(shape, dtype=torch.float64)[None]))
        _, x = forward_kinematics(
            body, torch.as_tensor(pose, dtype=torch.float64), torch.as_tensor(root), heads
        )
    return x.numpy()


def _bvh_heads(path: Path, names: tuple[str, ...], frames: list[int]) -> np.ndarray:
    """(frames, joints, 3) world joint positions by bvhio's FK, back in the z-up world (metres)."""
    root = bvhio.readAsHierarchy(str(path))
    joints = {j.Name: j for j, _, _ in root.layout()}
    out = []
    for f in frames:
        root.loadPose(f)
        p = np.array([list(joints[n].PositionWorld) for n in names], dtype=np.float64) / 100.0  # cm -> m
        out.append(np.stack([p[:, 0], -p[:, 2], p[:, 1]], axis=1))  # y-up (x, z, -y) -> z-up
    return np.array(out)


def test_bvh_forward_kinematics_reproduces_anny_bone_heads(
    session: tuple[Path, BodyFit], tmp_path: Path
) -> None:
    s, fit = session
    assert INVALID_ROWS == (2, 3) and not fit.valid[[2, 3], 1].any()
    files = export_files(ExportSelection(s, names=dict(enumerate(ATHLETES))), "bvh")
    assert sorted(files) == sorted(f"{n}.bvh" for n in ATHLETES)
    rows = [0, 2, 3, 5, fit.frame_indices.size - 1]
    for pi, name in enumerate(ATHLETES):
        path = tmp_path / f"{name}.bvh"
        path.write_bytes(files[f"{name}.bvh"])
        got = _bvh_heads(path, fit.bone_names, rows)
        # Blue's not-fitted rows (2, 3) hold the nearest fitted frame (1 and 4)
        held = [r if fit.valid[r, pi] else {2: 1, 3: 4}[r] for r in rows]
        want = _anny_heads(fit.shape[pi], fit.pose[held, pi], fit.root_translation_m[held, pi])
        err = np.linalg.norm(got - want, axis=-1)
        assert err.max() <= TOL_M, f"{name}: BVH FK differs from anny by {err.max() * 1000:.3f} mm"
        # the root follows the fit's root translation, and the body moves between frames
        np.testing.assert_allclose(got[:, 0], fit.root_translation_m[held, pi], atol=TOL_M)
        assert np.linalg.norm(want[-1] - want[0], axis=-1).max() > 0.01


def test_large_rotations_and_gimbal_lock_survive_the_euler_conversion(
    session: tuple[Path, BodyFit], tmp_path: Path
) -> None:
    s, fit = session
    skel = fit_skeleton(fit, 0)
    rng = np.random.default_rng(1)
    n, nb = 4, skel.n_bones
    pose = rng.normal(0, 1.2, (n, nb, 3))
    pose[0, 5] = [np.pi / 2, 0.0, 0.0]  # world x = BVH x: Xrotation exactly 90 degrees (ZXY's lock)
    pose[1, 9] = [0.0, 0.0, np.pi * 0.999]  # about world z = BVH y, near 180 degrees
    root = rng.normal(0, 1.0, (n, 3))
    path = tmp_path / "random.bvh"
    path.write_text(bvh_text(skel, pose, root, 1 / FPS))
    got = _bvh_heads(path, fit.bone_names, list(range(n)))
    want = _anny_heads(fit.shape[0], pose, root)
    assert np.linalg.norm(got - want, axis=-1).max() <= TOL_M


def test_bvh_file_is_well_formed_for_blender(session: tuple[Path, BodyFit]) -> None:
    s, fit = session
    text = export_files(ExportSelection(s, athletes=(1,), names=dict(enumerate(ATHLETES))), "bvh")["Blue.bvh"]
    lines = [ln.strip() for ln in text.decode().splitlines()]
    assert lines[0] == "HIERARCHY" and lines[1] == f"ROOT {fit.bone_names[0]}"
    names = [ln.split()[1] for ln in lines if ln.split()[0] in ("ROOT", "JOINT")]
    assert all(len(ln.split()) == 2 for ln in lines if ln.split()[0] in ("ROOT", "JOINT"))  # no spaces
    assert sorted(names) == sorted(fit.bone_names)
    parents = anny_body().bone_parent
    leaves = [b for b in range(len(fit.bone_names)) if b not in parents]
    assert lines.count("End Site") == len(leaves) >= 5  # feet, wrists, head
    assert lines.count("{") == lines.count("}") == len(names) + len(leaves)
    chans = [ln for ln in lines if ln.startswith("CHANNELS")]
    assert chans[0] == "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"
    assert set(chans[1:]) == {"CHANNELS 3 Zrotation Xrotation Yrotation"}
    m = lines.index("MOTION")
    assert lines[m + 1] == f"Frames: {fit.frame_indices.size}"
    assert re.fullmatch(r"Frame Time: 0\.0200+", lines[m + 2])
    motion = lines[m + 3 :]
    assert len(motion) == fit.frame_indices.size
    assert {len(ln.split()) for ln in motion} == {6 + 3 * (len(names) - 1)}
    # every End Site is a real bone end (a non-zero offset), for Blender's tails
    ends = [lines[i + 2] for i, ln in enumerate(lines) if ln == "End Site"]
    assert all(np.linalg.norm([float(v) for v in e.split()[1:]]) > 1.0 for e in ends)  # > 1 cm


def test_cli_writes_a_zip_of_both_athletes_and_refuses_physics(
    session: tuple[Path, BodyFit], tmp_path: Path
) -> None:
    s, fit = session
    runner = CliRunner()
    out = tmp_path / "bvh.zip"
    r = runner.invoke(app, ["export", str(s), "--format", "bvh", "--frames", "12:16", "--out", str(out)])
    assert r.exit_code == 0, r.output
    with zipfile.ZipFile(io.BytesIO(out.read_bytes())) as z:
        assert sorted(z.namelist()) == ["Blue.bvh", "Red.bvh"]
        red = z.read("Red.bvh").decode()
    assert "Frames: 4\n" in red
    r = runner.invoke(
        app, ["export", str(s), "--format", "bvh", "--source", "physics", "--out", str(tmp_path / "p.bvh")]
    )
    assert r.exit_code != 0 and "body fit" in r.output and "physics" in r.output
    assert not (tmp_path / "p.bvh").exists()
    with pytest.raises(ValueError, match="source raw"):
        export_files(ExportSelection(s, source="raw"), "bvh")
