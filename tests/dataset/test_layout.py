"""The release's documented NPZ layouts name exactly the arrays the schema classes write, and a
physics result passes the release validator (also one written before ``observed``/``untrackable``)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from pipeline.dataset.layout import NPZ_LAYOUTS
from pipeline.dataset.session import release_physics, write_npz
from pipeline.dataset.validate import _Checker as Checker
from pipeline.schema.base import to_arrays
from pipeline.schema.joints import COCO17_FEET
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit, PhysicsResult

F, P = 5, 2


def _physics() -> PhysicsResult:
    return PhysicsResult(
        person_ids=np.arange(P), frame_indices=np.arange(F), fps=50.0, qpos=np.zeros((F, 3)), qvel=np.zeros((F, 2)),
        ctrl=np.zeros((F, 4)), joint_torque_nm=np.zeros((F, 4)), residual_root_force=np.zeros((F, P, 6)),
        actuation="pd", contact_frame=np.array([1]), contact_person=np.array([[0, 1]]), contact_body=np.array([[1, 2]]),
        contact_depth_m=np.array([0.01]), body_names=("world", "p0_left_hand", "p1_head"),
        untrackable=np.zeros((F, P), bool), observed=np.ones((F, P), bool),
    )  # fmt: skip


def _keypoints() -> Keypoints3D:
    j = len(COCO17_FEET)
    return Keypoints3D(
        joint_names=COCO17_FEET, person_ids=np.arange(P), frame_indices=np.arange(F), fps=50.0,
        xyz_m=np.zeros((F, P, j, 3)), valid=np.ones((F, P, j), bool), confidence=np.ones((F, P, j)),
        n_views=np.full((F, P, j), 2), reproj_err_px=np.zeros((F, P, j)), source="fit",
    )  # fmt: skip


def _bodyfit() -> BodyFit:
    return BodyFit(
        body_model="anny", rig="default", bone_names=("root", "spine"), person_ids=np.arange(P),
        frame_indices=np.arange(F), fps=50.0, shape=np.zeros((P, 3)), pose=np.zeros((F, P, 2, 3)),
        root_translation_m=np.zeros((F, P, 3)), valid=np.ones((F, P), bool), loss_final=np.zeros(P),
    )  # fmt: skip


def test_layouts_name_every_array_the_schema_writes() -> None:
    for kind, obj in (("physics", _physics()), ("keypoints3d", _keypoints()), ("bodyfit", _bodyfit())):
        assert set(to_arrays(obj)) == {a.name for a in NPZ_LAYOUTS[kind]}, kind


def test_a_physics_result_validates_also_one_from_before_the_masks(tmp_path: Path) -> None:
    old = replace(_physics(), untrackable=np.zeros((0, 0), bool), observed=np.zeros((0, 0), bool))
    for name, res in (("new", _physics()), ("old", old)):
        rel = f"{name}/result.npz"
        write_npz(tmp_path / rel, to_arrays(release_physics(res)))
        checker = Checker(tmp_path)
        assert checker.npz(rel, "physics") is not None, checker.problems
        assert checker.problems == []
    arrays = dict(np.load(tmp_path / "old/result.npz"))
    assert arrays["observed"].shape == (F, P) and arrays["observed"].all() and not arrays["untrackable"].any()
