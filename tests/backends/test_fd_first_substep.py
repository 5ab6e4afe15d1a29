"""A control step's Jacobians from every k-th MuJoCo substep only (``fd_interval_s``):
with k = substeps built as A^s and Σ A^i B from the first substep's finite differences, close
to the chained per-substep Jacobians when the substeps are short; k = 1 is the chain itself."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from pipeline.backends.mujoco.ilqr import ILQRConfig, fd_every, knot_jacobians  # noqa: E402
from tests.backends.test_ilqr import ARM_XML, TipCost  # noqa: E402

SUBSTEPS = 4
STEP = 0.005  # s, the arm's MuJoCo timestep here


def _arm() -> tuple[mujoco.MjModel, TipCost]:
    return mujoco.MjModel.from_xml_string(ARM_XML.replace('timestep="0.02"', 'timestep="0.005"')), TipCost(np.zeros(3))


def test_first_substep_jacobians_are_its_powers() -> None:
    model, cost = _arm()
    q, v, u = np.array([0.4, -0.9]), np.array([1.5, -2.0]), np.array([3.0, -1.0])
    d = mujoco.MjData(model)
    A_fast, B_fast = knot_jacobians(model, d, cost, q, v, np.zeros(2), u, 0, ILQRConfig(fd_interval_s=SUBSTEPS * STEP), SUBSTEPS)
    # The first substep's own finite differences, by MuJoCo.
    d.qpos[:], d.qvel[:], d.ctrl[:] = q, v, u
    A1, B1 = np.zeros((4, 4)), np.zeros((4, 2))
    mujoco.mjd_transitionFD(model, d, 1e-6, False, A1, B1, None, None)
    A_want = np.linalg.matrix_power(A1, SUBSTEPS)
    B_want = sum(np.linalg.matrix_power(A1, i) for i in range(SUBSTEPS)) @ B1
    np.testing.assert_allclose(A_fast, A_want, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(B_fast, B_want, rtol=1e-10, atol=1e-12)
    # Against the chained per-substep Jacobians: within 10 % for 5 ms substeps of a fast-swinging arm (5 % off here), not equal.
    A_all, B_all = knot_jacobians(model, mujoco.MjData(model), cost, q, v, np.zeros(2), u, 0, ILQRConfig(fd_interval_s=0.0), SUBSTEPS)
    assert not np.allclose(A_fast, A_all, rtol=0, atol=1e-9)
    assert np.abs(A_fast - A_all).max() < 0.1 * np.abs(A_all).max()
    assert np.abs(B_fast - B_all).max() < 0.1 * np.abs(B_all).max()
    # With one substep there is nothing to stand for.
    A1s, B1s = knot_jacobians(model, mujoco.MjData(model), cost, q, v, np.zeros(2), u, 0, ILQRConfig(fd_interval_s=SUBSTEPS * STEP), 1)
    assert fd_every(model, ILQRConfig(fd_interval_s=0.012)) == 2 and fd_every(model, ILQRConfig(fd_interval_s=0.0)) == 1
    np.testing.assert_array_equal(A1s, A1)
    np.testing.assert_array_equal(B1s, B1)


def test_every_second_substep_chains_two_powered_blocks(monkeypatch: pytest.MonkeyPatch) -> None:
    """k = 2 of 4 substeps: differences at substeps 0 and 2 only, each squared, chained."""
    model, cost = _arm()
    q, v, u = np.array([0.4, -0.9]), np.array([1.5, -2.0]), np.array([3.0, -1.0])
    calls: list[np.ndarray] = []
    real = mujoco.mjd_transitionFD

    def spy(m, d, eps, centred, A, B, C, D):  # type: ignore[no-untyped-def]
        real(m, d, eps, centred, A, B, C, D)
        calls.append(np.concatenate([d.qpos, d.qvel]))

    monkeypatch.setattr(mujoco, "mjd_transitionFD", spy)
    A2, B2 = knot_jacobians(model, mujoco.MjData(model), cost, q, v, np.zeros(2), u, 0, ILQRConfig(fd_interval_s=2 * STEP), SUBSTEPS)
    assert len(calls) == 2
    # The second differentiated state is the one two MuJoCo steps on.
    d = mujoco.MjData(model)
    d.qpos[:], d.qvel[:], d.ctrl[:] = q, v, u
    mujoco.mj_step(model, d)
    mujoco.mj_step(model, d)
    np.testing.assert_allclose(calls[1], np.concatenate([d.qpos, d.qvel]), atol=1e-12)
    A_all, _ = knot_jacobians(model, mujoco.MjData(model), cost, q, v, np.zeros(2), u, 0, ILQRConfig(fd_interval_s=0.0), SUBSTEPS)
    A4, _ = knot_jacobians(model, mujoco.MjData(model), cost, q, v, np.zeros(2), u, 0, ILQRConfig(fd_interval_s=4 * STEP), SUBSTEPS)
    assert np.abs(A2 - A_all).max() < np.abs(A4 - A_all).max()  # closer to the chain than one difference
