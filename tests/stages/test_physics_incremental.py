"""Incremental physics re-runs: after a late edit, only the windows that read a changed
frame are re-planned, from the stored state; the rest is the previous result.

Two persons facing each other (``test_physics._facing_pair``), 60 frames, short windows.
The edit lifts one athlete's wrists by 2 cm from frame 50 on: it changes neither the feet
nor the bones' lengths, so the reference changes only from frame 50 on.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("mujoco")

from pipeline.backends.mujoco.physics import window_starts  # noqa: E402
from pipeline.stages.physics import PhysicsInputs, PhysicsOutput, run  # noqa: E402
from pipeline.stages.physics_incremental import PhysicsPrevious  # noqa: E402
from tests.stages.test_physics import FAST, _facing_pair  # noqa: E402

N_FRAMES = 60
EDIT_FRAME = 50
ARRAYS = ("qpos", "qvel", "ctrl", "joint_torque_nm", "residual_root_force")


def _edited(kp):  # type: ignore[no-untyped-def]
    xyz = kp.xyz_m.copy()
    wrists = [kp.joint_names.index("left_wrist"), kp.joint_names.index("right_wrist")]
    xyz[EDIT_FRAME:, 1, wrists, 2] += 0.02
    return kp.replace(xyz_m=xyz)


def _previous(out: PhysicsOutput) -> PhysicsPrevious:
    assert out.checkpoints is not None
    return PhysicsPrevious(out.result, out.mjcf, out.checkpoints)


@pytest.fixture(scope="module")
def runs() -> dict[str, PhysicsOutput]:
    kp = _facing_pair(0.3, N_FRAMES)
    first = run(PhysicsInputs(kp), FAST)
    prev = _previous(first)
    # The reference run: the edited input planned from frame 0 on the same humanoids (a
    # previous run whose reference matches no frame keeps its bodies and re-plans all).
    assert first.checkpoints is not None
    nothing = dataclasses.replace(
        first.checkpoints, reference_digest=np.zeros_like(first.checkpoints.reference_digest)
    )
    return {
        "first": first,
        "again": run(PhysicsInputs(kp), FAST),
        "unchanged": run(PhysicsInputs(kp, previous=prev), FAST),
        "incremental": run(PhysicsInputs(_edited(kp), previous=prev), FAST),
        "full": run(
            PhysicsInputs(_edited(kp), previous=PhysicsPrevious(first.result, first.mjcf, nothing)), FAST
        ),
    }


def test_the_physics_is_deterministic(runs: dict[str, PhysicsOutput]) -> None:
    for name in ARRAYS:
        assert np.array_equal(getattr(runs["first"].result, name), getattr(runs["again"].result, name)), name


def test_an_unchanged_input_reuses_every_window(runs: dict[str, PhysicsOutput]) -> None:
    out = runs["unchanged"]
    assert out.stats["reused_frames"] == N_FRAMES and out.stats["replanned_from_frame"] == -1
    assert out.stats["first_changed_input_frame"] == N_FRAMES
    assert out.stats["windows"] == runs["first"].stats["windows"]
    assert out.stats["iterations"] == runs["first"].stats["iterations"]
    for name in ARRAYS:
        assert np.array_equal(getattr(out.result, name), getattr(runs["first"].result, name)), name


def test_only_windows_reading_a_changed_frame_are_replanned(runs: dict[str, PhysicsOutput]) -> None:
    out, first = runs["incremental"], runs["first"]
    st = out.stats
    assert st["first_changed_input_frame"] == EDIT_FRAME
    assert st["first_changed_reference_frame"] == EDIT_FRAME
    s = st["replanned_from_frame"]
    assert 0 < s == st["reused_frames"] < EDIT_FRAME
    # The first re-planned window reads a frame within the schedule's reach of the change
    # and the window before it does not.
    assert st["replan_reach_frames"] > 0  # the servo schedule's spline (``SPLINE_REACH_FRAMES``)
    changed = EDIT_FRAME - st["replan_reach_frames"]
    starts = window_starts(N_FRAMES, FAST.solver.window, FAST.solver.commit)
    k = starts.index(s)
    assert s + FAST.solver.window >= changed > starts[k - 1] + FAST.solver.window
    # Frames before the re-planned window are the previous result, bit for bit; the edit
    # shows after it.
    for name in ("qpos", "qvel"):
        a, b = getattr(out.result, name), getattr(first.result, name)
        assert np.array_equal(a[: s + 1], b[: s + 1]), name
    assert not np.array_equal(out.result.qpos[EDIT_FRAME:], first.result.qpos[EDIT_FRAME:])
    assert np.array_equal(out.result.ctrl[:s], first.result.ctrl[:s])


def test_the_incremental_result_matches_a_full_run(runs: dict[str, PhysicsOutput]) -> None:
    """Against the edited input planned from frame 0 on the same humanoids. The reused
    frames differ only by what the servo schedule's spline carries back from the edit
    (< 4e-12 of it, ``SPLINE_REACH_FRAMES``) grown by the optimiser: measured 1.4e-9 m in
    qpos (2e-5 N·m in torque) before the re-planned window and 5e-9 m after it."""
    out, full = runs["incremental"], runs["full"]
    assert full.stats["reused_frames"] == 0
    s = out.stats["replanned_from_frame"]
    for name, tol in (("qpos", 1e-6), ("qvel", 1e-5), ("joint_torque_nm", 1e-2)):
        d = np.abs(getattr(out.result, name) - getattr(full.result, name))
        assert d[:s].max() < tol, (name, d[:s].max())
        assert d[s:].max() < tol, (name, d[s:].max())
    # What the stage reports for the whole bout is the same as a full run's.
    for key in ("windows", "windows_with_residual", "resets", "kinematic_frames"):
        assert out.stats[key] == full.stats[key], key


def test_off_or_another_layout_runs_in_full(runs: dict[str, PhysicsOutput]) -> None:
    kp = _edited(_facing_pair(0.3, N_FRAMES))
    prev = _previous(runs["first"])
    off = run(PhysicsInputs(kp, previous=prev), dataclasses.replace(FAST, incremental=False, max_frames=20))
    assert off.stats["incremental"] == "full run: incremental is off" and off.stats["reused_frames"] == 0
    short = run(PhysicsInputs(kp, previous=prev), dataclasses.replace(FAST, max_frames=20))
    assert (
        short.stats["incremental"].startswith("full run: frames changed")
        and short.stats["reused_frames"] == 0
    )
    # A full run's result does not depend on the previous run it was offered.
    for name in ARRAYS:
        assert np.array_equal(getattr(off.result, name), getattr(short.result, name)), name
