"""The iLQR's shortcuts change no number: line-search rollouts stopped once their cost
exceeds the best total so far pick the same step, and the backward pass with its
products on worker threads returns the serial gains bit for bit."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

import pipeline.backends.mujoco.ilqr as ilqr  # noqa: E402
from pipeline.backends.mujoco.ilqr import (  # noqa: E402
    Bound,
    ILQRConfig,
    Linearisation,
    Trajectory,
    Workers,
    _candidates,
    backward_pass,
    linearise,
    optimise,
    rollout,
)
from pipeline.backends.mujoco.tracking import _skew, _skews  # noqa: E402
from tests.backends.test_ilqr_parallel import SUBSTEPS, PushedTipCost, _line_search_inputs, _problem  # noqa: E402


class NonNegativeCost(PushedTipCost):
    """``PushedTipCost`` (a sum of squares) marked as such: ``optimise`` may stop rollouts."""

    non_negative = True


SMALL_MU = 1e-6
"""Regularisation of the line-search tests: the full step overshoots, so some candidates are worse than others."""


@pytest.mark.parametrize("threads", [1, 2])
def test_bounded_line_search_picks_the_same_step(threads: int) -> None:
    model, data, cost, q0, v0, nominal, K, k, alphas, act = _line_search_inputs(SMALL_MU)
    full = _candidates(model, data, cost, q0, v0, nominal, K, k, alphas, act, 0, None, SUBSTEPS, None)
    with Workers(model, threads) as w:
        cut = _candidates(model, data, cost, q0, v0, nominal, K, k, alphas, act, 0, None, SUBSTEPS, w, Bound(nominal.total))
    totals, cut_totals = [c.total for c in full], [c.total for c in cut]
    assert min(totals) < nominal.total
    assert int(np.argmin(cut_totals)) == int(np.argmin(totals))
    assert min(cut_totals) == min(totals)
    best = int(np.argmin(totals))
    np.testing.assert_array_equal(cut[best].qpos, full[best].qpos)
    np.testing.assert_array_equal(cut[best].ctrl, full[best].ctrl)
    stopped = [i for i, c in enumerate(cut) if c.cut]
    # Some rollout was stopped early (else this test checks nothing), and each stopped one
    # is truly worse than the chosen step, before the end of its horizon.
    assert stopped
    for i in stopped:
        assert totals[i] > min(totals)
        assert np.count_nonzero(cut[i].costs) < cut[i].costs.size
    for i, c in enumerate(cut):
        if not c.cut:
            assert c.total == totals[i]


def test_rollout_stops_once_over_the_bound() -> None:
    model, cost, ctrl = _problem()
    q0, v0 = np.array([0.3, -0.8]), np.zeros(2)
    data = mujoco.MjData(model)
    free = rollout(model, data, cost, q0, v0, ctrl, substeps=SUBSTEPS)
    loose = rollout(model, data, cost, q0, v0, ctrl, substeps=SUBSTEPS, bound=Bound(float("inf")))
    assert not loose.cut and loose.total == free.total
    np.testing.assert_array_equal(loose.qpos, free.qpos)
    half = 0.5 * free.total
    tight = rollout(model, data, cost, q0, v0, ctrl, substeps=SUBSTEPS, bound=Bound(half))
    assert tight.cut and tight.total == float("inf")
    # Stopped at the first step whose running cost passes the bound.
    n = int(np.argmax(np.cumsum(free.costs) > half * (1.0 + Bound.SLACK)))
    np.testing.assert_array_equal(tight.costs[: n + 1], free.costs[: n + 1])
    assert not tight.costs[n + 1 :].any()


def _random_linearisation(H: int = 6, nx: int = 12, na: int = 5) -> Linearisation:
    rng = np.random.default_rng(7)

    def spd(n: int) -> np.ndarray:
        m = rng.standard_normal((n, n))
        return m @ m.T / n + 0.1 * np.eye(n)

    return Linearisation(
        A=np.eye(nx) + 0.1 * rng.standard_normal((H, nx, nx)),
        B=0.3 * rng.standard_normal((H, nx, na)),
        lx=rng.standard_normal((H + 1, nx)),
        lu=rng.standard_normal((H, na)),
        lxx=np.stack([spd(nx) for _ in range(H + 1)]),
        luu=np.stack([spd(na) for _ in range(H)]),
    )


def test_backward_pass_on_threads_equals_the_serial_one() -> None:
    lin = _random_linearisation()
    serial = backward_pass(lin, 1e-3)
    with ThreadPoolExecutor(2) as pool:
        threaded = backward_pass(lin, 1e-3, pool)
    assert serial is not None and threaded is not None
    np.testing.assert_array_equal(threaded[0], serial[0])
    np.testing.assert_array_equal(threaded[1], serial[1])
    assert threaded[2:] == serial[2:]
    assert np.abs(serial[0]).max() > 0.0


def test_backward_pass_on_threads_reports_a_non_pd_q_uu() -> None:
    lin = _random_linearisation()
    lin.luu[2] = -10.0 * np.eye(lin.luu.shape[1])
    assert backward_pass(lin, 1e-3) is None
    with ThreadPoolExecutor(2) as pool:
        assert backward_pass(lin, 1e-3, pool) is None


def test_skews_are_the_rows_cross_product_matrices() -> None:
    a = np.random.default_rng(1).standard_normal((5, 3))
    s = _skews(a)
    for i in range(5):
        np.testing.assert_array_equal(s[i], _skew(a[i]))
        np.testing.assert_allclose(s[i] @ [1.0, 2.0, 3.0], np.cross(a[i], [1.0, 2.0, 3.0]), atol=1e-12)


@pytest.mark.parametrize("threads", [1, 2])
def test_optimise_with_stopped_rollouts_gives_the_same_result(threads: int, monkeypatch: pytest.MonkeyPatch) -> None:
    model, cost, ctrl = _problem()
    marked = NonNegativeCost(cost.target)
    cfg = ILQRConfig(max_iter=6, rel_tol=0.0, deriv_every=4, mu_init=1e-6)
    q0, v0 = np.array([0.3, -0.8]), np.zeros(2)
    stopped: list[bool] = []
    real = ilqr.rollout

    def recording(*args: object, **kwargs: object) -> Trajectory:
        tr = real(*args, **kwargs)  # type: ignore[arg-type]
        stopped.append(tr.cut)
        return tr

    monkeypatch.setattr(ilqr, "rollout", recording)
    plain = optimise(model, mujoco.MjData(model), cost, q0, v0, ctrl, cfg, substeps=SUBSTEPS, threads=threads)
    assert not any(stopped)  # an unmarked cost: no bound
    fast = optimise(model, mujoco.MjData(model), marked, q0, v0, ctrl, cfg, substeps=SUBSTEPS, threads=threads)
    assert any(stopped)
    assert len(plain.cost_history) > 2 and plain.cost_history[-1] < plain.cost_history[0]
    assert fast.cost_history == plain.cost_history
    assert fast.iterations == plain.iterations and fast.mu == plain.mu
    np.testing.assert_array_equal(fast.traj.qpos, plain.traj.qpos)
    np.testing.assert_array_equal(fast.traj.ctrl, plain.traj.ctrl)


class ThreadSafeDerivatives(PushedTipCost):
    """``PushedTipCost`` whose derivatives keep no shared scratch: they may run on threads."""

    derivatives_thread_safe = True

    def __init__(self, target: np.ndarray) -> None:
        super().__init__(target)
        self.threads: set[str] = set()

    def derivatives(
        self, model: mujoco.MjModel, data: mujoco.MjData, t: int, u: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        self.threads.add(threading.current_thread().name)
        jac = np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jac, None, 0)
        r = data.site_xpos[0] - self.target
        nv = model.nv
        lx, lxx = np.zeros(2 * nv), np.zeros((2 * nv, 2 * nv))
        lx[:nv] = 20.0 * jac.T @ r + 0.1 * t
        lxx[:nv, :nv] = 20.0 * jac.T @ jac
        lx[nv:] = 0.02 * data.qvel
        lxx[nv:, nv:] = 0.02 * np.eye(nv)
        if u is None:
            return lx, np.zeros(model.nu), lxx, np.zeros((model.nu, model.nu))
        return lx, 2e-3 * u, lxx, 2e-3 * np.eye(model.nu)


def test_cost_derivatives_on_threads_equal_the_serial_ones() -> None:
    model, cost, ctrl = _problem()
    safe = ThreadSafeDerivatives(cost.target)
    traj = rollout(model, mujoco.MjData(model), safe, np.array([0.3, -0.8]), np.zeros(2), ctrl, substeps=SUBSTEPS)
    act = np.arange(model.nu)
    cfg = ILQRConfig(deriv_every=3)
    first = linearise(model, mujoco.MjData(model), safe, traj, cfg, act, t0=4, substeps=SUBSTEPS)
    # Re-using the dynamics: no finite differences, the cost derivatives go to the threads.
    serial = linearise(model, mujoco.MjData(model), safe, traj, cfg, act, t0=4, dynamics=first, substeps=SUBSTEPS)
    safe.threads.clear()
    with Workers(model, 2) as w:
        threaded = linearise(model, mujoco.MjData(model), safe, traj, cfg, act, t0=4, dynamics=first, substeps=SUBSTEPS, workers=w)
    assert safe.threads and all(name.startswith("ilqr") for name in safe.threads)
    assert np.abs(serial.lx[:, :2] - serial.lx[0, :2]).max() > 1e-3  # they differ along the horizon
    for name in ("lx", "lu", "lxx", "luu"):
        np.testing.assert_array_equal(getattr(threaded, name), getattr(serial, name), err_msg=name)
        np.testing.assert_array_equal(getattr(threaded, name), getattr(first, name), err_msg=name)
