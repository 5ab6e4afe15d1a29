"""A person absent from the input is simulated as a stand-in that touches the floor and itself
(as built) only: no contact with the athletes in view in the simulation, the collision cost or
the separation (``pipeline.backends.mujoco.absent``)."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from pipeline.backends.mujoco.absent import AbsentContacts, absent_persons, geom_groups  # noqa: E402
from pipeline.backends.mujoco.config import HumanoidConfig  # noqa: E402
from pipeline.backends.mujoco.reference import build_scene  # noqa: E402
from pipeline.backends.mujoco.separation import separate_persons  # noqa: E402
from pipeline.backends.mujoco.skeleton import build_skeleton  # noqa: E402
from pipeline.schema.joints import COCO17_FEET  # noqa: E402
from tests.backends.test_clearance import _cost  # noqa: E402
from tests.backends.test_humanoid import _DEFAULT_LENGTHS  # noqa: E402

BOTH, SECOND_ABSENT = np.array([False, False]), np.array([False, True])


def _overlapping() -> tuple[object, np.ndarray]:
    """Two athletes 0.2 m apart face to face (their bodies overlap), feet 5 mm into the floor."""
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    scene = build_scene([skel, skel], [0, 1], 50.0, COCO17_FEET, HumanoidConfig())
    m, lay = scene.model, scene.layout
    q = m.qpos0.copy()
    for p, x, quat in ((lay.persons[0], 0.0, [1, 0, 0, 0]), (lay.persons[1], 0.2, [0, 0, 0, 1])):
        q[p.qpos_adr : p.qpos_adr + 3] = [x, 0.0, skel.pelvis_height_m - 0.005]
        q[p.qpos_adr + 3 : p.qpos_adr + 7] = quat
    return scene, q


def _contact_pairs(m: object, geom_person: np.ndarray, q: np.ndarray) -> set[tuple[int, int]]:
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_fwdPosition(m, d)
    g = d.contact.geom[: d.ncon]
    return {tuple(sorted((int(geom_person[a]), int(geom_person[b])))) for a, b in g}  # type: ignore[misc]


def test_an_absent_person_touches_no_athlete_in_view_in_the_simulation() -> None:
    scene, q = _overlapping()
    m, gp = scene.model, scene.layout.geom_person  # type: ignore[attr-defined]
    assert {(0, 1), (-1, 0), (-1, 1)} <= _contact_pairs(m, gp, q)  # as built: they collide, both stand
    switch = AbsentContacts(m, gp)
    switch.apply(SECOND_ABSENT)
    pairs = _contact_pairs(m, gp, q)
    assert (0, 1) not in pairs and (-1, 0) in pairs and (-1, 1) in pairs
    # Stand-ins keep their contacts among themselves, and so each its own self-collision: with
    # neither, Shelf's 3-actor physics (no inter-person contact at all) moved, PCP 97.17 ->
    # 96.84 %; with them it is unchanged.
    switch.apply(np.array([True, True]))
    assert {(0, 1), (-1, 0), (-1, 1)} <= _contact_pairs(m, gp, q)
    switch.restore()
    assert (0, 1) in _contact_pairs(m, gp, q)


def test_the_collision_cost_and_the_separation_leave_an_absent_person_out() -> None:
    scene, q = _overlapping()
    m = scene.model  # type: ignore[attr-defined]
    cost = _cost(scene, q, clearance_m=0.01)
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_fwdPosition(m, d)
    both = cost.value(m, d, 0, None)
    cost.set_absent(SECOND_ABSENT)
    alone = cost.value(m, d, 0, None)
    assert both > 1.0 and alone < 1e-3 * both  # the overlap is what both pay for
    moved = separate_persons(scene, q)  # type: ignore[arg-type]
    kept = separate_persons(scene, q, absent=SECOND_ABSENT)  # type: ignore[arg-type]
    assert np.abs(moved - q).max() > 0.01 and np.array_equal(kept, q)


def test_absence_is_read_from_the_site_weights() -> None:
    w = np.ones((10, 3, 4))
    w[2:6, 1] = 0.0  # person 1 unseen in frames 2-5
    w[:, 2, 1:] = 0.0  # person 2 seen through one site
    assert absent_persons(w, 2, 6).tolist() == [False, True, False]
    assert absent_persons(w, 2, 7).tolist() == [False, False, False]
    gp = np.array([-1, 0, 0, 1, 2])
    assert geom_groups(gp, np.array([False, True, False])).tolist() == [-1, 0, 0, -1, 2]
    assert geom_groups(gp, BOTH.repeat(2)[:3]) is gp
