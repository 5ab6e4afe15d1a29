"""The root wrench a motion needs beyond its foot contacts (inverse dynamics)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mujoco")

from pipeline.stages.physics_dynamics import needed_residual  # noqa: E402
from tests.stages.test_physics import _facing_pair  # noqa: E402


def _shifted(kp, dz_m: np.ndarray):  # type: ignore[no-untyped-def]
    xyz = kp.xyz_m.copy()
    xyz[..., 2] += dz_m[:, None, None]
    return kp.replace(xyz_m=xyz)


def test_standing_needs_no_residual_and_hanging_needs_body_weight() -> None:
    stand = _facing_pair(1.2, n_frames=12)
    res = needed_residual(stand)
    assert res.force_n.shape == (12, 2, 3) and res.torque_nm.shape == (12, 2, 3)
    assert np.all(res.weight_n > 300.0)
    s = res.summary()
    # The feet carry the weight of a person standing (and swaying by 1 cm).
    assert s["needed_force_frac_bw"] < 0.02 and s["needed_torque_bw_m"] < 0.01
    # Held still 0.3 m above the floor: the pelvis must be held up, by one body weight.
    still = stand.replace(xyz_m=np.repeat(stand.xyz_m[:1], 12, axis=0))
    hang = needed_residual(_shifted(still, np.full(12, 0.3)), body_keypoints=stand)
    f = hang.force_n / hang.weight_n[None, :, None]
    assert np.allclose(f[..., 2], 1.0, atol=0.03)
    assert np.abs(f[..., :2]).max() < 0.03
    # Swaying up there (±1 cm at 10 rad/s, ±0.1 g) also needs the sideways push.
    sway = needed_residual(_shifted(stand, np.full(12, 0.3)), body_keypoints=stand)
    fy = sway.force_n[..., 1] / sway.weight_n[None]
    assert 0.03 < np.abs(fy).max() < 0.12


def test_free_fall_needs_no_residual() -> None:
    stand = _facing_pair(3.0, n_frames=20)
    t = np.arange(20) / stand.fps
    still = stand.replace(xyz_m=np.repeat(stand.xyz_m[:1], 20, axis=0))
    fall = _shifted(still, 1.5 - 0.5 * 9.81 * t**2)  # from 1.5 m up, above the floor throughout
    res = needed_residual(fall, body_keypoints=stand)
    f = np.linalg.norm(res.force_n, axis=-1) / res.weight_n[None]
    # Interior frames (the 3-frame smoothing of velocities clamps at the ends).
    assert f[6:-6].max() < 0.05
    # Held still in the air at the same height, it needs its full weight instead.
    still = stand.replace(xyz_m=np.repeat(stand.xyz_m[:1], 20, axis=0))
    held = needed_residual(_shifted(still, np.full(20, 1.5)), body_keypoints=stand)
    assert np.allclose(np.linalg.norm(held.force_n, axis=-1) / held.weight_n[None], 1.0, atol=0.03)


def test_bad_input_is_refused_with_the_reason() -> None:
    kp = _facing_pair(1.2, n_frames=6)
    with pytest.raises(ValueError, match="at least 3 frames"):
        needed_residual(_facing_pair(1.2, n_frames=2))
    with pytest.raises(ValueError, match=r"needed_residual: persons \[1\] are not in body_keypoints"):
        needed_residual(kp, body_keypoints=kp.replace(person_ids=np.array([0, 7])))
    with pytest.raises(ValueError, match=r"got 0 of the requested \[5\] \(persons with motion: \[0, 1\]\)"):
        needed_residual(kp, person_ids=[5])
    only0 = needed_residual(kp, person_ids=[0])
    assert only0.person_ids.tolist() == [0] and only0.force_n.shape == (6, 1, 3)
