"""The ``mujoco`` export: a ZIP of scene.xml, motion.npz and replay.py. replay.py runs headless in a
subprocess on the extracted files; its body and site positions must match ``mj_forward`` on the
physics artifacts' qpos and the physics stage's own keypoints."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import mujoco
import numpy as np
import pytest

from pipeline.artifacts import ArtifactStore, Manifest
from pipeline.io.export import ExportSelection, export_files
from pipeline.io.export.write import write_files
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import PhysicsResult
from tests.io.export.export_session import FIRST_FRAME, FPS, write_export_session


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_export_session(tmp_path_factory.mktemp("mj") / "s")


def test_replay_script_reproduces_the_physics_result(session: Path, tmp_path: Path) -> None:
    frames = (FIRST_FRAME + 2, FIRST_FRAME + 6)
    sel = ExportSelection(session, frames=frames, names={0: "Red", 1: "Blue"})
    files = export_files(sel, "mujoco")
    assert sorted(files) == ["motion.npz", "replay.py", "scene.xml"]
    assert len(files["replay.py"].decode().splitlines()) <= 20
    zpath = write_files(files, tmp_path / "mujoco.zip")
    with zipfile.ZipFile(zpath) as z:
        z.extractall(tmp_path / "x")
    env = {**os.environ, "MUJOCO_GL": "egl", "OMP_NUM_THREADS": "1"}
    r = subprocess.run([sys.executable, "replay.py", "--headless"], cwd=tmp_path / "x", env=env,
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr
    replayed = np.load(tmp_path / "x" / "replayed.npz")

    # The reference, straight from the artifacts (not through the export).
    store = ArtifactStore(session)
    res = store.load("physics", "result", PhysicsResult)
    rows = np.flatnonzero((res.frame_indices >= frames[0]) & (res.frame_indices < frames[1]))
    assert rows.size == 4
    model = mujoco.MjModel.from_xml_string((store.stage_dir("physics") / "scene.xml").read_text())
    data = mujoco.MjData(model)
    body_xpos = []
    for q in res.qpos[rows]:
        data.qpos[:] = q
        mujoco.mj_forward(model, data)
        body_xpos.append(data.xpos.copy())
    np.testing.assert_allclose(replayed["body_xpos"], np.array(body_xpos), atol=1e-9)
    assert np.ptp(replayed["body_xpos"][:, 1:, 2]) > 0.5  # real bodies at real heights, not the origin

    # Independent of mj_forward here: the physics stage's own keypoints are its site positions.
    kp = store.load("physics", "keypoints3d", Keypoints3D)
    sites = [model.site(i).name for i in range(model.nsite)]
    for pi, pid in enumerate(kp.person_ids.tolist()):
        idx = [sites.index(f"p{pid}_{j}") for j in kp.joint_names]
        np.testing.assert_allclose(replayed["site_xpos"][:, idx], kp.xyz_m[rows, pi], atol=1e-6)

    motion = np.load(tmp_path / "x" / "motion.npz")
    np.testing.assert_array_equal(motion["qpos"], res.qpos[rows])
    np.testing.assert_array_equal(motion["ctrl"], res.ctrl[rows])
    np.testing.assert_allclose(motion["time_s"], np.arange(*frames) / FPS)
    assert motion["athlete_names"].tolist() == ["Red", "Blue"] and float(motion["fps"]) == FPS
    assert motion["qvel"].shape == (4, model.nv) and motion["qpos"].shape == (4, model.nq)


def test_mujoco_export_without_physics_is_a_lookup_error(session: Path, tmp_path: Path) -> None:
    s = write_export_session(tmp_path / "s", physics=False)
    with pytest.raises(LookupError, match="physics stage has not produced result.npz"):
        export_files(ExportSelection(s), "mujoco")
    # A physics result without its scene.xml is reported the same way, naming the file.
    res = ArtifactStore(session).load("physics", "result", PhysicsResult)
    ArtifactStore(s).write(
        Manifest(stage="physics", code_version="t", config={}, config_hash="0", inputs={}), {"result": res}
    )
    with pytest.raises(LookupError, match="scene.xml"):
        export_files(ExportSelection(s), "mujoco")


def test_the_readme_gives_the_replay_script_as_exported() -> None:
    from pipeline.io.export.mjcf import REPLAY_PY

    readme = (Path(__file__).resolve().parents[3] / "README.md").read_text()
    assert REPLAY_PY.strip() in readme and len(REPLAY_PY.strip().splitlines()) <= 20
