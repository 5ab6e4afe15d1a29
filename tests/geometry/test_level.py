"""Which way is up: a calibration that is tilted, y-up, z-down or a camera's frame is turned so
the floor is level, and a level one is kept."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from pipeline.geometry.bundle import BundleConfig
from pipeline.geometry.floor import AthletePixels, FloorConfig, estimate_floor
from pipeline.geometry.level import Levelling, level_world
from pipeline.geometry.projection import project
from pipeline.geometry.world import rotation_to_z, transform_world, turn_deg
from pipeline.stages.calibrate import CalibrateConfig, gather_pixels, run, summary
from pipeline.synthetic.bout import SyntheticBout, make_bout
from pipeline.synthetic.config import SyntheticConfig

RING = np.array([[x, y, 0.0] for x in (-1.5, 0.0, 1.5) for y in (-1.5, 0.0, 1.5)])
"""Floor points of a 3 m ring, in the bout's own (true, level) world."""


def _rigid(R: np.ndarray, t: tuple[float, float, float]) -> np.ndarray:
    W = np.eye(4)
    W[:3, :3], W[:3, 3] = R, t
    return W


def _about(axis: tuple[float, float, float], deg: float) -> np.ndarray:
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    a = np.radians(deg)
    return np.eye(3) + np.sin(a) * K + (1.0 - np.cos(a)) * (K @ K)


@pytest.fixture(scope="module")
def bout() -> SyntheticBout:
    """4 cameras x 300 frames, floor at z = 0: the athletes cover about 1.5 m x 2 m of floor."""
    return make_bout(SyntheticConfig(n_cameras=4, n_frames=300, seed=0))


def _level(bout: SyntheticBout, world_from_true: np.ndarray, cfg: FloorConfig = FloorConfig(), frames: int | None = None) -> tuple[Levelling, np.ndarray]:
    """Level ``bout`` seen through a calibration whose world is ``world_from_true`` of the
    bout's; returns the levelling and the transform from the true world to the levelled,
    lowered one."""
    assoc = bout.gt_association()
    uv, conf, _ = gather_pixels(bout.tracks, assoc, bout.rig.n_views)
    names, P = tuple(bout.tracks.joint_names), assoc.n_persons
    if frames is not None:
        keep = frames * P * len(names)
        uv, conf = uv[:keep], conf[:keep]
    rig = transform_world(bout.rig, world_from_true)
    pix = AthletePixels(uv, conf, P, names, BundleConfig().min_conf)
    lev = level_world(rig, pix, cfg)
    turned = transform_world(rig, _rigid(lev.rotation, (0.0, 0.0, 0.0)))
    floor = estimate_floor(turned, pix, cfg, up_measured=lev.up_measured)
    return lev, _rigid(lev.rotation, (0.0, 0.0, -floor.shift_m)) @ world_from_true


def _floor_error_mm(true_to_levelled: np.ndarray) -> tuple[float, float]:
    """The true world's up against the levelled world's (deg), and the largest height (mm) a
    point of the true floor gets in the levelled world over the ring."""
    up = true_to_levelled[:3, :3] @ [0.0, 0.0, 1.0]
    z = RING @ true_to_levelled[2, :3] + true_to_levelled[2, 3]
    return float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0)))), float(1000 * np.abs(z).max())


def test_transform_world_moves_points_not_pixels(bout: SyntheticBout) -> None:
    W = _rigid(_about((1.0, 2.0, 0.5), 37.0), (0.3, -1.0, 2.0))
    moved = transform_world(bout.rig, W)
    X = np.random.default_rng(0).uniform([-1, -1, 0], [1, 1, 2], (50, 3))
    a, _ = project(bout.rig, X)
    b, _ = project(moved, X @ W[:3, :3].T + W[:3, 3])
    assert np.allclose(a, b, atol=1e-6)
    assert transform_world(bout.rig, np.eye(4)) is bout.rig


@pytest.mark.parametrize("n", [(0.1, -0.2, 0.97), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 0.0, 1.0), (0.3, 0.2, -0.9)])
def test_rotation_to_z(n: tuple[float, float, float]) -> None:
    R = rotation_to_z(np.array(n))
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(R @ (np.array(n) / np.linalg.norm(n)), [0.0, 0.0, 1.0], atol=1e-12)
    assert turn_deg(R) == pytest.approx(np.degrees(np.arccos(n[2] / np.linalg.norm(n))), abs=1e-6)


def test_a_level_world_is_kept(bout: SyntheticBout) -> None:
    lev, _ = _level(bout, np.eye(4))
    assert not lev.rotated and lev.tilt_deg < 0.5 and "kept level" in lev.reason, lev
    assert lev.body_tilt_deg < 5.0 and lev.up_measured  # boxers lean a little forward


@pytest.mark.parametrize(
    "label, world_from_true",
    [
        ("tilted 3 deg", _rigid(_about((1.0, 0.3, 0.0), 3.0), (0.2, -0.1, 0.4))),
        ("y-up", _rigid(_about((1.0, 0.0, 0.0), -90.0), (0.0, 1.2, 0.0))),
        ("z-down", _rigid(_about((1.0, 0.0, 0.0), 180.0), (0.0, 0.0, -0.3))),
        ("a camera's frame", None),
    ],
)
def test_a_world_that_is_not_level_is_turned(bout: SyntheticBout, label: str, world_from_true: np.ndarray | None, caplog: pytest.LogCaptureFixture) -> None:
    if world_from_true is None:  # aniposelib's convention: the world is camera 0's frame
        world_from_true = np.linalg.inv(bout.rig.T_world_cam[0])
    with caplog.at_level(logging.WARNING, logger="pipeline.geometry.level"):
        lev, true_to_levelled = _level(bout, world_from_true)
    assert lev.rotated and "to level the floor" in lev.reason, (label, lev)
    up_err, floor_mm = _floor_error_mm(true_to_levelled)
    # Measured 0.06-0.13 deg and 2-5 mm (seeds 0-2, 4 cameras; 2 cameras up to 0.16 deg, 7 mm).
    assert up_err < 0.3 and floor_mm < 15.0, (label, up_err, floor_mm)
    assert ("not z-up" in caplog.text) == (lev.body_tilt_deg > FloorConfig().max_body_tilt_deg), caplog.text


def test_no_floor_plane_but_not_z_up_turns_to_the_athletes(bout: SyntheticBout) -> None:
    """When the floor's slope is not known well enough (a short clip; forced here), a y-up
    world is still caught from the athletes standing along y, and turned to their up; a small
    tilt is left alone."""
    strict = FloorConfig(max_slope_se_deg=0.01)
    lev, true_to_levelled = _level(bout, _rigid(_about((1.0, 0.0, 0.0), -90.0), (0.0, 1.2, 0.0)), strict, frames=60)
    assert lev.rotated and np.isnan(lev.tilt_deg) and "not z-up" in lev.reason, lev
    assert "the feet covered too little floor" in lev.reason
    up_err, floor_mm = _floor_error_mm(true_to_levelled)
    assert up_err < 4.0 and floor_mm < 100.0, (up_err, floor_mm)  # their lean: measured 1.0 deg, 37 mm
    kept, _ = _level(bout, _rigid(_about((1.0, 0.0, 0.0), 3.0), (0.0, 0.0, 0.0)), strict, frames=60)
    assert not kept.rotated and "the feet covered too little floor" in kept.reason, kept


def test_a_short_clip_levels_less_precisely(bout: SyntheticBout) -> None:
    """120 frames (2.4 s): a 3 deg tilt is still found, less precisely (seeds 0-5, 2 and 4
    cameras: within 0.7 deg; 300 frames: 0.4)."""
    lev, true_to_levelled = _level(bout, _rigid(_about((1.0, 0.0, 0.0), 3.0), (0.0, 0.0, 0.0)), frames=120)
    se = float(lev.reason.split("± ")[1].split(" deg")[0])
    up_err, floor_mm = _floor_error_mm(true_to_levelled)
    assert lev.rotated and se <= FloorConfig().max_slope_se_deg and up_err < 1.0 and floor_mm < 40.0, (lev, up_err)


def test_height_mode_and_missing_joints_keep_the_world(bout: SyntheticBout) -> None:
    tilted = _rigid(_about((0.0, 1.0, 0.0), 5.0), (0.0, 0.0, 0.0))
    lev, _ = _level(bout, tilted, FloorConfig(mode="height"))
    assert not lev.rotated and "off" in lev.reason
    assoc = bout.gt_association()
    uv, conf, _ = gather_pixels(bout.tracks, assoc, bout.rig.n_views)
    names = tuple(f"joint{i}" if "shoulder" in n or n == "nose" else n for i, n in enumerate(bout.tracks.joint_names))
    lev = level_world(bout.rig, AthletePixels(uv, conf, assoc.n_persons, names, BundleConfig().min_conf), FloorConfig())
    assert not lev.rotated and not lev.up_measured and "no ankles and shoulders" in lev.reason


def test_calibrate_levels_then_lowers(bout: SyntheticBout) -> None:
    world_from_true = _rigid(_about((0.0, 1.0, 0.0), 4.0), (0.0, 0.0, 0.25))
    rig = transform_world(bout.rig, world_from_true)
    res = run(bout.tracks, bout.gt_association(), rig, CalibrateConfig(mode="off"))
    assert res.level is not None and res.level.rotated and res.floor is not None
    up_err, floor_mm = _floor_error_mm(res.world_from_input @ world_from_true)
    assert up_err < 0.3 and floor_mm < 15.0, (up_err, floor_mm)
    assert np.allclose(transform_world(rig, res.world_from_input).T_world_cam, res.rig.T_world_cam)
    s = summary(res)
    assert abs(s["world_turn_deg"] - 4.0) < 0.3 and "to level the floor" in s["level"], s


def test_config() -> None:
    for bad in ({"mode": "level"}, {"min_tilt_deg": -1.0}, {"max_up_gap_deg": 0.0}, {"cell_m": float("nan")}, {"max_slope_se_deg": 0.0}, {"hold_deg": -0.1}, {"max_body_tilt_deg": 0.0}, {"max_up_spread_deg": -1.0}):
        with pytest.raises(ValueError, match="FloorConfig"):
            FloorConfig(**bad)  # type: ignore[arg-type]


def test_athletes_who_are_not_upright_keep_the_world(bout: SyntheticBout) -> None:
    """Athletes whose ankles-to-shoulders directions vary more than ``max_up_spread_deg`` (on
    the ground, say) give no up, and a y-up world is then kept, not turned. The boxers here
    vary by 5-7 deg (median), so a 3 deg limit stands in for athletes on the ground."""
    y_up = _rigid(_about((1.0, 0.0, 0.0), -90.0), (0.0, 1.2, 0.0))
    lev, _ = _level(bout, y_up, FloorConfig(max_up_spread_deg=3.0))
    assert not lev.rotated and not lev.up_measured and "not upright" in lev.reason, lev
    spread = float(lev.reason.split("varies by ")[1].split(" deg")[0])
    assert 3.0 < spread < 10.0, lev.reason
    assert _level(bout, y_up)[0].rotated  # the default limit (20 deg) takes them as upright
