"""The iLQR's parallel parts against their serial versions: the knots' finite differences on
worker threads, the line-search candidates rolled out together, whole optimisations run
twice, and the physics cost's cached per-substep residual torque against its formula."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from pipeline.backends.mujoco.ilqr import (  # noqa: E402
    ILQRConfig,
    ILQRResult,
    Linearisation,
    Workers,
    _candidates,
    backward_pass,
    linearise,
    optimise,
    rollout,
)
from tests.backends.test_ilqr import ARM_XML, TipCost  # noqa: E402

# An arm that hits the floor: contacts make the derivatives depend on the state.
ARM_FLOOR_XML = (
    ARM_XML.replace('timestep="0.02"', 'timestep="0.01"')
    .replace("<worldbody>", '<worldbody>\n    <geom type="plane" size="2 2 0.1"/>')
    .replace('pos="0 0 1"', 'pos="0 0 0.5"')
)
SUBSTEPS = 2


class PushedTipCost(TipCost):
    """``TipCost`` with a state-dependent external force applied in ``prepare`` (like the
    physics cost's residual torque): each thread must apply it to its own data."""

    thread_safe = True

    def prepare(self, model: mujoco.MjModel, data: mujoco.MjData, t: int, sub: int = 0) -> None:
        data.xfrc_applied[2, :3] = [-3.0 * data.qvel[1], 0.0, 2.0 + 0.1 * t + 0.05 * sub]


def _problem(H: int = 20) -> tuple[mujoco.MjModel, PushedTipCost, np.ndarray]:
    model = mujoco.MjModel.from_xml_string(ARM_FLOOR_XML)
    rng = np.random.default_rng(3)
    ctrl = np.column_stack([rng.normal(-4.0, 3.0, H), rng.normal(2.0, 2.0, H)])
    return model, PushedTipCost(np.array([0.5, 0.0, 0.1])), ctrl


def test_threaded_finite_differences_equal_the_serial_ones() -> None:
    model, cost, ctrl = _problem()
    traj = rollout(model, mujoco.MjData(model), cost, np.array([0.3, -0.8]), np.zeros(2), ctrl, substeps=SUBSTEPS)
    assert traj.stable
    cfg = ILQRConfig(deriv_every=3)
    act = np.arange(model.nu)
    serial = linearise(model, mujoco.MjData(model), cost, traj, cfg, act, t0=4, substeps=SUBSTEPS)
    with Workers(model, 2) as w:
        threaded = linearise(model, mujoco.MjData(model), cost, traj, cfg, act, t0=4, substeps=SUBSTEPS, workers=w)
    # The floor contact changes the Jacobians along the trajectory: not a trivial case.
    assert np.abs(serial.A[0] - serial.A[-1]).max() > 1e-3
    for name in ("A", "B", "lx", "lu", "lxx", "luu"):
        np.testing.assert_allclose(getattr(threaded, name), getattr(serial, name), rtol=0.0, atol=0.0, err_msg=name)


def _line_search_inputs(mu: float) -> tuple:
    """(model, data, cost, q0, v0, nominal, K, k, alphas, act) of a line search on the pushed
    arm: a nominal rollout, its backward pass at regularisation ``mu`` and 6 step sizes."""
    model, cost, ctrl = _problem()
    q0, v0 = np.array([0.3, -0.8]), np.zeros(2)
    data = mujoco.MjData(model)
    nominal = rollout(model, data, cost, q0, v0, ctrl, substeps=SUBSTEPS)
    act = np.arange(model.nu)
    lin = linearise(model, data, cost, nominal, ILQRConfig(deriv_every=1), act, substeps=SUBSTEPS)
    bp = backward_pass(lin, mu)
    assert bp is not None
    K, k, _, _ = bp
    return model, data, cost, q0, v0, nominal, K, k, np.logspace(0.0, -2.0, 6), act


def test_batched_line_search_picks_the_same_step_as_the_sequential_one() -> None:
    model, data, cost, q0, v0, nominal, K, k, alphas, act = _line_search_inputs(1e-3)
    # Sequential reference: one closed-loop rollout per step size on the caller's data.
    seq = [rollout(model, data, cost, q0, v0, nominal.ctrl, 0, nominal, K, k, float(a), act, None, SUBSTEPS).total for a in alphas]
    with Workers(model, 2) as w:
        batch = _candidates(model, data, cost, q0, v0, nominal, K, k, alphas, act, 0, None, SUBSTEPS, w)
    totals = [c.total for c in batch]
    assert totals == seq
    assert int(np.argmin(totals)) == int(np.argmin(seq))
    # The step sizes lead to different costs, so picking the same one means something.
    assert len(set(totals)) == len(totals)
    assert min(totals) < nominal.total


def test_optimisation_is_deterministic_and_independent_of_threads() -> None:
    model, cost, ctrl = _problem()
    cfg = ILQRConfig(max_iter=5, rel_tol=0.0, deriv_every=4)
    q0, v0 = np.array([0.3, -0.8]), np.zeros(2)

    def run(threads: int) -> ILQRResult:
        return optimise(model, mujoco.MjData(model), cost, q0, v0, ctrl, cfg, substeps=SUBSTEPS, threads=threads)

    a, b, serial = run(2), run(2), run(1)
    assert a.cost_history[-1] < a.cost_history[0]
    for other in (b, serial):
        assert other.cost_history == a.cost_history
        np.testing.assert_array_equal(other.traj.qpos, a.traj.qpos)
        np.testing.assert_array_equal(other.traj.ctrl, a.traj.ctrl)


def test_threads_by_default_only_for_a_cost_marked_thread_safe(monkeypatch: pytest.MonkeyPatch) -> None:
    import pipeline.backends.mujoco.ilqr as ilqr

    made: list[int] = []
    real = ilqr.Workers

    def recording(model: mujoco.MjModel, threads: int) -> ilqr.Workers:
        made.append(threads)
        return real(model, threads)

    monkeypatch.setattr(ilqr, "Workers", recording)
    monkeypatch.setattr(ilqr, "default_threads", lambda: 2)
    model, cost, ctrl = _problem(6)
    cfg = ILQRConfig(max_iter=1)
    optimise(model, mujoco.MjData(model), cost, np.array([0.3, -0.8]), np.zeros(2), ctrl, cfg, substeps=SUBSTEPS)
    optimise(model, mujoco.MjData(model), TipCost(np.zeros(3)), np.zeros(2), np.zeros(2), ctrl, cfg, substeps=SUBSTEPS)
    assert made == [2, 1]


def test_workers_refuse_zero_threads() -> None:
    model, _, _ = _problem()
    with pytest.raises(ValueError, match="threads must be >= 1"):
        Workers(model, 0)


def test_prepare_applies_the_residual_torque_of_its_formula() -> None:
    """``TrackingCost.prepare`` (cached reference terms) against the torque written out:
    −kp R (q ⊖ q̂) plus the schedule's feed-forward, clipped to the limit, plus kd R̂ ω̂."""
    from pipeline.backends.mujoco.config import CostWeights, HumanoidConfig
    from pipeline.backends.mujoco.reference import build_reference, build_scene
    from pipeline.backends.mujoco.skeleton import skeleton_from_keypoints
    from pipeline.backends.mujoco.tracking import TrackingCost
    from tests.backends.test_humanoid import _rest_keypoints

    kp = _rest_keypoints(1.0, 12)
    scene = build_scene([skeleton_from_keypoints(kp, 0)], [0], kp.fps, kp.joint_names, HumanoidConfig())
    ref, _, _ = build_reference(scene, kp, [0], separate=False, substeps=scene.substeps)
    assert ref.schedule is not None
    cost = TrackingCost(scene.model, scene.layout, ref, CostWeights())
    p = scene.layout.persons[0]
    limit = np.array([p.mass_kg * 9.81 * 0.3])
    cost.set_residual(True, limit, 0.03)
    kp_rot = limit[0] / 0.03
    kd = 2.0 * np.sqrt(kp_rot * p.mass_kg * 0.15**2)
    data = mujoco.MjData(scene.model)
    rng = np.random.default_rng(0)
    sch = ref.schedule
    clipped = 0
    for t, sub in [(0, 0), (3, 1), (3, 1), (7, 5), (11, 7), (20, 2)]:
        data.qpos[:] = ref.qpos[min(t, 11)]
        quat = data.qpos[p.qpos_adr + 3 : p.qpos_adr + 7] + rng.normal(0.0, 0.05 if t != 7 else 0.5, 4)
        data.qpos[p.qpos_adr + 3 : p.qpos_adr + 7] = quat / np.linalg.norm(quat)
        data.qvel[:] = rng.normal(0.0, 0.5, scene.model.nv)
        data.ctrl[:] = 0.0
        cost.prepare(scene.model, data, t, sub)
        tr, s = min(t, 11), min(sub, sch.substeps - 1)
        q, q_ref = data.qpos[p.qpos_adr + 3 : p.qpos_adr + 7], sch.qpos[tr, s, p.qpos_adr + 3 : p.qpos_adr + 7]
        err, R, R_ref = np.zeros(3), np.zeros(9), np.zeros(9)
        mujoco.mju_subQuat(err, q, q_ref)
        mujoco.mju_quat2Mat(R, q)
        mujoco.mju_quat2Mat(R_ref, q_ref)
        tau = -kp_rot * (R.reshape(3, 3) @ err) + sch.root_torque[tr, s, 0]
        n = np.linalg.norm(tau)
        clipped += int(n > limit[0])
        tau = (tau if n <= limit[0] else tau * limit[0] / n) + kd * (R_ref.reshape(3, 3) @ sch.qvel[tr, s, p.qvel_adr + 3 : p.qvel_adr + 6])
        np.testing.assert_allclose(data.xfrc_applied[p.root_body, 3:6], tau, rtol=1e-12, atol=1e-9)
        # The servo targets moved along the schedule from the frame's first substep.
        shift = sch.ctrl[tr, s] - sch.ctrl[tr, 0]
        np.testing.assert_allclose(data.ctrl[cost._acts], shift[cost._acts], rtol=0.0, atol=1e-12)
    assert clipped >= 1  # the large tilt at frame 7 saturates the torque
    cost.set_residual(False)


def test_plain_rollout_seconds_steps_the_scene_and_checks_shapes(monkeypatch: pytest.MonkeyPatch) -> None:
    from pipeline.backends.mujoco import timing

    steps: list[float] = []
    real_step = mujoco.mj_step

    def counting_step(m: mujoco.MjModel, d: mujoco.MjData) -> None:
        steps.append(float(d.ctrl[0]))
        real_step(m, d)

    monkeypatch.setattr(timing.mujoco, "mj_step", counting_step)
    ctrl = np.array([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    # timestep 0.01 s at 50 fps: two MuJoCo steps per frame, each frame's control held.
    assert timing.plain_rollout_seconds(ARM_FLOOR_XML, np.zeros(2), ctrl, 50.0) > 0.0
    assert steps == [1.0, 1.0, 2.0, 2.0, 3.0, 3.0]
    with pytest.raises(ValueError, match="do not match the scene"):
        timing.plain_rollout_seconds(ARM_FLOOR_XML, np.zeros(3), ctrl, 50.0)
    with pytest.raises(ValueError, match="fps must be > 0"):
        timing.plain_rollout_seconds(ARM_FLOOR_XML, np.zeros(2), ctrl, 0.0)


def _reference_backward_pass(lin: Linearisation, mu: float) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """The Riccati recursion written out term by term (general LU solves)."""
    H, nx, na = lin.B.shape
    Vx, Vxx = lin.lx[H].copy(), lin.lxx[H].copy()
    K, k, dV1, dV2 = np.zeros((H, na, nx)), np.zeros((H, na)), 0.0, 0.0
    for t in range(H - 1, -1, -1):
        A, B = lin.A[t], lin.B[t]
        Qx, Qu = lin.lx[t] + A.T @ Vx, lin.lu[t] + B.T @ Vx
        Qxx, Quu, Qux = lin.lxx[t] + A.T @ Vxx @ A, lin.luu[t] + B.T @ Vxx @ B, B.T @ Vxx @ A
        reg = 0.5 * (Quu + Quu.T) + mu * np.eye(na)
        if np.linalg.eigvalsh(reg).min() <= 0:
            return None
        k[t], K[t] = -np.linalg.solve(reg, Qu), -np.linalg.solve(reg, Qux)
        dV1 += float(k[t] @ Qu)
        dV2 += 0.5 * float(k[t] @ Quu @ k[t])
        Vx = Qx + K[t].T @ Quu @ k[t] + K[t].T @ Qu + Qux.T @ k[t]
        Vxx = Qxx + K[t].T @ Quu @ K[t] + K[t].T @ Qux + Qux.T @ K[t]
        Vxx = 0.5 * (Vxx + Vxx.T)
    return K, k, dV1, dV2


def test_backward_pass_matches_the_riccati_recursion_written_out() -> None:
    rng = np.random.default_rng(1)
    H, nx, na = 6, 8, 3

    def spd(n: int, scale: float) -> np.ndarray:
        M = rng.normal(size=(n, n))
        return scale * (M @ M.T) / n

    lin = Linearisation(
        A=np.eye(nx)[None] + 0.1 * rng.normal(size=(H, nx, nx)), B=0.3 * rng.normal(size=(H, nx, na)),
        lx=rng.normal(size=(H + 1, nx)), lu=rng.normal(size=(H, na)),
        lxx=np.stack([spd(nx, 1.0) for _ in range(H + 1)]), luu=np.stack([spd(na, 0.1) for _ in range(H)]),
    )
    got, want = backward_pass(lin, 1e-3), _reference_backward_pass(lin, 1e-3)
    assert got is not None and want is not None
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=1e-9, atol=1e-12)
    # A Q_uu that regularisation cannot make positive definite: no step.
    bad = Linearisation(A=lin.A, B=lin.B, lx=lin.lx, lu=lin.lu, lxx=lin.lxx, luu=lin.luu - 50.0 * np.eye(na))
    assert backward_pass(bad, 1e-3) is None and _reference_backward_pass(bad, 1e-3) is None
