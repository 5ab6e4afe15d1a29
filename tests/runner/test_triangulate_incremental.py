"""An identity edit late in a bout re-triangulates, but with the previous run's bone lengths
held (where they barely moved) the frames well before the edit stay exactly as they were, so
the fit and physics after it can re-run incrementally."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.artifacts import ArtifactStore
from pipeline.runner import run
from pipeline.schema.annotations import SwapIdentities, save_annotations
from pipeline.schema.bones import BoneLengths
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.stages.filtering import hold_lengths
from pipeline.stages.fit_incremental import INPUT_TOL
from tests.conftest import write_tiny_session

N_FRAMES, EDIT = 80, 70
SMOOTHER_REACH = 40
"""Frames before an edit the Kalman smoother may still move (its backward pass decays)."""


def test_hold_lengths_keeps_a_length_that_barely_moved() -> None:
    held = np.array([[0.30, 0.40, np.nan, 0.25]])
    new = np.array([[0.303, 0.45, np.nan, np.nan]])
    out = hold_lengths(new, held, 0.02)
    np.testing.assert_array_equal(out, [[0.30, 0.45, np.nan, np.nan]])
    assert hold_lengths(new, None, 0.02) is new and hold_lengths(new, held, 0.0) is new
    assert hold_lengths(new, held[:, :2], 0.02) is new  # another bone set: nothing held


def _options(session: Path, triangulate: dict) -> None:
    d = json.loads((session / "session.json").read_text())
    d["stage_config"] = {"triangulate": triangulate}
    (session / "session.json").write_text(json.dumps(d))


def test_a_late_edit_leaves_the_early_frames_untouched(tmp_path: Path) -> None:
    stages = ("detect2d", "track", "associate", "calibrate", "triangulate")
    s = write_tiny_session(tmp_path / "s", stages=stages, n_frames=N_FRAMES)
    store = ArtifactStore(s)
    reports = {r.stage: r for r in run(s)}
    assert reports["triangulate"].metrics["incremental"] == "full run: no previous run"
    before = store.load("triangulate", "keypoints3d", Keypoints3D)
    bones = store.load("triangulate", "bone_lengths", BoneLengths)
    assert bones.rigid_m.shape[0] == before.n_persons and np.isfinite(bones.rigid_m).any()

    save_annotations(s / "annotations.json", [SwapIdentities(frame=EDIT, person_a=0, person_b=1)])
    reports = {r.stage: r for r in run(s)}
    tri = reports["triangulate"]
    assert tri.action == "ran" and tri.metrics["incremental"].startswith("bone lengths held")
    # The calibrate stage re-ran on the edited association and kept its rig (same decision, within the thresholds).
    assert reports["calibrate"].action == "ran" and reports["calibrate"].metrics["incremental"].startswith(
        "previous rig kept"
    )
    after = store.load("triangulate", "keypoints3d", Keypoints3D)
    early = slice(0, EDIT - SMOOTHER_REACH)
    # Unchanged for the fit's incremental re-run: within its input tolerance (the smoother's
    # backward pass leaves changes of ~1e-7 m this far back).
    assert np.array_equal(after.valid[early], before.valid[early])
    assert np.abs(after.xyz_m[early] - before.xyz_m[early]).max() <= INPUT_TOL["kp3d_m"]
    assert not np.allclose(after.xyz_m[EDIT:], before.xyz_m[EDIT:])  # the swap took effect

    # Off: the bone lengths are estimated afresh, and the manifest says why.
    _options(s, {"incremental": False})
    reports = {r.stage: r for r in run(s)}
    assert reports["triangulate"].metrics["incremental"] == "full run: incremental is off"


def _standing(n_frames: int, forearm_scale: np.ndarray) -> Keypoints3D:
    """One person standing still (the fill template), left forearm scaled per frame."""
    from pipeline.schema.joints import COCO17
    from pipeline.stages.joint_fill import TEMPLATE_M

    names = tuple(COCO17)
    base = np.array([TEMPLATE_M[n] for n in names])
    xyz = np.repeat(base[None, None], n_frames, axis=0).copy()  # (F, 1, J, 3)
    e, w = names.index("left_elbow"), names.index("left_wrist")
    xyz[:, 0, w] = xyz[:, 0, e] + forearm_scale[:, None] * (base[w] - base[e])
    ones = np.ones((n_frames, 1, len(names)))
    conf = 0.9 * ones
    conf[:, 0, w] = 0.8  # the wrist is the bone check's weaker end
    return Keypoints3D(
        joint_names=names, person_ids=np.array([0]), frame_indices=np.arange(n_frames), fps=50.0,
        xyz_m=xyz, valid=ones.astype(bool), confidence=conf, n_views=(3 * ones).astype(np.int64),
        reproj_err_px=ones, source="raw",
    )  # fmt: skip


def test_held_bone_lengths_keep_an_early_outlier_decision() -> None:
    """An early frame just beyond the bone check's tolerance; a late edit moves the median
    forearm by under 1 %: afresh the early frame flips to an inlier and its wrist moves, held
    it stays as it was."""
    from pipeline.stages.filtering import FilterConfig, run_holding

    rng = np.random.default_rng(0)
    F = 100
    cfg = FilterConfig()
    scale = 1.0 + rng.uniform(-0.03, 0.03, F)
    edited = scale.copy()
    edited[80:] = 1.03  # the late frames' forearm changes (an identity fix): its median moves up
    # Frame 10: beyond the tolerance of the first median, within that of the edited one.
    scale[10] = edited[10] = (1.0 + cfg.bone_tolerance) * 0.5 * (np.median(scale) + np.median(edited))
    first, bones = run_holding(_standing(F, scale), cfg)
    fresh, fresh_bones = run_holding(_standing(F, edited), cfg)
    held, held_bones = run_holding(_standing(F, edited), cfg, held=bones)
    k = bones.rigid_m.shape[1]
    assert (
        k and np.nanmax(np.abs(fresh_bones.rigid_m / bones.rigid_m - 1.0)) < cfg.hold_bone_rel
    )  # a small move
    np.testing.assert_array_equal(held_bones.rigid_m, bones.rigid_m)
    early = slice(0, 40)
    assert np.abs(held.xyz_m[early] - first.xyz_m[early]).max() <= INPUT_TOL["kp3d_m"]
    # Afresh the early frame moves by far more than the fit's input tolerance (0.5 mm).
    assert np.abs(fresh.xyz_m[early] - first.xyz_m[early]).max() > 10 * INPUT_TOL["kp3d_m"]
