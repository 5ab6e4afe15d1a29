"""``layout_advice``: cameras that see no depth well (facing each other, or looking the same way)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.geometry.layout import GOOD_PAIR_DEG, layout_advice, viewing_angles_deg
from pipeline.geometry.rotations import look_at_T_world_cam
from pipeline.schema.camera import CameraRig


def _rig(azimuths_deg: list[float], height_m: float = 2.5) -> CameraRig:
    """Cameras 6 m from the ring centre at these azimuths, looking at (0, 0, 1)."""
    a = np.radians(azimuths_deg)
    n = len(a)
    Ts = [look_at_T_world_cam(np.array([6 * np.cos(t), 6 * np.sin(t), height_m]), np.array([0.0, 0.0, 1.0])) for t in a]
    K = np.array([[1000.0, 0, 640], [0, 1000.0, 360], [0, 0, 1]])
    return CameraRig(names=tuple(f"cam{i + 1}" for i in range(n)), K=np.stack([K] * n), dist=np.zeros((n, 5)),
                     T_world_cam=np.stack(Ts), image_size_wh=np.array([[1280, 720]] * n), fps=50.0)  # fmt: skip


def test_viewing_angles_of_a_level_rig_are_the_azimuth_gaps() -> None:
    ang = viewing_angles_deg(_rig([0.0, 90.0, 180.0], height_m=1.0))  # looking level: axes in the floor plane
    np.testing.assert_allclose(ang, [[0, 90, 180], [90, 0, 90], [180, 90, 0]], atol=1e-6)


def test_two_cameras_facing_each_other_get_advice() -> None:
    advice = layout_advice(_rig([10.0, 190.0]))
    assert advice is not None and advice.startswith("cam1 and cam2 look ")
    assert "(facing each other)" in advice and f"{GOOD_PAIR_DEG[0]:g}-{GOOD_PAIR_DEG[1]:g} deg apart" in advice


def test_two_cameras_side_by_side_get_advice() -> None:
    advice = layout_advice(_rig([0.0, 20.0]))
    assert advice is not None and "(looking the same way)" in advice


@pytest.mark.parametrize("azimuths", [[0.0, 90.0], [0.0, 60.0], [0.0, 120.0], [0.0], [0.0, 180.0, 90.0], [0, 72, 144, 216, 288]])
def test_a_rig_with_a_good_pair_or_a_single_camera_gets_none(azimuths: list[float]) -> None:
    assert layout_advice(_rig(azimuths)) is None


def test_more_cameras_none_of_them_a_good_pair() -> None:
    advice = layout_advice(_rig([0.0, 180.0, 10.0]))
    assert advice is not None and advice.startswith("no two of the 3 cameras are 45-135 deg apart (the nearest, ")
