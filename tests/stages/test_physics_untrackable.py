"""Windows the physics cannot track without a residual root force are flagged, counted and
logged (residual modes ``off`` and ``fallback``), never silently hidden by the residual;
and the opt-in residual's cap is settable as the benches and session.json set it."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest

pytest.importorskip("mujoco")

import pipeline.backends.mujoco.physics as mp  # noqa: E402
from pipeline.schema.base import from_arrays, to_arrays  # noqa: E402
from pipeline.schema.keypoints3d import Keypoints3D  # noqa: E402
from pipeline.schema.results import PhysicsResult  # noqa: E402
from pipeline.stages.physics import PhysicsConfig, PhysicsInputs, PhysicsOutput, run  # noqa: E402
from tests.backends.test_humanoid import _rest_keypoints  # noqa: E402

N_FRAMES, JUMP_AT, JUMP_M = 12, 7, 1.0
SOLVER = {"window": 5, "commit": 3, "ilqr": {"max_iter": 2, "n_alpha": 3}}
STARTS = mp.window_starts(N_FRAMES, SOLVER["window"], SOLVER["commit"])  # type: ignore[arg-type]


def _cfg(mode: str) -> PhysicsConfig:
    return PhysicsConfig(skeleton="keypoints", solver=SOLVER, residual={"mode": mode})


def _standing() -> Keypoints3D:
    return _rest_keypoints(1.0, N_FRAMES)


def _teleporting() -> Keypoints3D:
    """The standing person's keypoints jump ``JUMP_M`` along x at frame ``JUMP_AT``: no
    body moved by joints and floor contacts alone follows that."""
    kp = _standing()
    xyz = kp.xyz_m.copy()
    xyz[JUMP_AT:, ..., 0] += JUMP_M
    return kp.replace(xyz_m=xyz)


def _expected_frames(flagged_starts: set[int]) -> np.ndarray:
    """(frames,) bool: the frames owned by the windows starting at ``flagged_starts``."""
    out = np.zeros(N_FRAMES, bool)
    for w, s in enumerate(STARTS):
        out[s : STARTS[w + 1] if w + 1 < len(STARTS) else N_FRAMES] = s in flagged_starts
    return out


def _run(kp: Keypoints3D, mode: str, caplog: pytest.LogCaptureFixture) -> tuple[PhysicsOutput, list[str]]:
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="pipeline.stages.physics"):
        out = run(PhysicsInputs(kp), _cfg(mode))
    said = [r.getMessage() for r in caplog.records if "could not be tracked without a residual" in r.getMessage()]
    return out, said


def test_off_flags_and_counts_the_untrackable_windows_only(caplog: pytest.LogCaptureFixture) -> None:
    assert len(STARTS) == 3 and STARTS[1] < JUMP_AT <= STARTS[1] + SOLVER["window"]  # type: ignore[operator]
    still, said = _run(_standing(), "off", caplog)
    assert not still.result.untrackable.any() and still.result.untrackable.shape == (N_FRAMES, 1)
    assert still.stats["untrackable_windows"] == 0 and still.stats["untrackable_frames"] == 0 and said == []
    out, said = _run(_teleporting(), "off", caplog)
    # The windows whose horizon reaches the jump; the first one ends before it.
    reach = {s for s in STARTS if s + SOLVER["window"] >= JUMP_AT}  # type: ignore[operator]
    assert reach == set(STARTS[1:])
    flags = _expected_frames(reach)
    assert out.result.untrackable[:, 0].tolist() == flags.tolist()
    st = out.stats
    assert st["residual_mode"] == "off" and st["windows_with_residual"] == 0
    assert np.abs(out.result.residual_root_force).max() == 0.0  # flagged, not helped
    assert st["untrackable_windows"] == len(reach) and st["untrackable_frames"] == int(flags.sum())
    assert st["untrackable_windows_pct"] == pytest.approx(100.0 * len(reach) / st["windows"])
    assert st["untrackable_frames_pct"] == pytest.approx(100.0 * flags.sum() / N_FRAMES)
    # One warning for the run, with the count and the frames.
    assert len(said) == 1
    assert f"{len(reach)} of {len(STARTS)} windows (frames {STARTS[1]}-{N_FRAMES - 1})" in said[0] and "off" in said[0]
    # The flags survive the artifact's round trip.
    back = from_arrays(PhysicsResult, to_arrays(out.result))
    assert np.array_equal(back.untrackable, out.result.untrackable)


def test_fallback_flags_exactly_the_windows_it_redid(caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    real = mp._first_stable
    with_residual: list[int] = []

    def spy(m, d, cost, qpos0, qvel0, inits, cfg, active, t0, warm, substeps, blocks=None):  # type: ignore[no-untyped-def]
        if int(m.opt.disableactuator) & (1 << mp.RESIDUAL_GROUP) == 0:  # the residual servos act
            with_residual.append(t0)
        return real(m, d, cost, qpos0, qvel0, inits, cfg, active, t0, warm, substeps, blocks)

    monkeypatch.setattr(mp, "_first_stable", spy)
    out, said = _run(_teleporting(), "fallback", caplog)
    redone = set(with_residual)
    assert redone  # the jump needs it
    assert out.result.untrackable[:, 0].tolist() == _expected_frames(redone).tolist()
    assert out.stats["untrackable_windows"] == len(redone) and len(said) == 1 and "fallback" in said[0]
    with_residual.clear()
    still, said = _run(_standing(), "fallback", caplog)
    assert with_residual == [] and not still.result.untrackable.any() and said == []


def test_always_records_nothing_new(caplog: pytest.LogCaptureFixture) -> None:
    out, said = _run(_teleporting(), "always", caplog)
    assert out.stats["windows_with_residual"] == out.stats["windows"] > 0
    assert not out.result.untrackable.any() and out.stats["untrackable_windows"] == 0 and said == []


def test_untrackable_frames_come_from_the_window_records() -> None:
    z = np.zeros(1)
    recs = [mp.WindowRecord(s, z, z, z, np.zeros((0, 1)), untrackable=s == 3) for s in (0, 3, 6)]
    assert np.flatnonzero(mp.untrackable_frames(recs, 10)).tolist() == [3, 4, 5]
    recs[2] = mp.WindowRecord(6, z, z, z, np.zeros((0, 1)), untrackable=True)
    assert np.flatnonzero(mp.untrackable_frames(recs, 10)).tolist() == [3, 4, 5, 6, 7, 8, 9]


def test_a_result_without_flags_still_loads_and_bad_flags_are_refused() -> None:
    out = run(PhysicsInputs(_rest_keypoints(1.0, 4)), PhysicsConfig(skeleton="keypoints", solver={"window": 3, "commit": 2, "ilqr": {"max_iter": 1, "n_alpha": 2}}, residual={"mode": "off"}))
    arrays = to_arrays(out.result)
    del arrays["untrackable"]  # written before the field existed
    assert from_arrays(PhysicsResult, arrays).untrackable.shape == (0, 0)
    arrays["untrackable"] = np.zeros((3, 1), bool)
    with pytest.raises(ValueError, match=r"PhysicsResult\.untrackable: expected shape \(4, 1\)"):
        from_arrays(PhysicsResult, arrays)


def test_the_opt_in_cap_is_settable_as_benches_and_sessions_set_it() -> None:
    """``cornerman bench physics --opt 'residual={"mode": "fallback", "force_frac": 0.05}'``
    (a JSON object, passed as a keyword) and ``stage_config.physics.residual`` in
    session.json give the same config; the cap is the root servos' force range."""
    from pipeline.backends.mujoco.reference import build_scene
    from pipeline.backends.mujoco.skeleton import skeleton_from_keypoints
    from pipeline.cli.main import _parse_opt
    from pipeline.schema.config_types import build_config
    from pipeline.stages.physics import residual_actuators

    opt = _parse_opt(['residual={"mode": "fallback", "force_frac": 0.05}'])
    cfg = PhysicsConfig(**opt)
    assert (cfg.residual.mode, cfg.residual.force_frac) == ("fallback", 0.05)
    assert build_config(PhysicsConfig, {"residual": {"mode": "fallback", "force_frac": 0.05}}, "session.json") == cfg
    kp = _standing()
    scene = build_scene([skeleton_from_keypoints(kp, 0)], [0], kp.fps, kp.joint_names, cfg.humanoid, residual_actuators(cfg))
    bw = scene.layout.persons[0].mass_kg * 9.81
    lim = scene.model.actuator_forcerange[scene.layout.residual_ids]
    assert lim.shape == (3, 2) and np.allclose(lim, [[-0.05 * bw, 0.05 * bw]] * 3, rtol=1e-4)
    assert bool(scene.model.actuator_forcelimited[scene.layout.residual_ids].all())
    with pytest.raises(ValueError, match=r"ResidualConfig\.force_frac must be > 0"):
        PhysicsConfig(residual={"mode": "fallback", "force_frac": 0.0})
    with pytest.raises(ValueError, match=r"PhysicsConfig\.residual: unknown keys \['force'\]"):
        PhysicsConfig(residual={"mode": "fallback", "force": 0.05})


def test_an_incremental_rerun_keeps_the_flags_of_the_windows_it_reuses() -> None:
    """An edit of the last frame re-plans only the windows that read it: the reused windows
    keep their flags (from the previous result), and the counts are those of a full run."""
    from pipeline.stages.physics_incremental import PhysicsPrevious

    n = 40  # room for the servo schedule's reach (``physics_incremental.reference_reach``)
    cfg = PhysicsConfig(skeleton="keypoints", solver=SOLVER, residual={"mode": "off"})
    kp = _rest_keypoints(1.0, n)
    xyz = kp.xyz_m.copy()
    xyz[JUMP_AT:, ..., 0] += JUMP_M
    kp = kp.replace(xyz_m=xyz)
    first = run(PhysicsInputs(kp), cfg)
    assert first.checkpoints is not None
    xyz[n - 1, :, kp.joint_names.index("left_wrist"), 2] += 0.02
    edited = kp.replace(xyz_m=xyz)
    again = run(PhysicsInputs(edited, previous=PhysicsPrevious(first.result, first.mjcf, first.checkpoints)), cfg)
    full = run(PhysicsInputs(edited), cfg)
    kept = again.stats["reused_frames"]
    assert 0 < kept < n and first.result.untrackable[:kept].any()  # reused windows, flagged ones among them
    assert np.array_equal(again.result.untrackable, full.result.untrackable)
    for key in ("untrackable_windows", "untrackable_frames"):
        assert again.stats[key] == full.stats[key] > 0
    # A previous result that did not record the flags is not reused: its windows' flags are unknown.
    legacy = PhysicsPrevious(dataclasses.replace(first.result, untrackable=np.zeros((0, 0), bool)), first.mjcf, first.checkpoints)
    rerun = run(PhysicsInputs(edited, previous=legacy), cfg)
    assert rerun.stats["reused_frames"] == 0 and "did not record" in rerun.stats["incremental"]
