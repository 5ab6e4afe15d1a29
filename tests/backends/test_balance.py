"""The balanced reference (``backends.mujoco.balance``): a centre of mass outside the planted
support is moved inside with the planted foot held, and ``none`` changes nothing."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from pipeline.backends.mujoco.balance import (  # noqa: E402
    balance_reference,
    centre_of_mass,
    nearest_in_polygon,
    shrink_polygon,
    solve_offset,
    support_polygons,
)
from pipeline.backends.mujoco.config import ReferenceConfig  # noqa: E402
from pipeline.backends.mujoco.reference import build_reference  # noqa: E402
from pipeline.backends.mujoco.schedule import foot_site_ids  # noqa: E402
from tests.backends.test_humanoid import _rest_keypoints  # noqa: E402
from tests.backends.test_schedule import FPS, _one_person_scene  # noqa: E402

SQUARE = np.array([[-0.1, -0.1], [0.1, -0.1], [0.1, 0.1], [-0.1, 0.1]])


def _outside_m(p: np.ndarray, poly: np.ndarray | None) -> float:
    assert poly is not None, "no planted foot where one is planted"
    return float(np.linalg.norm(nearest_in_polygon(p, poly) - p))


def test_polygon_helpers() -> None:
    assert _outside_m(np.array([0.05, 0.0]), SQUARE) == 0.0
    assert _outside_m(np.array([0.3, 0.0]), SQUARE) == pytest.approx(0.2)
    small = shrink_polygon(SQUARE, 0.02 * np.sqrt(2))
    assert np.abs(small).max() == pytest.approx(0.08)


def test_offset_brings_an_outside_zmp_onto_the_support_and_leaves_flight_free() -> None:
    F = 40
    zmp = np.tile([0.3, 0.05], (F, 1))
    polys: list[np.ndarray | None] = [SQUARE] * F
    polys[:10] = [None] * 10  # flight: no constraint
    d = solve_offset(zmp, np.full(F, 0.09), polys, FPS, w_vel=1e-4, w_acc=1e-6, w_size=1e-2)
    acc = np.zeros_like(d)
    acc[1:-1] = (d[2:] - 2 * d[1:-1] + d[:-2]) * FPS**2
    after = zmp + d - 0.09 * acc  # the ZMP with the offset, its own acceleration included
    worst = max(_outside_m(after[f], SQUARE) for f in range(10, F))
    assert worst < 0.025, worst  # soft: the offset's size weight keeps it ~2 cm short of the edge
    assert _outside_m(zmp[20], SQUARE) > 0.15
    # Only the x component was outside: y barely moves.
    assert np.abs(d[15:, 1]).max() < 0.01


def test_com_outside_one_planted_foot_is_moved_over_it_and_the_foot_stays() -> None:
    scene = _one_person_scene()
    m = scene.model
    F = 20
    q = np.tile(m.qpos0, (F, 1))
    planted = np.zeros((F, 1, 2), dtype=bool)
    planted[:, 0, 0] = True  # standing on the left foot only: the CoM is between the feet
    feet, root = foot_site_ids(scene.layout), [scene.layout.persons[0].root_body]
    before = centre_of_mass(m, root, q)[:, 0, :2]
    polys = support_polygons(m, feet, q, planted, 0.0)
    assert min(_outside_m(before[f], polys[f][0]) for f in range(F)) > 0.03

    q1, offset = balance_reference(
        scene, q, planted, FPS, ReferenceConfig(balance="zmp", balance_support="planted")
    )
    after = centre_of_mass(m, root, q1)[:, 0, :2]
    polys1 = support_polygons(m, feet, q1, planted, 0.0)
    assert max(_outside_m(after[f], polys1[f][0]) for f in range(F)) < 0.005
    np.testing.assert_allclose(after - before, offset[:, 0], atol=0.01)
    d0, d1 = mujoco.MjData(m), mujoco.MjData(m)
    for f in range(F):
        d0.qpos[:], d1.qpos[:] = q[f], q1[f]
        mujoco.mj_kinematics(m, d0)
        mujoco.mj_kinematics(m, d1)
        moved = np.linalg.norm(d0.site_xpos[feet[0][0]] - d1.site_xpos[feet[0][0]], axis=-1)
        assert moved.max() < 0.005, (f, moved)


def test_none_leaves_the_reference_unchanged() -> None:
    scene = _one_person_scene()
    q = np.tile(scene.model.qpos0, (6, 1))
    planted = np.zeros((6, 1, 2), dtype=bool)
    planted[:, 0, 0] = True
    q1, offset = balance_reference(scene, q, planted, FPS, ReferenceConfig())
    np.testing.assert_array_equal(q1, q)
    assert not offset.any()
    kp = _rest_keypoints(1.0, n_frames=6)
    plain, _, _ = build_reference(scene, kp, [0], substeps=2, flat_feet=True, sole_lift_m=0.007)
    none, _, _ = build_reference(
        scene, kp, [0], substeps=2, flat_feet=True, sole_lift_m=0.007, balance=ReferenceConfig()
    )
    np.testing.assert_array_equal(none.qpos, plain.qpos)
    np.testing.assert_array_equal(none.ctrl, plain.ctrl)


def test_config_refuses_bad_balance_values() -> None:
    with pytest.raises(ValueError, match="balance_rounds"):
        ReferenceConfig(balance_rounds=0)
    with pytest.raises(ValueError, match="balance_margin_m"):
        ReferenceConfig(balance_margin_m=-0.01)
    with pytest.raises(ValueError, match="balance"):
        ReferenceConfig(balance="lipm")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="planted"):
        balance_reference(
            _one_person_scene(),
            np.zeros((5, 1)),
            np.zeros((5, 2, 2), bool),
            FPS,
            ReferenceConfig(balance="zmp"),
        )


def test_low_support_counts_an_unplanted_foot_on_the_floor() -> None:
    scene = _one_person_scene()
    F = 12
    q = np.tile(scene.model.qpos0, (F, 1))
    planted = np.zeros((F, 1, 2), dtype=bool)
    planted[:, 0, 0] = True  # the right foot rests on the floor too, only not flagged planted
    _, offset = balance_reference(
        scene, q, planted, FPS, ReferenceConfig(balance="zmp", balance_support="low")
    )
    _, offset_planted = balance_reference(
        scene, q, planted, FPS, ReferenceConfig(balance="zmp", balance_support="planted")
    )
    assert np.abs(offset).max() < 0.005
    assert np.abs(offset_planted).max() > 0.05
