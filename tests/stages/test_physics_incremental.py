"""Incremental physics re-runs: after a late edit, only the windows that read a changed
frame are re-planned, from the stored state; the rest is the previous result.

Two persons facing each other (``test_physics._facing_pair``), 60 frames, short windows.
The edit lifts one athlete's wrists by 2 cm from frame 50 on: it changes neither the feet
nor the bones' lengths, so the reference changes beyond the tolerances
(``PhysicsConfig.incremental_tol_m``/``_rad``) only from a few frames before 50 on (the
servo schedule's spline carries a fading part of it back). A second edit moves the wrists by
0.1 mm from frame 30 on: a change, but within the tolerances.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mujoco")

from pipeline.backends.mujoco.physics import window_starts  # noqa: E402
from pipeline.schema.base import load_npz, to_arrays  # noqa: E402
from pipeline.stages.physics import PhysicsInputs, PhysicsOutput, run  # noqa: E402
from pipeline.stages.physics_incremental import PhysicsCheckpoints, PhysicsPrevious, reference_reach  # noqa: E402
from tests.stages.test_physics import FAST, _facing_pair  # noqa: E402

N_FRAMES = 60
EDIT_FRAME = 50
ARRAYS = ("qpos", "qvel", "ctrl", "joint_torque_nm", "residual_root_force")


SMALL_FRAME, SMALL_M = 30, 0.0001


def _edited(kp, frame: int = EDIT_FRAME, lift_m: float = 0.02):  # type: ignore[no-untyped-def]
    xyz = kp.xyz_m.copy()
    wrists = [kp.joint_names.index("left_wrist"), kp.joint_names.index("right_wrist")]
    xyz[frame:, 1, wrists, 2] += lift_m
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
    assert first.checkpoints.reference_values is not None
    nothing = dataclasses.replace(
        first.checkpoints,
        reference_digest=np.zeros_like(first.checkpoints.reference_digest),
        reference_values=first.checkpoints.reference_values + np.float32(1.0),
    )
    return {
        "first": first,
        "again": run(PhysicsInputs(kp), FAST),
        "unchanged": run(PhysicsInputs(kp, previous=prev), FAST),
        "incremental": run(PhysicsInputs(_edited(kp), previous=prev), FAST),
        "small": run(PhysicsInputs(_edited(kp, SMALL_FRAME, SMALL_M), previous=prev), FAST),
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
    assert out.stats["ik_reused_frames"] == N_FRAMES
    assert out.stats["ik_incremental"] == f"reused every frame (0-{N_FRAMES - 1})"
    assert out.stats["windows"] == runs["first"].stats["windows"]
    assert out.stats["iterations"] == runs["first"].stats["iterations"]
    for name in ARRAYS:
        assert np.array_equal(getattr(out.result, name), getattr(runs["first"].result, name)), name


def test_only_windows_reading_a_changed_frame_are_replanned(runs: dict[str, PhysicsOutput]) -> None:
    out, first = runs["incremental"], runs["first"]
    st = out.stats
    assert st["first_changed_input_frame"] == EDIT_FRAME
    # The inverse kinematics is solved from the edit on (the wrists are not feet: the planted
    # feet's targets, which reach back, do not change); the frames before are the stored IK.
    assert st["ik_reused_frames"] == EDIT_FRAME
    assert st["ik_incremental"] == f"reused frames 0-{EDIT_FRAME - 1}, solved from frame {EDIT_FRAME}"
    ik_new, ik_old = out.checkpoints, first.checkpoints
    assert ik_new is not None and ik_old is not None
    assert ik_new.ik_qpos is not None and ik_old.ik_qpos is not None
    assert np.array_equal(ik_new.ik_qpos[:EDIT_FRAME], ik_old.ik_qpos[:EDIT_FRAME])
    assert not np.array_equal(ik_new.ik_qpos[EDIT_FRAME:], ik_old.ik_qpos[EDIT_FRAME:])
    # The schedule's spline carries the change a few frames back beyond the tolerances:
    # fewer than the allowance a bit-for-bit comparison would need (``reference_reach``).
    assert st["first_changed_reference_frame_exact"] == EDIT_FRAME  # before the schedule
    changed = st["first_changed_reference_frame"]
    reach = reference_reach(True, FAST.reference.feedforward_smooth_frames)
    assert EDIT_FRAME - reach < EDIT_FRAME - 10 <= changed < EDIT_FRAME
    s = st["replanned_from_frame"]
    assert 0 < s == st["reused_frames"] < EDIT_FRAME
    # The first re-planned window reads the first changed frame and the window before it does not.
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
    frames are the previous run's, whose reference differs from the edited one there by less
    than the tolerances (the servo schedule's spline carries a fading part of the edit back);
    the full run tracks that slightly other reference and the optimiser carries the
    difference on. Measured: 1.8e-7 in qpos (m or rad), 6.5e-6 in qvel, 2.3e-3 N·m in
    torque before the re-planned window; 5.1e-6, 3.1e-4 and 0.064 N·m after it."""
    out, full = runs["incremental"], runs["full"]
    assert full.stats["reused_frames"] == 0
    s = out.stats["replanned_from_frame"]
    ck_new, ck_old = out.checkpoints, runs["first"].checkpoints
    assert ck_new is not None and ck_old is not None
    assert ck_new.reference_values is not None and ck_old.reference_values is not None
    assert ck_new.reference_tol is not None
    moved = np.abs(ck_new.reference_values[:s] - ck_old.reference_values[:s])
    assert moved.max() > 0 and (moved <= ck_new.reference_tol).all()  # a change, within the tolerances
    for name, tol in (("qpos", 2e-5), ("qvel", 1e-3), ("joint_torque_nm", 0.2)):
        d = np.abs(getattr(out.result, name) - getattr(full.result, name))
        assert d[:s].max() < tol / 10, (name, d[:s].max())
        assert d[s:].max() < tol, (name, d[s:].max())
    # What the stage reports for the whole bout is the same as a full run's.
    for key in ("windows", "windows_with_residual", "resets", "kinematic_frames"):
        assert out.stats[key] == full.stats[key], key


def test_a_change_within_the_tolerances_reuses_every_window(runs: dict[str, PhysicsOutput]) -> None:
    out, first = runs["small"], runs["first"]
    st = out.stats
    assert st["first_changed_input_frame"] == SMALL_FRAME
    assert st["first_changed_reference_frame_exact"] == SMALL_FRAME  # a change, bit for bit
    assert st["first_changed_reference_frame"] == N_FRAMES and st["reused_frames"] == N_FRAMES
    for name in ARRAYS:
        assert np.array_equal(getattr(out.result, name), getattr(first.result, name)), name


def test_old_checkpoints_without_reference_values_replan_and_say_why(
    runs: dict[str, PhysicsOutput], tmp_path: Path
) -> None:
    """Checkpoints written before the reference values and the inverse kinematics were
    stored (as loaded from such a file): everything is planned and solved again."""
    first = runs["first"]
    assert first.checkpoints is not None
    dropped = dataclasses.replace(
        first.checkpoints, reference_values=None, reference_tol=None, ik_qpos=None, ik_input_digest=None,
        ik_model_digest="",
    )  # fmt: skip
    path = tmp_path / "checkpoints.npz"
    later = ("reference_values", "reference_tol", "ik_qpos", "ik_input_digest", "ik_model_digest")
    arrays = {k: v for k, v in to_arrays(dropped).items() if not k.endswith(later)}
    assert len(arrays) == len(to_arrays(dropped)) - len(later)
    np.savez(path, **arrays)  # type: ignore[arg-type]
    old = load_npz(path, PhysicsCheckpoints)
    assert old.stored_ik() is None and old.reference_values is None
    out = run(
        PhysicsInputs(_facing_pair(0.3, N_FRAMES), previous=PhysicsPrevious(first.result, first.mjcf, old)),
        dataclasses.replace(FAST, max_frames=0),
    )
    assert (
        out.stats["incremental"]
        == "full run: the previous run stored no reference values (older checkpoints)"
    )
    assert out.stats["reused_frames"] == 0
    assert out.stats["ik_incremental"] == (
        "solved every frame: the previous run stored no inverse kinematics (older checkpoints)"
    )
    assert out.stats["ik_reused_frames"] == 0
    for name in ARRAYS:  # planned from frame 0 on the same humanoids: the same as the first run
        assert np.array_equal(getattr(out.result, name), getattr(first.result, name)), name


def test_off_or_another_layout_runs_in_full(runs: dict[str, PhysicsOutput]) -> None:
    kp = _edited(_facing_pair(0.3, N_FRAMES))
    prev = _previous(runs["first"])
    off = run(PhysicsInputs(kp, previous=prev), dataclasses.replace(FAST, incremental=False, max_frames=20))
    assert off.stats["incremental"] == "full run: incremental is off" and off.stats["reused_frames"] == 0
    assert (
        off.stats["ik_incremental"] == "solved every frame (full run)" and off.stats["ik_reused_frames"] == 0
    )
    short = run(PhysicsInputs(kp, previous=prev), dataclasses.replace(FAST, max_frames=20))
    assert (
        short.stats["incremental"].startswith("full run: frames changed")
        and short.stats["reused_frames"] == 0
    )
    # A full run's result does not depend on the previous run it was offered.
    for name in ARRAYS:
        assert np.array_equal(getattr(off.result, name), getattr(short.result, name)), name
