"""The clearance of the physics stage's collision term (``CostWeights.collision_clearance_m``):
two athletes closer than the clearance pay (clearance − distance)², with a gradient that
matches finite differences, and the simulated model is left as it was."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from pipeline.backends.mujoco.config import CostWeights, HumanoidConfig  # noqa: E402
from pipeline.backends.mujoco.reference import build_scene  # noqa: E402
from pipeline.backends.mujoco.skeleton import build_skeleton  # noqa: E402
from pipeline.backends.mujoco.tracking import Reference, TrackingCost  # noqa: E402
from pipeline.schema.joints import COCO17_FEET  # noqa: E402
from tests.backends.test_humanoid import _DEFAULT_LENGTHS  # noqa: E402

W_COLLISION = 1000.0


def _near_miss() -> tuple[object, np.ndarray, float]:
    """Two athletes face to face, apart: the scene, the pose and the smallest distance
    between their geoms (m), from ``mj_geomDistance``."""
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    scene = build_scene([skel, skel], [0, 1], 50.0, COCO17_FEET, HumanoidConfig())
    m, lay = scene.model, scene.layout
    q = m.qpos0.copy()
    for p, x, quat in ((lay.persons[0], 0.0, [1, 0, 0, 0]), (lay.persons[1], 0.45, [0, 0, 0, 1])):
        q[p.qpos_adr : p.qpos_adr + 3] = [x, 0.0, skel.pelvis_height_m]
        q[p.qpos_adr + 3 : p.qpos_adr + 7] = quat
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    geoms = [np.flatnonzero(lay.geom_person == i) for i in (0, 1)]
    fromto = np.zeros(6)
    dist = min(mujoco.mj_geomDistance(m, d, int(a), int(b), 1.0, fromto) for a, b in itertools.product(*geoms))
    return scene, q, float(dist)


def _cost(scene: object, q: np.ndarray, clearance_m: float) -> TrackingCost:
    m, lay = scene.model, scene.layout  # type: ignore[attr-defined]
    F, P = 3, len(lay.persons)
    ref = Reference(
        site_ids=np.zeros((P, 0), np.int64),
        site_local_m=np.zeros((F, P, 0, 3)),
        site_world_m=np.zeros((F, P, 0, 3)),
        site_weight=np.zeros((F, P, 0)),
        qpos=np.tile(q, (F, 1)),
        qvel=np.zeros((F, m.nv)),
        ctrl=np.zeros((F, m.nu)),
    )
    # As ``optimise_bout`` does: the collision term reads every pair of the athletes' geoms.
    weights = CostWeights(w_collision=W_COLLISION, collision_clearance_m=clearance_m)
    return TrackingCost(m, lay, ref, weights, probe=scene.collision_probe())  # type: ignore[attr-defined]


def test_clearance_prices_a_near_miss_and_leaves_the_simulation_alone() -> None:
    scene, q, dist = _near_miss()
    m = scene.model  # type: ignore[attr-defined]
    assert 0.005 < dist < 0.2
    margin_before = m.geom_margin.copy()
    data = mujoco.MjData(m)
    data.qpos[:] = q
    mujoco.mj_forward(m, data)
    # Apart: no cost without a clearance.
    assert _cost(scene, q, 0.0).value(m, data, 1, None) == pytest.approx(0.0, abs=1e-12)
    # 1 cm more clearance than the gap: the nearest pair pays w · (1 cm)², other pairs
    # closer than the clearance a little more.
    clear = dist + 0.01
    cost = _cost(scene, q, clear)
    c = cost.value(m, data, 1, None)
    assert c >= W_COLLISION * 0.01**2 * (1 - 1e-6)
    assert c < 20 * W_COLLISION * 0.01**2
    np.testing.assert_array_equal(m.geom_margin, margin_before)
    # Its gradient in the second athlete's root position matches finite differences.
    lx, _, _, _ = cost.derivatives(m, data, 1, None)
    x_dof = scene.layout.persons[1].qvel_adr  # type: ignore[attr-defined]
    x_adr = scene.layout.persons[1].qpos_adr  # type: ignore[attr-defined]
    eps = 1e-6
    vals = []
    for s in (1, -1):
        data.qpos[:] = q
        data.qpos[x_adr] += s * eps
        mujoco.mj_forward(m, data)
        vals.append(cost.value(m, data, 1, None))
    fd = (vals[0] - vals[1]) / (2 * eps)
    assert fd < -1.0  # moving the second athlete away (+x) lowers the cost
    assert lx[x_dof] == pytest.approx(fd, rel=1e-3)


def test_physics_config_refuses_a_negative_clearance() -> None:
    from pipeline.stages.physics import PhysicsConfig

    with pytest.raises(ValueError, match="CostWeights.collision_clearance_m must be >= 0"):
        PhysicsConfig(solver={"weights": {"collision_clearance_m": -0.01}})
