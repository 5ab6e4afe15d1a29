"""ArtifactStore: atomic writes, manifests, crash recovery (including a real SIGKILL)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pipeline.artifacts import ArtifactStore, Manifest, sha256_file
from pipeline.schema import Keypoints3D
from pipeline.schema.joints import COCO17


def _manifest(stage: str) -> Manifest:
    return Manifest(stage=stage, code_version="test", config={"a": 1}, config_hash="h", inputs={})


def test_write_and_load_with_hashes(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path)
    kp = Keypoints3D.empty(COCO17, np.array([0]), np.arange(3), 30.0, "filtered")
    m = store.write(_manifest("triangulate"), {"keypoints3d": kp, "scene.xml": "<mujoco/>"})
    assert set(m.outputs) == {"keypoints3d.npz", "scene.xml"}
    assert m.outputs["keypoints3d.npz"] == sha256_file(tmp_path / "artifacts/triangulate/keypoints3d.npz")
    back = store.load("triangulate", "keypoints3d", Keypoints3D)
    assert back.n_frames == 3
    # npz is loadable without pickle
    with np.load(tmp_path / "artifacts/triangulate/keypoints3d.npz", allow_pickle=False) as z:
        assert "xyz_m" in z.files


def test_failed_write_keeps_previous_version(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path)
    store.write(_manifest("fit"), {"a": {"x": np.arange(3)}})
    before = (tmp_path / "artifacts/fit/a.npz").read_bytes()

    class Boom:
        pass

    with pytest.raises(ValueError):
        store.write(_manifest("fit"), {"a": {"x": np.arange(5)}, "b": Boom()})
    assert (tmp_path / "artifacts/fit/a.npz").read_bytes() == before
    assert not [p for p in (tmp_path / "artifacts").iterdir() if p.name.startswith(".tmp-")]


def test_recovery_from_interrupted_swap(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path)
    store.write(_manifest("fit"), {"a": {"x": np.arange(3)}})
    # Simulate a crash between "rename old away" and "rename new into place".
    (tmp_path / "artifacts/fit").rename(tmp_path / "artifacts/.old-fit-deadbeef")
    (tmp_path / "artifacts/.tmp-fit-cafebabe").mkdir()
    store2 = ArtifactStore(tmp_path)
    assert store2.manifest("fit") is not None
    np.testing.assert_array_equal(np.load(tmp_path / "artifacts/fit/a.npz")["x"], np.arange(3))
    assert sorted(p.name for p in (tmp_path / "artifacts").iterdir()) == ["fit"]


WRITER = r"""
import sys, time, numpy as np
from pipeline.artifacts import ArtifactStore, Manifest
store = ArtifactStore(sys.argv[1])
m = lambda s: Manifest(stage=s, code_version="t", config={}, config_hash="h", inputs={})
store.write(m("triangulate"), {"k": {"x": np.arange(10)}})
orig = np.savez
def slow_savez(f, **kw):
    orig(f, **kw)
    print("WRITING", flush=True)
    time.sleep(60)
np.savez = slow_savez
store.write(m("fit"), {"big": {"x": np.zeros(1000)}})
"""


def test_sigkill_mid_write_leaves_earlier_artifacts_intact(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    deadline = time.time() + 60
    line = ""
    while time.time() < deadline and "WRITING" not in line:
        line = proc.stdout.readline()
    assert "WRITING" in line, "writer never reached the second stage"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)
    store = ArtifactStore(tmp_path)  # recovery runs on open
    assert store.manifest("triangulate") is not None
    np.testing.assert_array_equal(store_load(tmp_path), np.arange(10))
    assert store.manifest("fit") is None
    assert not (tmp_path / "artifacts/fit").exists()
    assert [p.name for p in (tmp_path / "artifacts").iterdir() if p.name.startswith(".")] == []


def store_load(root: Path) -> np.ndarray:
    with np.load(root / "artifacts/triangulate/k.npz") as z:
        return z["x"]


def test_corrupt_manifest_is_reported(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path)
    store.write(_manifest("fit"), {"a": {"x": np.arange(3)}})
    (tmp_path / "artifacts/fit/manifest.json").write_text("{not json")
    with pytest.raises(ValueError, match="manifest.json: corrupt manifest"):
        store.manifest("fit")
