"""A calibration whose origin is above the floor, or whose world is tilted: the pipeline levels
and lowers its world to the floor, and ground truth given in the calibration's world is
compared in that one."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.artifacts import ArtifactStore
from pipeline.geometry.world import lower_world, transform_world
from pipeline.runner import run
from pipeline.runner.rig import world_from_input
from pipeline.schema import Keypoints3D, SessionConfig
from pipeline.schema.annotations import SwapIdentities, save_annotations
from pipeline.synthetic import SyntheticBout, SyntheticConfig, write_session
from pipeline.synthetic.bout import make_bout

RAISED_M = 0.10
"""The calibration's origin above the floor (Shelf's is about 9 cm above it)."""
STAGES = ("detect2d", "track", "associate", "calibrate", "triangulate", "evaluate")


def world_shift_m(session: Path) -> float:
    """How far the session's downstream world was lowered (m), checking it was not turned."""
    W = world_from_input(session, SessionConfig.load(session))
    assert np.array_equal(W[:3, :3], np.eye(3)), W
    return float(-W[2, 3])


@pytest.fixture(scope="module")
def bout() -> SyntheticBout:
    return make_bout(SyntheticConfig(n_cameras=4, n_frames=60, seed=0))


def _session(bout: SyntheticBout, path: Path, raise_m: float) -> Path:
    """``bout`` as a session whose calibration (and ground truth) put the floor at ``-raise_m``."""
    raised = dataclasses.replace(
        bout, rig=lower_world(bout.rig, raise_m), gt=bout.gt.replace(xyz_m=bout.gt.xyz_m - [0.0, 0.0, raise_m])
    )
    write_session(raised, path)
    cfg = SessionConfig.load(path)
    dataclasses.replace(cfg, stages=STAGES).save(path)
    return path


def test_the_world_is_lowered_to_the_floor_and_the_truth_with_it(bout: SyntheticBout, tmp_path: Path) -> None:
    plain = _session(bout, tmp_path / "plain", 0.0)
    raised = _session(bout, tmp_path / "raised", RAISED_M)
    run(plain)
    run(raised)
    assert world_shift_m(plain) == 0.0
    shift = world_shift_m(raised)
    assert abs(shift + RAISED_M) < 0.01, shift
    report = json.loads((raised / "artifacts" / "calibrate" / "report.json").read_text())
    assert report["floor_shift_m"] == pytest.approx(shift) and "world moved" in report["floor"]

    a = ArtifactStore(plain).load("triangulate", "keypoints3d", Keypoints3D)
    b = ArtifactStore(raised).load("triangulate", "keypoints3d", Keypoints3D)
    # The same points in the floor world, not clamped onto the raised world's z = 0.
    both = a.valid & b.valid
    dz = (b.xyz_m - a.xyz_m)[..., 2][both]
    assert np.abs(np.median(dz) - (-RAISED_M - shift)) < 0.002 and np.percentile(np.abs(dz), 95) < 0.02

    m_plain = json.loads((plain / "artifacts" / "evaluate" / "metrics.json").read_text())
    m_raised = json.loads((raised / "artifacts" / "evaluate" / "metrics.json").read_text())
    e_plain = m_plain["sources"]["filtered"]["mpjpe_mm"]
    e_raised = m_raised["sources"]["filtered"]["mpjpe_mm"]
    # The truth moved with the world: the error is the plain session's, not ~100 mm more.
    assert e_plain < 40 and abs(e_raised - e_plain) < 3.0, (e_plain, e_raised)


def test_floor_off_keeps_the_calibration_world(bout: SyntheticBout, tmp_path: Path) -> None:
    s = _session(bout, tmp_path / "off", RAISED_M)
    plain = _session(bout, tmp_path / "plain", 0.0)
    cfg = SessionConfig.load(s)
    dataclasses.replace(cfg, stage_config={"calibrate": {"floor": {"mode": "off"}}}).save(s)
    run(s)
    run(plain)
    assert world_shift_m(s) == 0.0
    kp = ArtifactStore(s).load("triangulate", "keypoints3d", Keypoints3D)
    heel = kp.joint_names.index("left_heel")
    # The calibration's z = 0 is 10 cm above the floor: the filter clamps the feet up to it.
    assert np.mean(kp.xyz_m[..., heel, 2][kp.valid[..., heel]] == 0.0) > 0.9
    errors = [
        json.loads((d / "artifacts" / "evaluate" / "metrics.json").read_text())["sources"]["filtered"]["mpjpe_mm"]
        for d in (plain, s)
    ]
    assert errors[1] > errors[0] + 1.0, errors  # the ankles are clamped too (measured +2 mm)


def test_a_late_edit_keeps_the_floor(bout: SyntheticBout, tmp_path: Path) -> None:
    """An identity swap changes the athletes' feet in the late frames; the floor measured
    again moves by a few mm at most, so the previous rig (and world) is kept."""
    s = _session(bout, tmp_path / "edit", RAISED_M)
    run(s)
    shift = world_shift_m(s)
    save_annotations(s / "annotations.json", [SwapIdentities(frame=45, person_a=0, person_b=1)])
    reports = {r.stage: r for r in run(s)}
    cal = reports["calibrate"]
    assert cal.action == "ran" and cal.metrics["incremental"].startswith("previous rig kept"), cal.metrics
    assert "the floor within" in cal.metrics["incremental"]
    assert world_shift_m(s) == shift


def test_a_tilted_calibration_is_levelled_and_the_truth_with_it(tmp_path: Path) -> None:
    """A calibration solved on a board lying 4 deg off level, 25 cm above the floor: the
    results come out in a level floor world, the same as the true calibration's."""
    bout = make_bout(SyntheticConfig(n_cameras=4, n_frames=300, seed=1))
    c, s_ = np.cos(np.radians(4.0)), np.sin(np.radians(4.0))
    W = np.array([[c, 0.0, s_, 0.0], [0.0, 1.0, 0.0, 0.0], [-s_, 0.0, c, -0.25], [0.0, 0.0, 0.0, 1.0]])
    tilted = dataclasses.replace(
        bout, rig=transform_world(bout.rig, W), gt=bout.gt.replace(xyz_m=bout.gt.xyz_m @ W[:3, :3].T + W[:3, 3])
    )
    plain, t = tmp_path / "plain", tmp_path / "tilted"
    for b, path in ((bout, plain), (tilted, t)):
        write_session(b, path)
        dataclasses.replace(SessionConfig.load(path), stages=STAGES).save(path)
        run(path)
    report = json.loads((t / "artifacts" / "calibrate" / "report.json").read_text())
    assert abs(report["world_turn_deg"] - 4.0) < 0.3 and "to level the floor" in report["level"], report
    true_to_floor = world_from_input(t, SessionConfig.load(t)) @ W
    assert np.degrees(np.arccos(true_to_floor[2, 2])) < 0.3, true_to_floor

    a = ArtifactStore(plain).load("triangulate", "keypoints3d", Keypoints3D)
    b = ArtifactStore(t).load("triangulate", "keypoints3d", Keypoints3D)
    heel = a.joint_names.index("left_heel")
    # The heels' heights in the levelled world are the plain session's, not 4 deg of slope off
    # (+-10 cm over the ring). The sessions may number the athletes differently: compare spreads.
    za, zb = (np.percentile(k.xyz_m[..., heel, 2][k.valid[..., heel]], [5, 50, 95]) for k in (a, b))
    assert np.abs(zb - za).max() < 0.01, (za, zb)
    errors = [
        json.loads((d / "artifacts" / "evaluate" / "metrics.json").read_text())["sources"]["filtered"]["mpjpe_mm"]
        for d in (plain, t)
    ]
    assert errors[0] < 40 and abs(errors[1] - errors[0]) < 2.0, errors


def test_a_damaged_world_file_is_a_clear_error(bout: SyntheticBout, tmp_path: Path) -> None:
    s = _session(bout, tmp_path / "damaged", RAISED_M)
    run(s)
    path = s / "artifacts" / "calibrate" / "world.json"
    for text, why in (("{not json", "not a calibrate world file"), ('{"other": 1}', "not a calibrate world file"), ('{"world_from_input": [[1, 0], [0, 1]]}', "finite 4x4")):
        path.write_text(text)
        with pytest.raises(ValueError, match=why) as e:
            world_from_input(s, SessionConfig.load(s))
        assert "world.json" in str(e.value) and "re-run the calibrate stage" in str(e.value)
