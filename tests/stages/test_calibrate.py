"""Calibrate stage: "auto" adopts a refinement only when held-out frames confirm it."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.geometry.bundle import BundleConfig
from pipeline.schema import Association, Tracks2D
from pipeline.schema.config_types import build_config
from pipeline.stages.calibrate import CalibrateConfig, FloorConfig, gather_pixels, run, summary
from pipeline.synthetic.bout import SyntheticBout, make_bout
from pipeline.synthetic.config import SyntheticConfig
from tests.geometry.test_bundle import perturb, pose_errors


def _subset(b: SyntheticBout, keep: np.ndarray, **override: int) -> tuple[Tracks2D, Association]:
    """The bout's tracks and true identities restricted to the rows ``keep``."""
    t = b.tracks
    kw = {k: (v[keep] if isinstance(v, np.ndarray) else v) for k, v in t.__dict__.items()}
    a = b.gt_association()
    return Tracks2D(**{**kw, **override}), Association(
        a.person_ids, a.person_names, a.person_of_det[keep], a.confidence[keep]
    )


KEEP_FLOOR = FloorConfig(mode="off")
"""These tests look at the refinement: a perturbed rig's world is also off the floor, which
the floor levelling (tests/geometry/test_floor.py) would move."""


@pytest.fixture(scope="module")
def bout() -> SyntheticBout:
    """4 cameras x 100 frames, 2 boxers + a bystander, 3 px keypoint noise."""
    return make_bout(SyntheticConfig(n_cameras=4, n_frames=100, seed=0))


def test_auto_adopts_on_a_perturbed_rig(bout: SyntheticBout) -> None:
    start = perturb(bout.rig, seed=0)
    res = run(bout.tracks, bout.gt_association(), start)
    assert res.adopted and res.reason.startswith("adopted: held-out median"), res.reason
    assert res.heldout_after_px < 0.5 * res.heldout_before_px
    assert res.before is not None and res.after is not None
    assert np.all(res.after.median_px < 0.5 * res.before.median_px)
    dc0, dr0, _ = pose_errors(bout.rig, start)
    dc, dr, _ = pose_errors(bout.rig, res.rig)
    # Closer to the truth (at 3 px noise on 50 frames the centres are only good to ~2 cm).
    assert dc.mean() < 0.7 * dc0.mean() and dr.max() < 0.4 * dr0.mean()
    assert np.all(res.center_shift_m > 0.0) and res.converged
    s = summary(res)
    assert s["adopted"] is True and s["median_after_px"] < s["median_before_px"]


def test_auto_refuses_when_the_rig_is_already_right(bout: SyntheticBout) -> None:
    res = run(bout.tracks, bout.gt_association(), bout.rig)
    assert not res.adopted and "below the required 10.0 %" in res.reason, res.reason
    assert res.rig is bout.rig
    assert abs(res.heldout_after_px - res.heldout_before_px) < 0.03 * res.heldout_before_px


def test_auto_refuses_when_data_cannot_constrain_a_camera(bout: SyntheticBout) -> None:
    """cam03 sees one athlete in one frame only: too few correspondences to refine it."""
    first = (bout.tracks.frame == 0) & (bout.gt_person_of_det == 0)
    keep = (bout.tracks.view != 2) | first
    tracks, assoc = _subset(bout, keep)
    start = perturb(bout.rig, seed=0)
    res = run(tracks, assoc, start, CalibrateConfig(floor=KEEP_FLOOR))
    assert not res.adopted and res.rig is start
    assert "too few correspondences" in res.reason and "cam03" in res.reason, res.reason
    with pytest.raises(ValueError, match="too few correspondences"):
        run(tracks, assoc, start, CalibrateConfig(mode="on"))


def test_auto_refuses_a_clip_too_short_to_validate(bout: SyntheticBout) -> None:
    keep = bout.tracks.frame < 6
    tracks, assoc = _subset(bout, keep, n_frames=6)
    res = run(tracks, assoc, bout.rig)
    assert not res.adopted and "6 frames are too few" in res.reason and res.before is None


def test_one_camera(bout: SyntheticBout) -> None:
    keep = bout.tracks.view == 0
    tracks, assoc = _subset(bout, keep, n_views=1)
    rig = bout.rig.subset([0])
    res = run(tracks, assoc, rig)
    assert not res.adopted and "needs >= 2 cameras" in res.reason
    with pytest.raises(ValueError, match="needs >= 2 cameras"):
        run(tracks, assoc, rig, CalibrateConfig(mode="on"))


def test_modes_on_and_off(bout: SyntheticBout) -> None:
    start = perturb(bout.rig, seed=1)
    off = run(bout.tracks, bout.gt_association(), start, CalibrateConfig(mode="off", floor=KEEP_FLOOR))
    assert off.rig is start and not off.adopted and "off" in off.reason and off.before is None
    on = run(bout.tracks, bout.gt_association(), start, CalibrateConfig(mode="on"))
    assert on.adopted and on.rig is not start and np.isnan(on.heldout_before_px)
    assert on.after is not None and on.before is not None and on.after.all_median_px < on.before.all_median_px


def test_gather_pixels_rows_are_frame_person_joint(bout: SyntheticBout) -> None:
    uv, conf, frame = gather_pixels(bout.tracks, bout.gt_association(), 4)
    J = len(bout.tracks.joint_names)
    assert uv.shape == (100 * 2 * J, 4, 2) and conf.shape == (100 * 2 * J, 4)
    assert np.array_equal(frame[:: 2 * J], np.arange(100))
    # A row: one joint of one athlete in one frame, the same in every view.
    i = np.flatnonzero((bout.gt_person_of_det == 1) & (bout.tracks.frame == 7) & (bout.tracks.view == 3))[0]
    row = (7 * 2 + 1) * J + 5
    assert np.allclose(uv[row, 3], bout.tracks.keypoints_px[i, 5])
    with pytest.raises(ValueError, match="tracks have 4 views but the rig has 3"):
        gather_pixels(bout.tracks, bout.gt_association(), 3)


def test_config() -> None:
    cfg = build_config(
        CalibrateConfig, {"mode": "on", "bundle": {"refine_focal": True}}, "stage_config.calibrate"
    )
    assert cfg.bundle == BundleConfig(refine_focal=True)
    assert CalibrateConfig(bundle={"max_points": 500}).bundle.max_points == 500  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="unknown keys"):
        CalibrateConfig(bundle={"refine_focus": True})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="mode"):
        CalibrateConfig(mode="maybe")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="min_improvement"):
        CalibrateConfig(min_improvement=1.5)


def test_hold_thresholds_compare_two_rigs_per_camera() -> None:
    import dataclasses

    from pipeline.stages.calibrate import holds, rig_change
    from tests.conftest import make_rig

    rig = make_rig(3)
    T = rig.T_world_cam.copy()
    T[1, :3, 3] += [0.004, 0.0, 0.0]  # camera 2 moves 4 mm
    near = dataclasses.replace(rig, T_world_cam=T)
    centre, rot, focal = rig_change(rig, near)
    np.testing.assert_allclose(centre, [0.0, 4.0, 0.0], atol=1e-9)
    assert rot.max() == pytest.approx(0.0, abs=1e-6) and focal.max() == 0.0
    cfg = CalibrateConfig()
    assert holds(rig, near, cfg) and holds(rig, rig, cfg)
    T2 = T.copy()
    T2[2, :3, 3] += [0.0, 0.0, 0.006]  # 6 mm: beyond hold_center_mm
    assert not holds(rig, dataclasses.replace(rig, T_world_cam=T2), cfg)
    K = rig.K.copy()
    K[0, 0, 0] *= 1.01
    assert not holds(rig, dataclasses.replace(rig, K=K), cfg)
    assert not holds(rig, make_rig(2), cfg)
    with pytest.raises(ValueError, match="hold_center_mm"):
        CalibrateConfig(hold_center_mm=-1.0)
