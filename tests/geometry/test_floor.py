"""The floor's height from the athletes' feet, and the world lowered to put it at z = 0."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.geometry.bundle import BundleConfig
from pipeline.geometry.floor import AthletePixels, FloorConfig, estimate_floor
from pipeline.geometry.projection import project
from pipeline.geometry.world import lower_world
from pipeline.schema.config_types import build_config
from pipeline.stages.calibrate import CalibrateConfig, gather_pixels, run, summary
from pipeline.synthetic.bout import SyntheticBout, make_bout
from pipeline.synthetic.config import SyntheticConfig

RAISED_M = 0.10
"""The test rig's world origin above the floor (Shelf's is about 9 cm above it)."""


@pytest.fixture(scope="module")
def bout() -> SyntheticBout:
    """4 cameras x 60 frames, 2 boxers + a bystander, floor at z = 0."""
    return make_bout(SyntheticConfig(n_cameras=4, n_frames=60, seed=0))


def _estimate(bout: SyntheticBout, rig: object, cfg: FloorConfig = FloorConfig(), names: tuple[str, ...] | None = None):  # type: ignore[no-untyped-def]
    assoc = bout.gt_association()
    uv, conf, _ = gather_pixels(bout.tracks, assoc, bout.rig.n_views)
    names = names or tuple(bout.tracks.joint_names)
    return estimate_floor(rig, AthletePixels(uv, conf, assoc.n_persons, names, BundleConfig().min_conf), cfg)  # type: ignore[arg-type]


def test_lower_world_moves_points_not_pixels(bout: SyntheticBout) -> None:
    X = np.random.default_rng(0).uniform([-1, -1, 0], [1, 1, 2], (50, 3))
    moved = lower_world(bout.rig, 0.25)
    a, _ = project(bout.rig, X)
    b, _ = project(moved, X - [0.0, 0.0, 0.25])
    assert np.allclose(a, b, atol=1e-6)
    assert np.allclose(moved.centers_world_m, bout.rig.centers_world_m - [0.0, 0.0, 0.25])
    assert lower_world(bout.rig, 0.0) is bout.rig


def test_a_floor_at_zero_is_kept(bout: SyntheticBout) -> None:
    est = _estimate(bout, bout.rig)
    assert est.joints == "soles" and est.shift_m == 0.0 and "floor kept" in est.reason, est.reason
    assert abs(est.floor_z_m) < 0.01, est.floor_z_m


def test_a_floor_below_the_origin_is_found_and_moved(bout: SyntheticBout) -> None:
    raised = lower_world(bout.rig, RAISED_M)  # the floor is at z = -0.10 in this world
    est = _estimate(bout, raised)
    assert abs(est.floor_z_m + RAISED_M) < 0.01 and est.shift_m == est.floor_z_m, est
    assert "world moved" in est.reason and f"{1000 * est.floor_z_m:+.0f} mm" in est.reason
    assert len(est.person_floor_z_m) == 2 and all(abs(z + RAISED_M) < 0.015 for z in est.person_floor_z_m)
    back = lower_world(raised, est.shift_m)
    assert np.abs(back.centers_world_m - bout.rig.centers_world_m).max() < 0.01


def test_ankles_when_there_are_no_feet(bout: SyntheticBout) -> None:
    names = tuple(f"joint{i}" if ("heel" in n or "toe" in n) else n for i, n in enumerate(bout.tracks.joint_names))
    est = _estimate(bout, lower_world(bout.rig, RAISED_M), names=names)
    assert est.joints == "ankles" and abs(est.floor_z_m + RAISED_M) < 0.015, est
    none = tuple(f"joint{i}" for i in range(len(names)))
    est = _estimate(bout, bout.rig, names=none)
    assert est.shift_m == 0.0 and np.isnan(est.floor_z_m) and "no ankles or feet" in est.reason


def test_a_floor_too_far_off_is_reported_not_applied(bout: SyntheticBout) -> None:
    est = _estimate(bout, lower_world(bout.rig, 0.6))
    assert est.shift_m == 0.0 and abs(est.floor_z_m + 0.6) < 0.01
    assert "more than 500 mm off: check that the calibration is z-up" in est.reason, est.reason


def test_too_few_frames_and_off(bout: SyntheticBout) -> None:
    raised = lower_world(bout.rig, RAISED_M)
    est = _estimate(bout, raised, FloorConfig(min_frames=61))
    assert est.shift_m == 0.0 and "no athlete has 61 frames" in est.reason
    est = _estimate(bout, raised, FloorConfig(mode="off"))
    assert est.shift_m == 0.0 and "off" in est.reason


def test_calibrate_puts_the_floor_at_zero(bout: SyntheticBout) -> None:
    raised = lower_world(bout.rig, RAISED_M)
    res = run(bout.tracks, bout.gt_association(), raised, CalibrateConfig(mode="off"))
    assert res.floor is not None and abs(res.floor.shift_m + RAISED_M) < 0.01
    assert np.abs(res.rig.centers_world_m - bout.rig.centers_world_m).max() < 0.01
    s = summary(res)
    assert s["floor_shift_m"] == round(res.floor.shift_m, 6) and "world moved" in s["floor"]
    kept = run(bout.tracks, bout.gt_association(), raised, CalibrateConfig(mode="off", floor={"mode": "off"}))  # type: ignore[arg-type]
    assert kept.rig is raised and kept.floor is not None and kept.floor.shift_m == 0.0


def test_config() -> None:
    cfg = build_config(CalibrateConfig, {"floor": {"min_shift_m": 0.05}}, "stage_config.calibrate")
    assert cfg.floor == FloorConfig(min_shift_m=0.05)
    with pytest.raises(ValueError, match="unknown keys"):
        CalibrateConfig(floor={"min_shift": 0.05})  # type: ignore[arg-type]
    for bad in ({"mode": "maybe"}, {"sole_height_m": -0.01}, {"min_shift_m": float("nan")}, {"max_shift_m": 0.02}, {"hold_m": -1.0}, {"min_frames": 0}, {"max_view_err_px": 0.0}):
        with pytest.raises(ValueError, match="FloorConfig"):
            FloorConfig(**bad)  # type: ignore[arg-type]


def test_pixels_that_are_not_frames_x_persons_x_joints_are_refused() -> None:
    names = ("left_ankle", "right_ankle")
    with pytest.raises(ValueError, match="AthletePixels: 5 rows are not frames x 2 persons x 2 joints"):
        AthletePixels(np.zeros((5, 3, 2)), np.zeros((5, 3)), 2, names, 0.5)
    with pytest.raises(ValueError, match="AthletePixels: 8 rows"):
        AthletePixels(np.zeros((8, 3, 2)), np.zeros((4, 3)), 2, names, 0.5)
    assert AthletePixels(np.zeros((8, 3, 2)), np.zeros((8, 3)), 2, names, 0.5).n_frames == 2
