"""Flat sole boxes under mesh feet (``HumanoidConfig.mesh_foot_sole``): the outline, and a
level foot resting on its sole from heel to toes instead of on its forefoot."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from pipeline.backends.mujoco.config import HumanoidConfig  # noqa: E402
from pipeline.backends.mujoco.humanoid import (  # noqa: E402
    SOLE_HALF_HEIGHT_M,
    build_scene_mjcf,
    load_model,
    scene_layout,
    sole_box,
)


def _yawed_foot(yaw: float, rng: np.random.Generator) -> np.ndarray:
    """Foot-like points: a 24 x 9 cm sole (a 9 x 5 grid, up to 4 mm uneven) at z = -0.07,
    yawed by ``yaw`` about z and centred at (0.05, 0.01), plus an instep 3-8 cm above it."""
    L, W = 0.12, 0.045
    gx, gy = np.meshgrid(np.linspace(-L, L, 9), np.linspace(-W, W, 5))
    top = rng.uniform([-0.5 * L, -W], [0.5 * L, W], size=(30, 2))
    xy = np.vstack([np.column_stack([gx.ravel(), gy.ravel()]), top])
    z = np.concatenate([-0.07 + rng.uniform(0.0, 0.004, size=45), rng.uniform(-0.04, 0.01, size=30)])
    z[0] = -0.07
    c, s = np.cos(yaw), np.sin(yaw)
    xy = xy @ np.array([[c, s], [-s, c]]) + np.array([0.05, 0.01])
    return np.column_stack([xy, z])


@pytest.mark.parametrize("yaw", [0.0, 0.3, -0.2])
def test_sole_box_recovers_a_yawed_sole(yaw: float) -> None:
    v = _yawed_foot(yaw, np.random.default_rng(0))
    centre, half, quat = sole_box(v)
    np.testing.assert_allclose(half, [0.12, 0.045, SOLE_HALF_HEIGHT_M], atol=1e-6)
    np.testing.assert_allclose(centre, [0.05, 0.01, -0.07 + SOLE_HALF_HEIGHT_M], atol=1e-6)
    assert 2.0 * np.arctan2(quat[3], quat[0]) == pytest.approx(yaw, abs=1e-6)
    assert quat[1] == quat[2] == 0.0


def test_sole_box_refuses_too_few_or_collinear_points() -> None:
    with pytest.raises(ValueError, match=">= 3 foot vertices"):
        sole_box(np.zeros((2, 3)))
    line = np.column_stack([np.linspace(0, 0.2, 10), np.zeros(10), np.zeros(10)])
    with pytest.raises(ValueError, match="degenerate"):
        sole_box(line)


def _foot_contacts(mesh_foot_sole: str) -> tuple[list[tuple[str, np.ndarray]], float]:
    """A keypoint-free anny humanoid with mesh feet, in its rest pose (feet level), lowered
    until its lowest sole point is 7 mm up (inside the 8 mm floor margin, as the reference
    stands planted feet): ([(body, floor contact position in the body's frame)], mass kg)."""
    pytest.importorskip("anny")
    from pipeline.backends.anny.body import bone_names
    from pipeline.backends.anny.humanoid import skeleton_from_bodyfit
    from pipeline.backends.anny.model import DEFAULT_RIG
    from pipeline.schema.results import BodyFit
    from pipeline.synthetic.anny_motion import make_anny_motion

    mo = make_anny_motion(2, seed=0)
    bf = BodyFit(
        body_model="anny",
        rig=DEFAULT_RIG,
        bone_names=bone_names(),
        person_ids=np.array([0]),
        frame_indices=np.arange(2),
        fps=50.0,
        shape=mo.shape[None],
        pose=mo.pose_aa[:, None],
        root_translation_m=mo.root_m[:, None],
        valid=np.ones((2, 1), bool),
        loss_final=np.zeros(1),
    )
    skel = skeleton_from_bodyfit(bf, 0, None, "mesh")
    cfg = HumanoidConfig(mesh_foot_sole=mesh_foot_sole)  # type: ignore[arg-type]
    model = load_model(build_scene_mjcf([skel], [0], 50.0, cfg))
    layout = scene_layout(model, [0])
    d = mujoco.MjData(model)
    mujoco.mj_forward(model, d)
    floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    lowest = min(
        mujoco.mj_geomDistance(model, d, floor, int(g), 1.0, None)
        for g in np.flatnonzero(layout.geom_is_foot)
    )
    d.qpos[layout.persons[0].qpos_adr + 2] += 0.007 - lowest
    mujoco.mj_forward(model, d)
    out = []
    for i in range(d.ncon):
        c = d.contact[i]
        if floor not in (c.geom1, c.geom2):
            continue
        b = int(model.geom_bodyid[c.geom2 if c.geom1 == floor else c.geom1])
        out.append((model.body(b).name, d.xmat[b].reshape(3, 3).T @ (c.pos - d.xpos[b])))
    return out, layout.persons[0].mass_kg


def test_box_sole_carries_a_level_foot_from_heel_to_toes() -> None:
    """With the hull alone MuJoCo keeps <= 3 contacts per foot, all near its lowest vertex in
    the forefoot; the sole box adds its 4 corners, behind the ankle and at the toes, at the
    same mass."""
    hull, m_hull = _foot_contacts("hull")
    box, m_box = _foot_contacts("box")
    assert m_box == pytest.approx(m_hull, rel=1e-9)
    for side in ("left", "right"):
        xh = np.array([p[0] for b, p in hull if b == f"p0_{side}_foot"])
        xb = np.array([p[0] for b, p in box if b == f"p0_{side}_foot"])
        assert 1 <= xh.size <= 3 and xb.size >= xh.size + 4
        assert xb.min() < -0.02 < 0.10 < xb.max()  # heel behind the ankle, toes well ahead
        assert np.ptp(xb) > 2.0 * np.ptp(xh) and np.ptp(xb) > 0.15
    assert all(b.endswith("_foot") for b, _ in hull + box)  # only the feet touch
