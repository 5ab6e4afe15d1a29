"""``SolverConfig.exact_retry_tol_m``: a window whose sites miss their targets by more than
the tolerance is planned again with every substep differentiated, the lower-cost plan is
kept, and the stats count those windows; below the tolerance nothing changes. Every plan a
window makes (this second one, the residual fallback's) enters the iteration count once."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

pytest.importorskip("mujoco")

import pipeline.backends.mujoco.physics as mp  # noqa: E402
from pipeline.backends.mujoco.config import SolverConfig  # noqa: E402
from pipeline.schema.keypoints3d import Keypoints3D  # noqa: E402
from pipeline.stages.physics import PhysicsConfig, PhysicsInputs, PhysicsOutput, run  # noqa: E402
from tests.backends.test_humanoid import _rest_keypoints  # noqa: E402

N_FRAMES, JUMP_AT, JUMP_M = 12, 7, 1.0
SOLVER = {"window": 5, "commit": 3, "ilqr": {"max_iter": 2, "n_alpha": 3}}
STARTS = mp.window_starts(N_FRAMES, SOLVER["window"], SOLVER["commit"])  # type: ignore[arg-type]


def _teleporting() -> Keypoints3D:
    """A standing person whose keypoints jump ``JUMP_M`` along x at frame ``JUMP_AT``: the
    windows that reach the jump miss their targets by decimetres, the first one does not."""
    kp = _rest_keypoints(1.0, N_FRAMES)
    xyz = kp.xyz_m.copy()
    xyz[JUMP_AT:, ..., 0] += JUMP_M
    return kp.replace(xyz_m=xyz)


def _run(tol: float, monkeypatch: pytest.MonkeyPatch) -> tuple[PhysicsOutput, list[tuple[int, float, float]]]:
    """The stage on the teleporting person (no residual), and the (window start, fd_interval_s,
    final cost) of every window plan ``_first_stable`` returned."""
    real = mp._first_stable
    calls: list[tuple[int, float, float]] = []

    def spy(m, d, cost, qpos0, qvel0, inits, cfg, active, t0, warm, substeps, blocks=None):  # type: ignore[no-untyped-def]
        res = real(m, d, cost, qpos0, qvel0, inits, cfg, active, t0, warm, substeps, blocks)
        calls.append((t0, cfg.fd_interval_s, float("nan") if res is None else float(res.traj.total)))
        return res

    monkeypatch.setattr(mp, "_first_stable", spy)
    options: dict[str, Any] = {
        "skeleton": "keypoints",
        "solver": {**SOLVER, "exact_retry_tol_m": tol},
        "residual": {"mode": "off"},
    }
    out = run(PhysicsInputs(_teleporting()), PhysicsConfig(**options))
    return out, calls


def test_windows_that_miss_are_replanned_with_exact_jacobians_and_counted(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    out, calls = _run(0.1, monkeypatch)
    default_fd = SolverConfig().ilqr.fd_interval_s
    assert default_fd > 0
    exact = [(t0, c) for t0, fd, c in calls if fd == 0.0]
    # Only the windows that reach the jump miss by more than 0.1 m, and each is re-planned once.
    reach = [s for s in STARTS if s + SOLVER["window"] >= JUMP_AT]  # type: ignore[operator]
    assert [t0 for t0, _ in exact] == reach and STARTS[0] not in reach
    assert out.stats["exact_retry_windows"] == len(reach)
    # Both plans of a re-planned window are stable ones (finite costs) to choose from.
    first = {t0: c for t0, fd, c in calls if fd == default_fd}
    assert all(np.isfinite(c) and np.isfinite(first[t0]) for t0, c in exact)


def test_above_every_error_nothing_is_replanned_and_the_result_is_unchanged(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    off, calls_off = _run(0.0, monkeypatch)
    high, calls_high = _run(100.0, monkeypatch)
    assert off.stats["exact_retry_windows"] == high.stats["exact_retry_windows"] == 0
    assert all(fd > 0 for _, fd, _ in calls_off + calls_high)
    assert np.array_equal(off.result.qpos, high.result.qpos) and np.array_equal(
        off.result.ctrl, high.result.ctrl
    )


def test_below_every_error_each_window_is_planned_both_ways(monkeypatch: pytest.MonkeyPatch) -> None:
    """With a tolerance below any error every window gets a second, exact plan, once."""
    retried, calls = _run(1e-9, monkeypatch)
    assert retried.stats["exact_retry_windows"] == len(STARTS)
    by_start: dict[int, dict[float, float]] = {}
    for t0, fd, c in calls:
        by_start.setdefault(t0, {})[fd] = c
    assert set(by_start) == set(STARTS) and all(len(v) == 2 for v in by_start.values())


def test_a_window_that_starts_far_off_is_not_replanned(monkeypatch: pytest.MonkeyPatch) -> None:
    """After the jump the simulated person starts each window centimetres to decimetres from
    its targets; with ``exact_retry_max_start_m`` below that, those windows keep their plan."""
    real = mp._mean_site_error
    at_start: list[float] = []

    def spy(scene, qpos, targets, weight):  # type: ignore[no-untyped-def]
        e = real(scene, qpos, targets, weight)
        if qpos.shape[0] == 1:  # the start-of-window check
            at_start.append(e)
        return e

    monkeypatch.setattr(mp, "_mean_site_error", spy)
    gate = 0.03
    options: dict[str, Any] = {
        "skeleton": "keypoints",
        "solver": {**SOLVER, "exact_retry_tol_m": 1e-9, "exact_retry_max_start_m": gate},
        "residual": {"mode": "off"},
    }
    out = run(PhysicsInputs(_teleporting()), PhysicsConfig(**options))
    near = sum(e <= gate for e in at_start)
    assert len(at_start) == len(STARTS) and 1 <= near < len(STARTS), at_start
    assert out.stats["exact_retry_windows"] == near


def test_a_bad_tolerance_is_refused() -> None:
    with pytest.raises(ValueError, match="exact_retry_tol_m must be >= 0"):
        SolverConfig(exact_retry_tol_m=-0.01)
    with pytest.raises(ValueError, match="exact_retry_tol_m must be >= 0"):
        SolverConfig(exact_retry_tol_m=float("nan"))
    for bad in (0.0, float("nan")):
        with pytest.raises(ValueError, match="exact_retry_max_start_m must be > 0"):
            SolverConfig(exact_retry_max_start_m=bad)


@pytest.mark.parametrize("mode, tol", [("off", 1e-9), ("fallback", 0.0), ("fallback", 1e-9)])
def test_every_plan_is_counted_once(mode: str, tol: float, monkeypatch: pytest.MonkeyPatch) -> None:
    """The stats' iterations are those of every plan made, kept or dropped, each once: the
    residual fallback's and the exact retry's second plans too."""
    real = mp._first_stable
    made: list[int] = []

    def spy(m, d, cost, qpos0, qvel0, inits, cfg, active, t0, warm, substeps, blocks=None):  # type: ignore[no-untyped-def]
        res = real(m, d, cost, qpos0, qvel0, inits, cfg, active, t0, warm, substeps, blocks)
        if res is not None:
            made.append(res.iterations)
        return res

    monkeypatch.setattr(mp, "_first_stable", spy)
    options: dict[str, Any] = {
        "skeleton": "keypoints",
        "solver": {**SOLVER, "exact_retry_tol_m": tol},
        "residual": {"mode": mode},
    }
    out = run(PhysicsInputs(_teleporting()), PhysicsConfig(**options))
    assert len(made) > len(STARTS)  # some window was planned twice
    assert out.stats["iterations"] == sum(made)


def test_a_rejected_fallback_plan_is_counted_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """Residual fallback whose plan with the residual costs more (made so here): the plan
    without it is kept, and both plans' iterations enter the stats once each."""
    import dataclasses

    real = mp._first_stable
    made: list[int] = []
    rejected: list[int] = []

    def spy(m, d, cost, qpos0, qvel0, inits, cfg, active, t0, warm, substeps, blocks=None):  # type: ignore[no-untyped-def]
        res = real(m, d, cost, qpos0, qvel0, inits, cfg, active, t0, warm, substeps, blocks)
        if res is None:
            return res
        if int(m.opt.disableactuator) & (1 << mp.RESIDUAL_GROUP) == 0:  # the residual acts: a worse plan
            rejected.append(t0)
            # Its own iteration count too, so that counting the kept plan twice cannot pass for it.
            worse = dataclasses.replace(res.traj, costs=res.traj.costs * 1e6 + 1.0)
            res = dataclasses.replace(res, traj=worse, iterations=res.iterations + 1000)
        made.append(res.iterations)
        return res

    monkeypatch.setattr(mp, "_first_stable", spy)
    options: dict[str, Any] = {"skeleton": "keypoints", "solver": SOLVER, "residual": {"mode": "fallback"}}
    out = run(PhysicsInputs(_teleporting()), PhysicsConfig(**options))
    assert rejected and out.stats["windows_with_residual"] == 0  # every residual plan was turned down
    assert out.stats["iterations"] == sum(made)
