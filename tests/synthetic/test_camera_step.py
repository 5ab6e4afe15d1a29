"""``SyntheticConfig.camera_step_deg``: cameras a chosen angle apart, with every random draw kept."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.synthetic import SyntheticConfig, make_bout


def _azimuth_deg(rig) -> np.ndarray:  # noqa: ANN001
    centres = rig.T_world_cam[:, :3, 3]
    return np.degrees(np.arctan2(centres[:, 1], centres[:, 0]))


def _gap_deg(a: float, b: float) -> float:
    """Angle from a to b around the ring, in [0, 360)."""
    return float((b - a) % 360.0)


def test_two_cameras_a_quarter_turn_apart_keep_every_other_draw() -> None:
    opposite = make_bout(SyntheticConfig(seed=3, n_frames=30, n_cameras=2))
    quarter = make_bout(SyntheticConfig(seed=3, n_frames=30, n_cameras=2, camera_step_deg=90.0))
    az_o, az_q = _azimuth_deg(opposite.rig), _azimuth_deg(quarter.rig)
    assert abs(_gap_deg(*az_o) - 180.0) <= 14.0  # evenly spread: facing each other (+-7 deg jitter each)
    assert abs(_gap_deg(*az_q) - 90.0) <= 14.0
    # Only the second camera moved around the ring: same first camera, lens, height and distance.
    np.testing.assert_allclose(quarter.rig.T_world_cam[0], opposite.rig.T_world_cam[0])
    np.testing.assert_allclose(quarter.rig.K, opposite.rig.K)
    c_q, c_o = quarter.rig.T_world_cam[:, :3, 3], opposite.rig.T_world_cam[:, :3, 3]
    np.testing.assert_allclose(c_q[:, 2], c_o[:, 2])
    np.testing.assert_allclose(np.linalg.norm(c_q[:, :2], axis=1), np.linalg.norm(c_o[:, :2], axis=1))
    # The same motion, seen from elsewhere: identical 3D, different 2D in the moved view.
    np.testing.assert_array_equal(quarter.gt.xyz_m, opposite.gt.xyz_m)
    first_q = quarter.clean_keypoints_px[quarter.tracks.view == 0]
    first_o = opposite.clean_keypoints_px[opposite.tracks.view == 0]
    np.testing.assert_allclose(first_q, first_o)
    second_q = quarter.clean_keypoints_px[quarter.tracks.view == 1]
    second_o = opposite.clean_keypoints_px[opposite.tracks.view == 1]
    assert second_q.shape != second_o.shape or not np.allclose(second_q, second_o)


def test_an_even_step_is_the_default_rig() -> None:
    even = make_bout(SyntheticConfig(seed=5, n_frames=10, n_cameras=4, camera_step_deg=90.0))
    default = make_bout(SyntheticConfig(seed=5, n_frames=10, n_cameras=4))
    np.testing.assert_allclose(even.rig.T_world_cam, default.rig.T_world_cam, atol=1e-12)


@pytest.mark.parametrize(("n_cameras", "step"), [(2, 181.0), (4, 91.0), (2, 10.0), (2, float("nan"))])
def test_a_step_out_of_range_is_refused(n_cameras: int, step: float) -> None:
    with pytest.raises(ValueError, match=r"camera_step_deg must be in \[15, .*\] deg for .* cameras"):
        SyntheticConfig(n_cameras=n_cameras, camera_step_deg=step)
