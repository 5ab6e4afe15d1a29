"""Incremental re-runs through the runner: the physics step gets its previous artifacts back,
the manifest records what was reused, and a config change or ``force`` runs in full.

The session enables only ``physics``; its input, the fit's keypoints, is written as a
``fit`` artifact by hand (two persons facing each other, ``test_physics._facing_pair``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mujoco")

from pipeline.artifacts import ArtifactStore, Manifest  # noqa: E402
from pipeline.runner import run  # noqa: E402
from pipeline.schema.keypoints3d import Keypoints3D  # noqa: E402
from pipeline.schema.results import PhysicsResult  # noqa: E402
from tests.conftest import write_tiny_session  # noqa: E402
from tests.stages.test_physics import _facing_pair  # noqa: E402

FAST = {"solver": {"window": 5, "commit": 3, "ilqr": {"max_iter": 2, "n_alpha": 3}}}
N_FRAMES, EDIT_FRAME = 40, 36


def _write_fit(session: Path, kp: Keypoints3D) -> None:
    m = Manifest(stage="fit", code_version="test", config={}, config_hash="test", inputs={})
    ArtifactStore(session).write(m, {"keypoints3d": kp})


def _physics_config(session: Path, cfg: dict) -> None:
    d = json.loads((session / "session.json").read_text())
    d["stage_config"] = {"physics": cfg}
    (session / "session.json").write_text(json.dumps(d))


def test_the_manifest_records_what_an_incremental_physics_run_reused(tmp_path: Path) -> None:
    s = write_tiny_session(tmp_path / "s", stages=("physics",))
    _physics_config(s, FAST)
    kp = _facing_pair(0.3, N_FRAMES)
    _write_fit(s, kp)
    store = ArtifactStore(s)

    (first,) = run(s)
    assert first.action == "ran" and first.metrics["incremental"] == "full run: no previous run"
    assert store.has("physics", "checkpoints.npz")
    m1 = store.manifest("physics")
    assert m1 is not None
    old = store.load("physics", "result", PhysicsResult)

    xyz = kp.xyz_m.copy()
    xyz[EDIT_FRAME:, 1, kp.joint_names.index("left_wrist"), 2] += 0.02
    _write_fit(s, kp.replace(xyz_m=xyz))
    (second,) = run(s)
    mt = second.metrics
    assert second.action == "ran"
    assert 0 < mt["reused_frames"] == mt["replanned_from_frame"] < EDIT_FRAME
    assert mt["first_changed_input_frame"] == EDIT_FRAME
    assert mt["incremental"] == f"reused frames 0-{mt['reused_frames'] - 1}"
    assert mt["previous_outputs_hash"] == m1.outputs_hash
    m2 = store.manifest("physics")
    assert m2 is not None and m2.metrics["previous_outputs_hash"] == m1.outputs_hash
    new = store.load("physics", "result", PhysicsResult)
    r = mt["reused_frames"]
    assert np.array_equal(new.qpos[:r], old.qpos[:r]) and not np.array_equal(new.qpos, old.qpos)

    # Another config (here: fewer frames, to keep the test short): the previous run is not
    # reused, and the manifest says why.
    _physics_config(s, {**FAST, "max_frames": 12})
    (third,) = run(s)
    assert third.metrics["incremental"] == "full run: the stage config changed"
    assert third.metrics["reused_frames"] == 0 and "previous_outputs_hash" not in third.metrics

    # A forced run recomputes too, even with nothing changed; so does one forced from the stage.
    (forced,) = run(s, force=True)
    assert forced.metrics["incremental"] == "full run: forced re-run" and forced.metrics["reused_frames"] == 0
    (forced,) = run(s, from_stage="physics", force=True)
    assert forced.metrics["incremental"] == "full run: forced re-run" and forced.metrics["reused_frames"] == 0

    # ``incremental: false`` in the stage config turns reuse off.
    _physics_config(s, {**FAST, "max_frames": 12, "incremental": False})
    (off,) = run(s)
    assert off.metrics["incremental"] == "full run: incremental is off"
