"""iLQR on tiny models: monotone cost decrease, adjoint gradient vs finite
differences, and the collision term separating two overlapping capsules."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from pipeline.backends.mujoco.ilqr import ILQRConfig, linearise, optimise, rollout, trajectory_gradient  # noqa: E402
from pipeline.backends.mujoco.tracking import collision_depths  # noqa: E402

ARM_XML = """
<mujoco>
  <option timestep="0.02" integrator="implicitfast"/>
  <worldbody>
    <body name="upper" pos="0 0 1">
      <joint name="shoulder" type="hinge" axis="0 1 0" damping="0.2"/>
      <geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.04"/>
      <body name="lower" pos="0.4 0 0">
        <joint name="elbow" type="hinge" axis="0 1 0" damping="0.2"/>
        <geom type="capsule" fromto="0 0 0 0.35 0 0" size="0.035"/>
        <site name="tip" pos="0.35 0 0"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="shoulder" ctrlrange="-20 20"/>
    <motor joint="elbow" ctrlrange="-10 10"/>
  </actuator>
</mujoco>
"""


class TipCost:
    """Quadratic cost: fingertip to a target + small velocity and control terms."""

    def __init__(self, target: np.ndarray) -> None:
        self.target = target
        self.jac = np.zeros((3, 2))

    def prepare(self, model: mujoco.MjModel, data: mujoco.MjData, t: int, sub: int = 0) -> None:
        pass

    def value(self, model: mujoco.MjModel, data: mujoco.MjData, t: int, u: np.ndarray | None) -> float:
        r = data.site_xpos[0] - self.target
        c = 10.0 * float(r @ r) + 0.01 * float(data.qvel @ data.qvel)
        return c + (1e-3 * float(u @ u) if u is not None else 0.0)

    def derivatives(
        self, model: mujoco.MjModel, data: mujoco.MjData, t: int, u: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        nv = model.nv
        mujoco.mj_jacSite(model, data, self.jac, None, 0)
        r = data.site_xpos[0] - self.target
        lx = np.zeros(2 * nv)
        lxx = np.zeros((2 * nv, 2 * nv))
        lx[:nv] = 20.0 * self.jac.T @ r
        lxx[:nv, :nv] = 20.0 * self.jac.T @ self.jac
        lx[nv:] = 0.02 * data.qvel
        lxx[nv:, nv:] = 0.02 * np.eye(nv)
        if u is None:
            return lx, np.zeros(model.nu), lxx, np.zeros((model.nu, model.nu))
        return lx, 2e-3 * u, lxx, 2e-3 * np.eye(model.nu)


def test_ilqr_decreases_cost_monotonically() -> None:
    model = mujoco.MjModel.from_xml_string(ARM_XML)
    data = mujoco.MjData(model)
    cost = TipCost(np.array([0.3, 0.0, 1.45]))
    res = optimise(model, data, cost, np.zeros(2), np.zeros(2), np.zeros((30, 2)), ILQRConfig(max_iter=15, rel_tol=0.0))
    hist = np.array(res.cost_history)
    assert np.all(np.diff(hist) <= 1e-12)
    assert hist[-1] < 0.2 * hist[0]
    # The accepted trajectory is a genuine simulation of its controls.
    again = rollout(model, data, cost, np.zeros(2), np.zeros(2), res.traj.ctrl)
    assert again.total == pytest.approx(res.traj.total, rel=1e-9)


def test_line_search_on_threads_gives_the_same_result() -> None:
    """Candidates rolled out together (each on its own MjData) pick the same steps."""
    model = mujoco.MjModel.from_xml_string(ARM_XML)
    cost = TipCost(np.array([0.3, 0.0, 1.45]))
    runs = [
        optimise(
            model, mujoco.MjData(model), cost, np.zeros(2), np.zeros(2), np.zeros((30, 2)),
            ILQRConfig(max_iter=6, rel_tol=0.0, threads=th),
        )
        for th in (1, 3)
    ]
    assert runs[0].cost_history == runs[1].cost_history
    np.testing.assert_array_equal(runs[0].traj.qpos, runs[1].traj.qpos)
    assert runs[1].cost_history[-1] < 0.5 * runs[1].cost_history[0]


@pytest.mark.parametrize("substeps", [1, 2])
def test_adjoint_gradient_matches_finite_differences(substeps: int) -> None:
    model = mujoco.MjModel.from_xml_string(ARM_XML.replace('timestep="0.02"', f'timestep="{0.02 / substeps}"'))
    data = mujoco.MjData(model)
    cost = TipCost(np.array([0.2, 0.0, 1.5]))
    rng = np.random.default_rng(0)
    U = rng.uniform(-3, 3, size=(8, 2))
    q0, v0 = np.array([0.3, -0.4]), np.array([0.5, 0.0])
    cfg = ILQRConfig(deriv_every=1, fd_centered=True, fd_interval_s=0.0)  # every substep: the exact chain
    traj = rollout(model, data, cost, q0, v0, U, substeps=substeps)
    g = trajectory_gradient(linearise(model, data, cost, traj, cfg, np.arange(2), substeps=substeps))
    eps = 1e-5
    for t, j in [(0, 0), (3, 1), (5, 0), (7, 1)]:
        up, um = U.copy(), U.copy()
        up[t, j] += eps
        um[t, j] -= eps
        fd = (rollout(model, data, cost, q0, v0, up, substeps=substeps).total - rollout(model, data, cost, q0, v0, um, substeps=substeps).total) / (2 * eps)
        assert g[t, j] == pytest.approx(fd, rel=1e-3, abs=1e-6)


class OffsetTipCost(TipCost):
    """TipCost whose ``prepare`` moves the controls at every substep by a known,
    time-dependent offset (as the physics stage's servo schedule does)."""

    def prepare(self, model: mujoco.MjModel, data: mujoco.MjData, t: int, sub: int = 0) -> None:
        data.ctrl[:] += np.array([2.0 * np.sin(t + 0.7 * sub), -1.5 * sub])


def test_substep_offsets_are_applied_once_and_differentiated() -> None:
    """Offsets added by ``prepare`` last one substep (the rollout resets the controls to
    u_t before each call, so they do not pile up), and the chained Jacobians through
    the substeps still give the exact gradient of the total cost."""
    substeps = 3
    model = mujoco.MjModel.from_xml_string(ARM_XML.replace('timestep="0.02"', f'timestep="{0.02 / substeps}"'))
    data = mujoco.MjData(model)
    cost = OffsetTipCost(np.array([0.2, 0.0, 1.5]))
    U = np.random.default_rng(1).uniform(-3, 3, size=(6, 2))
    q0, v0 = np.array([0.3, -0.4]), np.zeros(2)
    traj = rollout(model, data, cost, q0, v0, U, substeps=substeps)
    # The same simulation by hand: ctrl = u_t + offset(t, sub) at every substep.
    d = mujoco.MjData(model)
    d.qpos[:], d.qvel[:] = q0, v0
    for t in range(U.shape[0]):
        for sub in range(substeps):
            d.ctrl[:] = U[t]
            cost.prepare(model, d, t, sub)
            mujoco.mj_step(model, d)
    np.testing.assert_allclose(traj.qpos[-1], d.qpos, atol=1e-12)
    cfg = ILQRConfig(deriv_every=1, fd_centered=True, fd_interval_s=0.0)  # every substep: the exact chain
    g = trajectory_gradient(linearise(model, data, cost, traj, cfg, np.arange(2), substeps=substeps))
    eps = 1e-5
    for t, j in [(0, 0), (2, 1), (5, 0)]:
        up, um = U.copy(), U.copy()
        up[t, j] += eps
        um[t, j] -= eps
        fd = (rollout(model, data, cost, q0, v0, up, substeps=substeps).total - rollout(model, data, cost, q0, v0, um, substeps=substeps).total) / (2 * eps)
        assert g[t, j] == pytest.approx(fd, rel=1e-3, abs=1e-6)


TWO_CAPSULES_XML = """
<mujoco>
  <option timestep="0.02" gravity="0 0 0" integrator="implicitfast"/>
  <worldbody>
    <body name="a" pos="0 0 1">
      <joint name="ax" type="slide" axis="1 0 0" damping="5"/>
      <geom type="capsule" fromto="0 0 -0.3 0 0 0.3" size="0.1" mass="1"/>
    </body>
    <body name="b" pos="0.12 0 1">
      <joint name="bx" type="slide" axis="1 0 0" damping="5"/>
      <geom type="capsule" fromto="0 0 -0.3 0 0 0.3" size="0.1" mass="1"/>
    </body>
  </worldbody>
  <actuator>
    <motor joint="ax" ctrlrange="-50 50"/>
    <motor joint="bx" ctrlrange="-50 50"/>
  </actuator>
</mujoco>
"""


class CollisionOnlyCost:
    """w4 · depth² between the two capsules (groups 0 and 1) + tiny control effort.

    The simulated model has contacts disabled, so only the cost term can separate
    the capsules; depths are read from a probe copy of the model with contacts on.
    """

    def __init__(self) -> None:
        self.groups = np.array([0, 1])
        self.probe = mujoco.MjModel.from_xml_string(TWO_CAPSULES_XML)
        self.probe_data = mujoco.MjData(self.probe)

    def _depths(self, data: mujoco.MjData, with_jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        self.probe_data.qpos[:] = data.qpos
        mujoco.mj_fwdPosition(self.probe, self.probe_data)
        return collision_depths(self.probe, self.probe_data, self.groups, with_jac)

    def prepare(self, model: mujoco.MjModel, data: mujoco.MjData, t: int, sub: int = 0) -> None:
        pass

    def value(self, model: mujoco.MjModel, data: mujoco.MjData, t: int, u: np.ndarray | None) -> float:
        depth, _ = self._depths(data, False)
        return 20.0 * float(depth @ depth) + (1e-6 * float(u @ u) if u is not None else 0.0) + 1e-3 * float(data.qvel @ data.qvel)

    def derivatives(
        self, model: mujoco.MjModel, data: mujoco.MjData, t: int, u: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        nv = model.nv
        depth, J = self._depths(data, True)
        assert J is not None
        lx = np.zeros(2 * nv)
        lxx = np.zeros((2 * nv, 2 * nv))
        lx[:nv] = 40.0 * J.T @ depth
        lxx[:nv, :nv] = 40.0 * J.T @ J
        lx[nv:] = 2e-3 * data.qvel
        lxx[nv:, nv:] = 2e-3 * np.eye(nv)
        lu = 2e-6 * u if u is not None else np.zeros(model.nu)
        return lx, lu, lxx, 2e-6 * np.eye(model.nu)


def test_collision_depth_jacobian_matches_finite_differences() -> None:
    model = mujoco.MjModel.from_xml_string(TWO_CAPSULES_XML)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    depth, J = collision_depths(model, data, np.array([0, 1]), True)
    # Parallel capsules: MuJoCo reports two contacts, both 8 cm deep.
    assert depth.size >= 1 and np.allclose(depth, 0.08, atol=1e-6)
    assert J is not None
    data.qpos[1] += 1e-6
    mujoco.mj_forward(model, data)
    d2, _ = collision_depths(model, data, np.array([0, 1]), False)
    assert (d2[0] - depth[0]) / 1e-6 == pytest.approx(J[0, 1], rel=1e-4)
    assert J[0, 1] == pytest.approx(-1.0, abs=1e-6) and J[0, 0] == pytest.approx(1.0, abs=1e-6)


def test_collision_term_separates_overlapping_capsules() -> None:
    model = mujoco.MjModel.from_xml_string(TWO_CAPSULES_XML.replace('gravity="0 0 0"', 'gravity="0 0 0"><flag contact="disable"/></option><option'))
    data = mujoco.MjData(model)
    cost = CollisionOnlyCost()
    H = 25
    passive = rollout(model, data, cost, np.zeros(2), np.zeros(2), np.zeros((H, 2)))
    res = optimise(model, data, cost, np.zeros(2), np.zeros(2), np.zeros((H, 2)), ILQRConfig(max_iter=10, rel_tol=0.0))
    data.qpos[:] = res.traj.qpos[-1]
    depth_end, _ = cost._depths(data, False)
    data.qpos[:] = passive.qpos[-1]
    depth_passive, _ = cost._depths(data, False)
    # Without the optimiser the (force-free) contact stays at 8 cm overlap.
    assert depth_passive.size >= 1 and depth_passive.max() > 0.07
    assert depth_end.size == 0 or depth_end.max() < 0.1 * depth_passive.max()
    # Axis distance (initially 0.12 m) reaches the sum of radii (0.2 m).
    assert 0.12 + res.traj.qpos[-1, 1] - res.traj.qpos[-1, 0] > 0.195


def _count_fd_calls(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    calls = [0]
    fd = mujoco.mjd_transitionFD

    def counted(*args: object) -> None:
        calls[0] += 1
        fd(*args)

    monkeypatch.setattr(mujoco, "mjd_transitionFD", counted)
    return calls


@pytest.mark.parametrize("reuse", [1, 2, 3])
def test_jacobian_reuse_keeps_the_descent_and_skips_finite_differences(monkeypatch: pytest.MonkeyPatch, reuse: int) -> None:
    model = mujoco.MjModel.from_xml_string(ARM_XML)
    data = mujoco.MjData(model)
    cost = TipCost(np.array([0.3, 0.0, 1.45]))
    calls = _count_fd_calls(monkeypatch)
    cfg = ILQRConfig(max_iter=9, rel_tol=0.0, deriv_every=2, jacobian_reuse=reuse)
    res = optimise(model, data, cost, np.zeros(2), np.zeros(2), np.zeros((30, 2)), cfg)
    hist = np.array(res.cost_history)
    assert np.all(np.diff(hist) <= 1e-12)
    assert hist[-1] < 0.2 * hist[0]
    # Fresh Jacobians only at iterations 1, reuse + 1, 2 reuse + 1, ...: 16 knots each
    # (every 2nd of 30 steps, plus the last).
    fresh = len(range(1, res.iterations + 1, reuse))
    assert calls[0] == 16 * fresh


def test_reused_jacobians_are_the_previous_ones_with_fresh_cost_derivatives() -> None:
    model = mujoco.MjModel.from_xml_string(ARM_XML)
    data = mujoco.MjData(model)
    cost = TipCost(np.array([0.3, 0.0, 1.45]))
    cfg = ILQRConfig(deriv_every=2)
    a = rollout(model, data, cost, np.zeros(2), np.zeros(2), np.zeros((20, 2)))
    b = rollout(model, data, cost, np.zeros(2), np.zeros(2), np.full((20, 2), 3.0))
    act = np.arange(model.nu)
    lin_a = linearise(model, data, cost, a, cfg, act)
    lin_b = linearise(model, data, cost, b, cfg, act)
    reused = linearise(model, data, cost, b, cfg, act, dynamics=lin_a)
    assert reused.seconds_fd == 0.0
    np.testing.assert_array_equal(reused.A, lin_a.A)
    np.testing.assert_array_equal(reused.B, lin_a.B)
    np.testing.assert_array_equal(reused.lx, lin_b.lx)
    np.testing.assert_array_equal(reused.lxx, lin_b.lxx)
    assert not np.allclose(lin_a.lx, lin_b.lx)


def test_ilqr_config_refuses_zero_reuse() -> None:
    with pytest.raises(ValueError, match="jacobian_reuse must be an integer >= 1"):
        ILQRConfig(jacobian_reuse=0)


def test_regularisation_follows_the_ratio_of_actual_to_expected_decrease() -> None:
    from pipeline.backends.mujoco.ilqr import _updated_mu

    cfg = ILQRConfig(regularisation="improvement_ratio")
    # Expected decrease -(a dV1 + a^2 dV2) = 1.0 for a = 1, dV1 = -1.5, dV2 = 0.5.
    assert _updated_mu(1.0, 0.9, 1.0, -1.5, 0.5, cfg) == pytest.approx(cfg.mu_down)  # well predicted: lower
    assert _updated_mu(1.0, 0.05, 1.0, -1.5, 0.5, cfg) == pytest.approx(cfg.mu_up)  # poorly: raise
    assert _updated_mu(1.0, 0.3, 1.0, -1.5, 0.5, cfg) == 1.0  # in between: keep
    assert _updated_mu(1e-6, 0.9, 1.0, -1.5, 0.5, cfg) == cfg.mu_min  # bounded
    assert _updated_mu(1.0, 0.05, 1.0, -1.5, 0.5, ILQRConfig()) == pytest.approx(ILQRConfig().mu_down)  # "success"


def test_ilqr_with_the_improvement_ratio_still_descends() -> None:
    model = mujoco.MjModel.from_xml_string(ARM_XML)
    data = mujoco.MjData(model)
    cost = TipCost(np.array([0.3, 0.0, 1.45]))
    cfg = ILQRConfig(max_iter=15, rel_tol=0.0, regularisation="improvement_ratio")
    hist = np.array(optimise(model, data, cost, np.zeros(2), np.zeros(2), np.zeros((30, 2)), cfg).cost_history)
    assert np.all(np.diff(hist) <= 1e-12) and hist[-1] < 0.2 * hist[0]
