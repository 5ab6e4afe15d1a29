"""iLQR trajectory optimisation on a MuJoCo model (Tassa et al. 2012; MJPC's planner).

State x = (qpos, qvel) in tangent coordinates (nx = 2·nv, no activations), control
u = ``data.ctrl`` restricted to the ``active`` actuators (the others stay at the
nominal trajectory's values).

One iteration:
1. *Linearise* along the nominal rollout: dynamics Jacobians A, B by finite
   differences (``mujoco.mjd_transitionFD``, or ``fd_split`` for persons apart), every
   ``deriv_every`` steps with linear interpolation in between (MuJoCo MPC's derivative
   skip), within a step one MuJoCo substep per ``fd_interval_s`` standing for the next
   ones, the knots on worker threads (``Workers``); cost gradients/Gauss–Newton Hessians
   from the ``Cost``; the Riccati recursion split per person where nothing couples them.
2. *Backward pass*: Riccati recursion with Levenberg–Marquardt regularisation μ on
   Q_uu (raised ×``mu_up`` on a non-PD Q_uu or a failed line search, lowered on
   success).
3. *Forward pass*: closed-loop rollouts u = ū + K (x ⊖ x̄) + α k for log-spaced
   α ∈ [α_min, 1], on the worker threads; the lowest total cost is accepted if it is
   below the nominal's, so the cost decreases monotonically; for a cost marked
   ``non_negative``, a rollout stops once its running cost exceeds the lowest total so
   far, which changes no choice. (Not ``mujoco.rollout``:
   it rolls out open-loop controls and neither applies the feedback per step nor the
   cost's state-dependent inputs per substep, nor returns the warm start.)

Threads change no number: each runs on its own ``MjData`` and every result is the
serial one.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Protocol

import mujoco
import numpy as np

from pipeline.backends.mujoco.config import ILQRConfig
from pipeline.backends.mujoco.fd_split import PersonBlocks, transition_fd

log = logging.getLogger(__name__)

MAX_SPEED = 100.0
"""|qvel| (m/s or rad/s) above which a rollout counts as diverged."""


class UnstableRollout(ValueError):
    """The initial control sequence of an optimisation diverges in simulation."""


class Cost(Protocol):
    """Running cost l(x_t, u_t, t) and terminal cost l_T(x_T).

    ``data`` holds the state x_t after ``mj_forward`` (positions, contacts, site
    poses valid). ``u`` is the full ``ctrl`` vector (nu,). Derivatives are with
    respect to the tangent state (2·nv) and the full control (nu).

    A cost whose ``prepare`` and ``value`` may run on several threads at once (each on its
    own ``data``, alongside ``derivatives`` on the caller's thread) says so with a class
    attribute ``thread_safe = True``; ``optimise`` then uses worker threads by default.
    A cost whose ``derivatives`` may also run on several threads at once (each on its own
    ``data``) says so with ``derivatives_thread_safe = True``: without finite differences
    to compute (``ILQRConfig.jacobian_reuse``), ``linearise`` spreads them over the threads.
    A cost whose every value is >= 0 says so with ``non_negative = True``; ``optimise`` then
    stops line-search rollouts whose running cost already exceeds the best total (``Bound``).
    """

    def prepare(self, model: mujoco.MjModel, data: mujoco.MjData, t: int, sub: int = 0) -> None:
        """Before MuJoCo substep ``sub`` of control step t: set state-dependent external
        inputs (``xfrc_applied``) and, optionally, time-dependent offsets of the
        controls: the caller sets ``data.ctrl`` to u_t before every call, so an offset
        added here lasts one substep."""
        ...

    def value(self, model: mujoco.MjModel, data: mujoco.MjData, t: int, u: np.ndarray | None) -> float: ...

    def derivatives(
        self, model: mujoco.MjModel, data: mujoco.MjData, t: int, u: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(lx (nx,), lu (nu,), lxx (nx, nx), luu (nu, nu)); lu/luu zero-size when u is None."""
        ...


@dataclass
class Trajectory:
    """A rollout: H controls, H+1 states, and what the cost/derivatives need."""

    qpos: np.ndarray  # (H+1, nq)
    qvel: np.ndarray  # (H+1, nv)
    ctrl: np.ndarray  # (H, nu)
    warmstart: np.ndarray  # (H+1, nv) qacc_warmstart at each state
    actuator_force: np.ndarray  # (H, nu)
    costs: np.ndarray  # (H+1,)
    stable: bool
    cut: bool = False
    """Stopped early because its cost already exceeded ``rollout``'s ``bound`` (the states
    and costs after that step are not filled in; the total counts as infinite)."""

    @property
    def total(self) -> float:
        return float(self.costs.sum()) if self.stable and not self.cut else float("inf")


class Bound:
    """An upper bound on the total cost a rollout must stay under to matter: the lowest of
    the nominal's total and the totals of the line search's finished candidates. Rollouts
    on several threads share one and lower it (``lower``); a stale read only makes it
    looser, never wrong.

    A rollout is stopped when its running cost exceeds the bound by more than a relative
    ``SLACK``: the running sum and ``Trajectory.total`` (numpy's pairwise sum) round
    differently, by far less than that, so a stopped rollout's total is surely above the
    bound and it could not have been picked."""

    SLACK = 1e-9

    def __init__(self, value: float) -> None:
        self.value = value

    def lower(self, total: float) -> None:
        if total < self.value:
            self.value = total

    def exceeded(self, so_far: float) -> bool:
        return so_far > self.value * (1.0 + self.SLACK)


def _set_state(model: mujoco.MjModel, data: mujoco.MjData, qpos: np.ndarray, qvel: np.ndarray, warm: np.ndarray | None) -> None:
    data.qpos[:] = qpos
    data.qvel[:] = qvel
    if warm is not None:
        data.qacc_warmstart[:] = warm


def state_diff(model: mujoco.MjModel, qpos_a: np.ndarray, qvel_a: np.ndarray, qpos_b: np.ndarray, qvel_b: np.ndarray) -> np.ndarray:
    """Tangent difference x_a ⊖ x_b (2·nv,)."""
    dq = np.zeros(model.nv)
    mujoco.mj_differentiatePos(model, dq, 1.0, qpos_b, qpos_a)
    return np.concatenate([dq, qvel_a - qvel_b])


def rollout(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    cost: Cost,
    qpos0: np.ndarray,
    qvel0: np.ndarray,
    ctrl: np.ndarray,
    t0: int = 0,
    nominal: Trajectory | None = None,
    K: np.ndarray | None = None,
    k: np.ndarray | None = None,
    alpha: float = 0.0,
    active: np.ndarray | None = None,
    warm0: np.ndarray | None = None,
    substeps: int = 1,
    bound: Bound | None = None,
) -> Trajectory:
    """Simulate H = len(ctrl) control steps (each ``substeps`` MuJoCo steps with the
    control held) from (qpos0, qvel0).

    Open loop when ``nominal`` is None; otherwise closed loop
    u_t = ctrl_t + K_t (x_t ⊖ x̄_t) + α k_t on the ``active`` controls (clamped to
    ``ctrlrange`` by MuJoCo). Costs are evaluated at each state; ``t0`` offsets the
    time index passed to the cost. An unstable step (NaN, |qvel| > ``MAX_SPEED`` or
    MuJoCo's bad-QACC warning) marks the trajectory unstable (total cost = inf).
    ``bound``: stop as soon as the costs so far exceed its value (``Trajectory.cut``): the
    costs are non-negative, so such a rollout's total would exceed it too.
    """
    H = ctrl.shape[0]
    nq, nv, nu = model.nq, model.nv, model.nu
    out = Trajectory(
        qpos=np.zeros((H + 1, nq)),
        qvel=np.zeros((H + 1, nv)),
        ctrl=np.array(ctrl, dtype=float),
        warmstart=np.zeros((H + 1, nv)),
        actuator_force=np.zeros((H, nu)),
        costs=np.zeros(H + 1),
        stable=True,
    )
    _set_state(model, data, qpos0, qvel0, warm0 if warm0 is not None else np.zeros(nv))
    data.time = 0.0
    act = np.arange(nu) if active is None else active
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    limited = model.actuator_ctrllimited.astype(bool)
    bad0 = data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number
    so_far = 0.0
    ctrl_buf = data.ctrl
    for t in range(H):
        out.qpos[t] = data.qpos
        out.qvel[t] = data.qvel
        out.warmstart[t] = data.qacc_warmstart
        u = out.ctrl[t].copy()
        if nominal is not None and K is not None and k is not None:
            dx = state_diff(model, data.qpos, data.qvel, nominal.qpos[t], nominal.qvel[t])
            u[act] += K[t] @ dx + alpha * k[t]
        u = np.where(limited, np.clip(u, lo, hi), u)
        out.ctrl[t] = u
        data.ctrl[:] = u
        cost.prepare(model, data, t0 + t, 0)
        # step1 computes the position/velocity stages of x_t (sites, contacts, qvel
        # still = v_t), where the running cost is evaluated; step2 integrates.
        mujoco.mj_step1(model, data)
        c_t = out.costs[t] = cost.value(model, data, t0 + t, u)
        if bound is not None:
            so_far += c_t
            if bound.exceeded(so_far):
                out.cut = True
                return out
        mujoco.mj_step2(model, data)
        out.actuator_force[t] = data.actuator_force
        for sub in range(1, substeps):
            ctrl_buf[:] = u
            cost.prepare(model, data, t0 + t, sub)
            mujoco.mj_step(model, data)
        ok = np.all(np.isfinite(data.qvel)) and np.abs(data.qvel).max() < MAX_SPEED
        if not (ok and data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number == bad0):
            out.stable = False
            out.qpos[t + 1 :] = out.qpos[t]
            out.qvel[t + 1 :] = 0.0
            return out
    out.qpos[H] = data.qpos
    out.qvel[H] = data.qvel
    out.warmstart[H] = data.qacc_warmstart
    mujoco.mj_forward(model, data)
    out.costs[H] = cost.value(model, data, t0 + H, None)
    return out


@dataclass
class Linearisation:
    A: np.ndarray  # (H, nx, nx)
    B: np.ndarray  # (H, nx, nu_active)
    lx: np.ndarray  # (H+1, nx)
    lu: np.ndarray  # (H, nu_active)
    lxx: np.ndarray  # (H+1, nx, nx)
    luu: np.ndarray  # (H, nu_active, nu_active)
    seconds_fd: float = 0.0
    seconds_cost: float = 0.0


def default_threads() -> int:
    """Worker threads of the finite differences and the line search: 2, or fewer when this
    process may use fewer CPUs (the result does not depend on it)."""
    return max(1, min(2, len(os.sched_getaffinity(0))))


class Workers:
    """A thread pool with one ``MjData`` of ``model`` per thread (MuJoCo releases the GIL
    while it steps, so finite differences and rollouts on separate data run in parallel).

    ``threads`` = 1: no pool, everything runs on the caller's thread with its own data."""

    def __init__(self, model: mujoco.MjModel, threads: int) -> None:
        if threads < 1:
            raise ValueError(f"ilqr.Workers: threads must be >= 1, got {threads}")
        self.model = model
        self.threads = threads
        self._local = threading.local()
        self.pool = ThreadPoolExecutor(threads, thread_name_prefix="ilqr") if threads > 1 else None

    def data(self) -> mujoco.MjData:
        """The calling thread's own ``MjData`` of the model."""
        d = getattr(self._local, "d", None)
        if d is None:
            d = self._local.d = mujoco.MjData(self.model)
        return d

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()

    def __enter__(self) -> Workers:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def fd_every(model: mujoco.MjModel, cfg: ILQRConfig) -> int:
    """Every how many MuJoCo substeps ``knot_jacobians`` differentiates (``ILQRConfig.fd_interval_s``), >= 1."""
    if cfg.fd_interval_s <= 0:
        return 1
    return max(1, int(round(cfg.fd_interval_s / float(model.opt.timestep))))


def knot_jacobians(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    cost: Cost,
    qpos: np.ndarray,
    qvel: np.ndarray,
    warm: np.ndarray,
    u: np.ndarray,
    t: int,
    cfg: ILQRConfig,
    substeps: int = 1,
    blocks: PersonBlocks | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(A (nx, nx), B (nx, nu)) of one control step (``substeps`` MuJoCo steps with the
    control held, the cost's ``prepare`` before each) at state (qpos, qvel, warm start) and
    control u, by finite differences on ``data`` (overwritten), chained over the substeps:
    x' = f(f(x, u), u) (the cost's time-dependent offsets do not depend on u). Only every
    ``fd_every`` -th substep is differentiated; the substeps in between reuse its Jacobians.

    Each substep's Jacobians come from ``fd_split.transition_fd`` (one DOF of every person
    nudged per step; the same numbers) when ``blocks`` is given, ``cfg.fd_split_persons`` is on,
    the differences are forward and the persons do not touch; else ``mujoco.mjd_transitionFD``."""
    nx = 2 * model.nv
    Ab = np.zeros((nx, nx))
    Bb = np.zeros((nx, model.nu))
    split = blocks if (cfg.fd_split_persons and not cfg.fd_centered) else None

    def jacobians() -> None:
        if split is None or not transition_fd(model, data, cfg.fd_eps, split, Ab, Bb):
            mujoco.mjd_transitionFD(model, data, cfg.fd_eps, cfg.fd_centered, Ab, Bb, None, None)

    _set_state(model, data, qpos, qvel, warm)
    data.ctrl[:] = u
    cost.prepare(model, data, t, 0)
    jacobians()
    A_t, B_t = Ab.copy(), Bb.copy()
    every = fd_every(model, cfg)
    at = prepared = 0  # the substep whose start state ``data`` holds, and is prepared for
    for sub in range(1, substeps):
        if sub % every == 0:
            while at < sub:
                if prepared != at:
                    data.ctrl[:] = u
                    cost.prepare(model, data, t, at)
                    prepared = at
                mujoco.mj_step(model, data)
                at += 1
            data.ctrl[:] = u
            cost.prepare(model, data, t, sub)
            prepared = sub
            jacobians()
        # Otherwise this substep's Jacobians are those of the last differentiated one.
        A_t, B_t = Ab @ A_t, Ab @ B_t + Bb
    return A_t, B_t


def linearise(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    cost: Cost,
    traj: Trajectory,
    cfg: ILQRConfig,
    active: np.ndarray,
    t0: int = 0,
    dynamics: Linearisation | None = None,
    substeps: int = 1,
    workers: Workers | None = None,
    blocks: PersonBlocks | None = None,
) -> Linearisation:
    """Dynamics Jacobians and cost derivatives along ``traj`` (see module docstring);
    ``substeps`` MuJoCo steps per control step, chained.

    ``dynamics``: a previous linearisation whose A, B are reused (only the cost
    derivatives are recomputed; ``ILQRConfig.jacobian_reuse``). ``workers``: the knots'
    finite differences run on its threads, each on its own data, while this thread
    computes the cost derivatives on ``data``; without knots, the cost derivatives of a
    cost marked ``derivatives_thread_safe`` run on its threads (the same numbers either
    way). ``blocks``: the persons of the model, for ``knot_jacobians``."""
    H = traj.ctrl.shape[0]
    nv = model.nv
    nx, na = 2 * nv, active.size
    tick = time.perf_counter
    lin = Linearisation(
        A=np.zeros((H, nx, nx)) if dynamics is None else dynamics.A,
        B=np.zeros((H, nx, na)) if dynamics is None else dynamics.B,
        lx=np.zeros((H + 1, nx)),
        lu=np.zeros((H, na)),
        lxx=np.zeros((H + 1, nx, nx)),
        luu=np.zeros((H, na, na)),
    )
    every = max(1, cfg.deriv_every)
    knots = sorted(set(list(range(0, H, every)) + [H - 1])) if dynamics is None else []

    def fd(t: int, d: mujoco.MjData | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        c0 = tick()
        dd = d if d is not None else workers.data()  # type: ignore[union-attr]
        A_t, B_t = knot_jacobians(model, dd, cost, traj.qpos[t], traj.qvel[t], traj.warmstart[t], traj.ctrl[t], t0 + t, cfg, substeps, blocks)
        return A_t, B_t[:, active], tick() - c0

    def cost_at(t: int, d: mujoco.MjData | None = None) -> None:
        dd = d if d is not None else workers.data()  # type: ignore[union-attr]
        _set_state(model, dd, traj.qpos[t], traj.qvel[t], traj.warmstart[t])
        u = traj.ctrl[t] if t < H else None
        if u is not None:
            dd.ctrl[:] = u
        mujoco.mj_forward(model, dd)
        lx, lu, lxx, luu = cost.derivatives(model, dd, t0 + t, u)
        lin.lx[t], lin.lxx[t] = lx, lxx
        if u is not None:
            lin.lu[t] = lu[active]
            lin.luu[t] = luu[np.ix_(active, active)]

    pool = workers.pool if workers is not None else None
    c_start = tick()
    futures = [pool.submit(fd, t) for t in knots] if pool is not None else []
    if pool is not None and not knots and getattr(cost, "derivatives_thread_safe", False):
        # No finite differences to overlap with: the cost derivatives go to the idle threads.
        list(pool.map(cost_at, range(H + 1)))
    else:
        for t in range(H + 1):
            cost_at(t, data)
    lin.seconds_cost = tick() - c_start
    if not knots:
        return lin
    results = [fd(t, data) for t in knots] if pool is None else [f.result() for f in futures]
    for t, (A_t, B_t, _) in zip(knots, results, strict=True):
        lin.A[t], lin.B[t] = A_t, B_t
    # Wall time: with a pool the finite differences overlap the cost derivatives, and count
    # for the rest of this call's time.
    lin.seconds_fd = tick() - c_start - lin.seconds_cost
    for a, b in zip(knots[:-1], knots[1:], strict=True):
        for t in range(a + 1, b):
            w = (t - a) / (b - a)
            lin.A[t] = (1 - w) * lin.A[a] + w * lin.A[b]
            lin.B[t] = (1 - w) * lin.B[a] + w * lin.B[b]
    return lin


class _Done:
    """A computed value behind ``concurrent.futures.Future``'s ``result()``: the serial
    stand-in of a pool's ``submit``."""

    def __init__(self, value: object) -> None:
        self.value = value

    def result(self) -> object:
        return self.value


def _now(fn: Callable[..., object], *args: object) -> _Done:
    return _Done(fn(*args))


def _q_uu(luu: np.ndarray, B: np.ndarray, Vxx: np.ndarray) -> np.ndarray:
    return luu + B.T @ (Vxx @ B)


def _q_xx(lxx: np.ndarray, A: np.ndarray, VA: np.ndarray) -> np.ndarray:
    return lxx + A.T @ VA


def _cross(Kt: np.ndarray, Qux: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return Kt @ Qux, Qux.T @ K


def backward_pass(
    lin: Linearisation, mu: float, pool: ThreadPoolExecutor | None = None
) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """Riccati recursion; returns (K (H, nu, nx), k (H, nu), dV1, dV2) with the
    expected decrease α·dV1 + α²·dV2, or None when a regularised Q_uu is not PD.

    ``pool``: the step's independent matrix products (Q_uu, Q_xx, Kᵀ Q_ux, Q_uxᵀ K) run on
    its threads meanwhile; every product and sum is the serial one, so is the result."""
    H, nx, na = lin.B.shape
    Vx = lin.lx[H].copy()
    Vxx = lin.lxx[H].copy()
    K = np.zeros((H, na, nx))
    k = np.zeros((H, na))
    dV1 = dV2 = 0.0
    eye = np.eye(na)
    run: Callable[..., Any] = pool.submit if pool is not None else _now
    for t in range(H - 1, -1, -1):
        A, B = lin.A[t], lin.B[t]
        f_uu = run(_q_uu, lin.luu[t], B, Vxx)
        VA = Vxx @ A
        f_xx = run(_q_xx, lin.lxx[t], A, VA)
        Qx = lin.lx[t] + A.T @ Vx
        Qu = lin.lu[t] + B.T @ Vx
        Qux = B.T @ VA
        Quu: np.ndarray = f_uu.result()
        try:
            L = np.linalg.cholesky(0.5 * (Quu + Quu.T) + mu * eye)
        except np.linalg.LinAlgError:
            f_xx.result()
            return None
        rhs = np.column_stack([Qu, Qux])
        sol = np.linalg.solve(L.T, np.linalg.solve(L, rhs))
        k[t] = -sol[:, 0]
        K[t] = -sol[:, 1:]
        Kt = K[t].T
        f_cross = run(_cross, Kt, Qux, K[t])
        dV1 += float(k[t] @ Qu)
        dV2 += 0.5 * float(k[t] @ Quu @ k[t])
        KtQuu = Kt @ Quu
        Vx = Qx + KtQuu @ k[t] + Kt @ Qu + Qux.T @ k[t]
        KtQuuK = KtQuu @ K[t]
        cross: tuple[np.ndarray, np.ndarray] = f_cross.result()
        KtQux, QuxtK = cross
        Qxx: np.ndarray = f_xx.result()
        Vxx = Qxx + KtQuuK + KtQux + QuxtK
        Vxx = 0.5 * (Vxx + Vxx.T)
    return K, k, dV1, dV2


def person_parts(blocks: PersonBlocks, active: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per person, (its rows of the state (2nv,): positions then velocities, its columns of
    the active controls) for ``blocked_backward_pass``."""
    nv = blocks.nv
    return [
        (np.concatenate([d, nv + d]).astype(np.int64), np.flatnonzero(np.isin(active, a)).astype(np.int64))
        for d, a in zip(blocks.dofs, blocks.acts, strict=True)
    ]


def separable(lin: Linearisation, parts: list[tuple[np.ndarray, np.ndarray]]) -> bool:
    """True when no dynamics Jacobian or cost Hessian of the window couples two persons
    (every cross-person block of A, B, lxx and luu exactly zero): the Riccati recursion then
    splits into one per person."""
    nx, na = lin.A.shape[1], lin.B.shape[2]
    px = np.full(nx, -1)
    pu = np.full(na, -1)
    for i, (xi, ui) in enumerate(parts):
        px[xi], pu[ui] = i, i
    if (px < 0).any() or (pu < 0).any():
        return False
    cross_xx = px[:, None] != px[None, :]
    cross_xu = px[:, None] != pu[None, :]
    cross_uu = pu[:, None] != pu[None, :]
    # Which entries are nonzero at any knot, then whether any of them crosses persons: one
    # pass over each array instead of a copy of its cross-person entries.
    return not any(
        np.any(np.any(a != 0, axis=0)[cross])
        for a, cross in ((lin.A, cross_xx), (lin.lxx, cross_xx), (lin.B, cross_xu), (lin.luu, cross_uu))
    )


def blocked_backward_pass(
    lin: Linearisation, mu: float, parts: list[tuple[np.ndarray, np.ndarray]], pool: ThreadPoolExecutor | None = None
) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """``backward_pass`` of a window that is ``separable`` over ``parts``: one recursion per
    person on his blocks (on ``pool``'s threads when given), assembled into the block-diagonal
    gains. The same policy as the full recursion up to rounding (sums over the persons' own
    rows instead of all), at a fraction of its products; None when some person's Q_uu is not PD."""
    H, nx, na = lin.B.shape

    def one(part: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, float, float] | None:
        xi, ui = part
        sub = Linearisation(
            A=lin.A[:, xi][:, :, xi], B=lin.B[:, xi][:, :, ui], lx=lin.lx[:, xi], lu=lin.lu[:, ui],
            lxx=lin.lxx[:, xi][:, :, xi], luu=lin.luu[:, ui][:, :, ui],
        )
        return backward_pass(sub, mu)

    results = list(pool.map(one, parts)) if pool is not None else [one(p) for p in parts]
    K = np.zeros((H, na, nx))
    k = np.zeros((H, na))
    dV1 = dV2 = 0.0
    for (xi, ui), res in zip(parts, results, strict=True):
        if res is None:
            return None
        Kp, kp, d1, d2 = res
        K[:, ui[:, None], xi[None, :]] = Kp
        k[:, ui] = kp
        dV1 += d1
        dV2 += d2
    return K, k, dV1, dV2


def trajectory_gradient(lin: Linearisation) -> np.ndarray:
    """Exact gradient dJ/du_t (H, nu_active) of the total cost by the adjoint
    recursion λ_t = lx_t + A_tᵀ λ_{t+1} (used to check derivatives)."""
    H = lin.B.shape[0]
    lam = lin.lx[H].copy()
    g = np.zeros_like(lin.lu)
    for t in range(H - 1, -1, -1):
        g[t] = lin.lu[t] + lin.B[t].T @ lam
        lam = lin.lx[t] + lin.A[t].T @ lam
    return g


@dataclass
class ILQRResult:
    traj: Trajectory
    cost_history: list[float]
    iterations: int
    mu: float
    seconds: dict[str, float]
    """Wall time by phase: ``derivatives_fd``, ``derivatives_cost``, ``backward``, ``rollouts``."""


def optimise(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    cost: Cost,
    qpos0: np.ndarray,
    qvel0: np.ndarray,
    ctrl_init: np.ndarray,
    cfg: ILQRConfig = ILQRConfig(),
    active: np.ndarray | None = None,
    t0: int = 0,
    warm0: np.ndarray | None = None,
    substeps: int = 1,
    threads: int | None = None,
    blocks: PersonBlocks | None = None,
) -> ILQRResult:
    """Minimise Σ_t l(x_t, u_t, t0+t) + l_T(x_H) over the ``active`` controls, each control
    held for ``substeps`` MuJoCo steps (the model's timestep is the control period / substeps).

    The returned cost history is non-increasing (a step is only accepted if it
    lowers the total cost). Raises ``UnstableRollout`` if the initial rollout is unstable.

    ``threads``: worker threads of the finite differences and the line search (None:
    ``cfg.threads`` if above 0, else ``default_threads()`` for a cost marked ``thread_safe``
    and 1 for any other); the result does not depend on it. ``blocks``: the model's persons,
    whose finite differences can share steps (``knot_jacobians``).
    """
    if threads is not None:
        n_threads = threads
    elif cfg.threads > 0:
        n_threads = cfg.threads
    else:
        n_threads = default_threads() if getattr(cost, "thread_safe", False) else 1
    with Workers(model, n_threads) as workers:
        act = np.arange(model.nu) if active is None else np.asarray(active, dtype=np.int64)
        parts = person_parts(blocks, act) if (blocks is not None and cfg.backward_split_persons) else None
        secs = {"derivatives_fd": 0.0, "derivatives_cost": 0.0, "backward": 0.0, "rollouts": 0.0}
        c0 = time.perf_counter()
        nominal = rollout(model, data, cost, qpos0, qvel0, ctrl_init, t0=t0, warm0=warm0, substeps=substeps)
        secs["rollouts"] += time.perf_counter() - c0
        if not nominal.stable:
            raise UnstableRollout("iLQR: the initial control sequence makes the simulation unstable")
        history = [nominal.total]
        alphas = np.logspace(0.0, np.log10(cfg.alpha_min), cfg.n_alpha)
        mu = cfg.mu_init
        it = 0
        lin: Linearisation | None = None
        while it < cfg.max_iter:
            it += 1
            reuse = lin if (it - 1) % cfg.jacobian_reuse else None
            lin = linearise(model, data, cost, nominal, cfg, act, t0=t0, dynamics=reuse, substeps=substeps, workers=workers, blocks=blocks)
            secs["derivatives_fd"] += lin.seconds_fd
            secs["derivatives_cost"] += lin.seconds_cost
            improved = False
            tries = 0
            while mu <= cfg.mu_max and tries <= cfg.max_backtracks:
                tries += 1
                c0 = time.perf_counter()
                if parts is not None and separable(lin, parts):
                    bp = blocked_backward_pass(lin, mu, parts, workers.pool)
                else:
                    bp = backward_pass(lin, mu, workers.pool)
                secs["backward"] += time.perf_counter() - c0
                if bp is None:
                    mu = max(mu * cfg.mu_up, 1e-4)
                    continue
                K, k, dV1, dV2 = bp
                # Line search over the step sizes; step 0 (the nominal itself, what the
                # feedback policy reproduces exactly) is a candidate too: a worse step is never taken.
                best: Trajectory | None = None
                best_alpha = 0.0
                c0 = time.perf_counter()
                bound = Bound(nominal.total) if getattr(cost, "non_negative", False) else None
                cands = _candidates(
                    model, data, cost, qpos0, qvel0, nominal, K, k, alphas, act, t0, warm0, substeps, workers, bound
                )
                for a, cand in zip(alphas, cands, strict=True):
                    if cand.total < (best.total if best is not None else nominal.total):
                        best, best_alpha = cand, float(a)
                secs["rollouts"] += time.perf_counter() - c0
                if best is not None:
                    mu = _updated_mu(mu, nominal.total - best.total, best_alpha, dV1, dV2, cfg)
                    nominal = best
                    improved = True
                    break
                mu = max(mu * cfg.mu_up, 1e-4)
            if not improved:
                log.debug("iLQR: no descent at iteration %d (mu=%.3g)", it, mu)
                break
            prev = history[-1]
            history.append(nominal.total)
            if (prev - nominal.total) <= cfg.rel_tol * abs(prev):
                break
        return ILQRResult(traj=nominal, cost_history=history, iterations=it, mu=mu, seconds=secs)


def _updated_mu(mu: float, actual: float, alpha: float, dV1: float, dV2: float, cfg: ILQRConfig) -> float:
    """The regularisation after an accepted step, from how well the quadratic model predicted
    it (MuJoCo MPC's iLQG): the ratio of the actual to the expected decrease
    ``-(alpha dV1 + alpha² dV2)``; a good prediction (ratio > 0.5) lowers μ, a poor one
    (< 0.1) raises it, in between it stays. ``cfg.regularisation == "success"``: lowered
    after every accepted step."""
    if cfg.regularisation == "success":
        return max(mu * cfg.mu_down, cfg.mu_min)
    expected = -(alpha * dV1 + alpha * alpha * dV2)
    ratio = actual / expected if expected > 0 else 0.0
    if ratio > 0.5:
        return max(mu * cfg.mu_down, cfg.mu_min)
    if ratio < 0.1:
        return min(mu * cfg.mu_up, cfg.mu_max)
    return mu


def _candidates(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    cost: Cost,
    qpos0: np.ndarray,
    qvel0: np.ndarray,
    nominal: Trajectory,
    K: np.ndarray,
    k: np.ndarray,
    alphas: np.ndarray,
    act: np.ndarray,
    t0: int,
    warm0: np.ndarray | None,
    substeps: int,
    workers: Workers | None,
    bound: Bound | None = None,
) -> list[Trajectory]:
    """Closed-loop rollouts of every line-search step size, in ``alphas`` order.

    ``bound``: a rollout whose running cost exceeds it (lowered by every finished
    candidate's total) is stopped (``Trajectory.cut``, total inf). Such a candidate's total
    is above the nominal's or another candidate's, so the lowest total, and which step
    has it, are the same as without the bound."""

    def one(a: float, d: mujoco.MjData | None = None) -> Trajectory:
        dd = d if d is not None else workers.data()  # type: ignore[union-attr]
        tr = rollout(model, dd, cost, qpos0, qvel0, nominal.ctrl, t0, nominal, K, k, a, act, warm0, substeps, bound)
        if bound is not None:
            bound.lower(tr.total)
        return tr

    if workers is None or workers.pool is None:
        return [one(float(a), data) for a in alphas]
    return list(workers.pool.map(one, [float(a) for a in alphas]))
