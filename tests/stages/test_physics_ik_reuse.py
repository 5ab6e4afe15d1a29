"""Reuse of a stored inverse kinematics when the physics reference is rebuilt after an edit
(``pipeline.backends.mujoco.ik_reuse``, ``reference.reference_and_ik``): the frames before
the first changed IK input are copied, the rest solved on from there, and the reference is
bit for bit the one solved from frame 0.

Two persons facing each other (``test_physics._facing_pair``), 40 frames, the stage's own
reference settings (flat feet, separation, servo schedule); the edit lifts one athlete's
wrists by 2 cm from frame 30 on. No optimiser runs here.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import numpy as np
import pytest

pytest.importorskip("mujoco")

from pipeline.backends.mujoco.ik_reuse import ReferenceIK, reusable_ik_frames  # noqa: E402
from pipeline.backends.mujoco.reference import Scene, build_scene, sole_heights_m  # noqa: E402
from pipeline.backends.mujoco.tracking import Reference  # noqa: E402
from pipeline.schema.keypoints3d import Keypoints3D  # noqa: E402
from pipeline.stages.physics import PhysicsConfig, build_skeletons, residual_actuators, stage_reference  # noqa: E402
from tests.stages.test_physics import _facing_pair  # noqa: E402
from tests.stages.test_physics_incremental import _edited  # noqa: E402

N_FRAMES, EDIT_FRAME = 40, 30
CFG = PhysicsConfig(skeleton="keypoints")
ROWS = [0, 1]


def _scene(kp: Keypoints3D, cfg: PhysicsConfig = CFG) -> Scene:
    skels, _ = build_skeletons(kp, ROWS, None, cfg)
    return build_scene(skels, [0, 1], kp.fps, kp.joint_names, cfg.humanoid, residual_actuators(cfg))


def _reference(
    scene: Scene, kp: Keypoints3D, stored: ReferenceIK | None = None, cfg: PhysicsConfig = CFG
) -> tuple[Reference, np.ndarray, np.ndarray, ReferenceIK]:
    return stage_reference(scene, kp, ROWS, cfg, sole_heights_m(kp, ROWS), stored)


def _assert_same_reference(a: Reference, b: Reference) -> None:
    """Every array of two references (and of their servo schedules) equal bit for bit."""
    assert (a.schedule is None) == (b.schedule is None)
    pairs = [(a, b)] + ([(a.schedule, b.schedule)] if a.schedule is not None else [])
    for x, y in pairs:
        for f in dataclasses.fields(x):  # type: ignore[arg-type]
            u, v = getattr(x, f.name), getattr(y, f.name)
            if isinstance(u, np.ndarray):
                assert np.array_equal(u, v), f.name
            elif not dataclasses.is_dataclass(u):  # the schedule: compared as its own pair
                assert u == v, f.name


@pytest.fixture(scope="module", autouse=True)
def _one_blas_thread() -> Iterator[None]:
    """As the stage runs (``physics.run``): the same sums in the same order, run after run."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield


@dataclasses.dataclass(frozen=True)
class Base:
    """The bout, its scene, its IK (``ik0``), the edited bout and its reference from scratch."""

    kp: Keypoints3D
    scene: Scene
    ik0: ReferenceIK
    edited: Keypoints3D
    scratch: tuple[Reference, np.ndarray, np.ndarray, ReferenceIK]


@pytest.fixture(scope="module")
def base() -> Base:
    kp = _facing_pair(0.3, N_FRAMES)
    scene = _scene(kp)
    edited = _edited(kp, EDIT_FRAME)
    _, _, _, ik0 = _reference(scene, kp)
    return Base(kp=kp, scene=scene, ik0=ik0, edited=edited, scratch=_reference(scene, edited))


def test_a_reused_ik_gives_the_reference_solved_from_scratch(base: Base) -> None:
    scene, edited, ik0 = base.scene, base.edited, base.ik0
    ref2, t2, w2, ik2 = base.scratch
    ref1, t1, w1, ik1 = _reference(scene, edited, ik0)
    assert ik0.reused_frames == 0 and ik2.reused_frames == 0
    assert ik1.reused_frames == EDIT_FRAME and ik1.why == ""
    assert np.array_equal(ik1.qpos, ik2.qpos) and np.array_equal(ik1.input_digest, ik2.input_digest)
    assert ik1.model_digest == ik2.model_digest == ik0.model_digest
    # The edit is solved anew: the frames from it on are not the stored ones.
    assert not np.array_equal(ik1.qpos[EDIT_FRAME:], ik0.qpos[EDIT_FRAME:])
    assert np.array_equal(t1, t2) and np.array_equal(w1, w2)
    _assert_same_reference(ref1, ref2)


def test_the_stored_frames_are_copied_not_solved(base: Base) -> None:
    scene, edited, ik0 = base.scene, base.edited, base.ik0
    marked = dataclasses.replace(ik0, qpos=ik0.qpos + 1e-3)  # same digests, other poses
    _, _, _, ik = _reference(scene, edited, marked)
    assert ik.reused_frames == EDIT_FRAME
    assert np.array_equal(ik.qpos[:EDIT_FRAME], marked.qpos[:EDIT_FRAME])
    # An unchanged input reuses every frame.
    _, _, _, same = _reference(scene, base.kp, marked)
    assert same.reused_frames == N_FRAMES and np.array_equal(same.qpos, marked.qpos)


def test_a_changed_humanoid_or_ik_setting_solves_every_frame(base: Base) -> None:
    kp, ik0, scene = base.kp, base.ik0, base.scene
    # Humanoids sized from 5 % longer bones: another model, the same targets.
    bigger = _scene(kp.replace(xyz_m=kp.xyz_m * 1.05))
    ref_a, _, _, ik_a = _reference(bigger, kp, ik0)
    ref_b, _, _, ik_b = _reference(bigger, kp)
    assert ik_a.reused_frames == 0 and ik_a.why == "the humanoids or the IK settings changed"
    assert np.array_equal(ik_a.qpos, ik_b.qpos) and not np.array_equal(ik_a.qpos, ik0.qpos)
    _assert_same_reference(ref_a, ref_b)
    # Another IK setting on the same humanoids.
    posture = dataclasses.replace(CFG, reference=dataclasses.replace(CFG.reference, ik_posture_weight=1e-3))
    _, _, _, ik_p = _reference(scene, kp, ik0, posture)
    assert ik_p.reused_frames == 0 and ik_p.why == "the humanoids or the IK settings changed"
    # Nothing stored (checkpoints older than the stored IK).
    _, _, _, ik_n = _reference(scene, kp, None)
    assert ik_n.reused_frames == 0 and ik_n.why == "" and np.array_equal(ik_n.qpos, ik0.qpos)


def test_reusable_frames_need_the_same_frames_and_a_target_of_every_person() -> None:
    F, P, S = 12, 2, 3
    digest = np.arange(1, F + 1, dtype=np.uint64)
    stored = ReferenceIK(qpos=np.zeros((F, 7)), input_digest=digest, model_digest="m")
    weight = np.ones((F, P, S))
    new = digest.copy()
    new[8] += np.uint64(1)
    assert reusable_ik_frames(stored, new, "m", weight) == (8, "")
    assert reusable_ik_frames(stored, digest, "m", weight) == (F, "")
    assert reusable_ik_frames(stored, new[:10], "m", weight[:10]) == (0, "the frames changed (12 -> 10)")
    changed0 = digest.copy()
    changed0[0] += np.uint64(1)
    assert reusable_ik_frames(stored, changed0, "m", weight) == (0, "the IK's inputs changed from frame 0 on")
    late = weight.copy()
    late[:9, 1] = 0.0  # person row 1 has no targets before the change at 8
    k, why = reusable_ik_frames(stored, new, "m", late)
    assert k == 0 and why == "persons (rows) [1] have no targets before frame 8, the first changed IK input"
    with pytest.raises(ValueError, match="reused_frames"):
        ReferenceIK(qpos=np.zeros((F, 7)), input_digest=digest, model_digest="m", reused_frames=F + 1)
