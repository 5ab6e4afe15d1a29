"""The synthetic boxers never pass through each other (``pipeline.synthetic.separate``)."""

from __future__ import annotations

import numpy as np

from pipeline.evaluate.physics_metrics import CapsuleProxy, inter_person_penetration_mm
from pipeline.schema.joints import COCO17_FEET, RIGID_BONES, bone_indices
from pipeline.synthetic.bout import make_bout
from pipeline.synthetic.config import SyntheticConfig
from pipeline.synthetic.separate import separate_persons


def test_bout_ground_truth_has_no_interpenetration() -> None:
    bout = make_bout(SyntheticConfig(seed=3, n_frames=200, bystander=False, id_swaps=False))
    assert inter_person_penetration_mm(bout.gt).max() < 1.0


def test_separation_keeps_shape_and_planted_feet() -> None:
    bout = make_bout(SyntheticConfig(seed=0, n_frames=300, bystander=False, id_swaps=False, clinch=True))
    # Push the second boxer 12 cm towards the first: deeper clinch overlaps to resolve.
    x = bout.gt.xyz_m.copy()
    centre = x[:, :, :, :2].mean(axis=2, keepdims=True)
    x[:, 1, :, :2] -= (
        0.12
        * (centre[:, 1] - centre[:, 0])
        / np.linalg.norm(centre[:, 1] - centre[:, 0], axis=-1, keepdims=True)
    )
    overlapped = bout.gt.replace(xyz_m=x)
    assert inter_person_penetration_mm(overlapped).max() > 80.0
    pinned = np.zeros(x.shape[:3], dtype=bool)
    for k, side in enumerate(("left", "right")):
        for part in ("ankle", "heel", "big_toe", "small_toe"):
            pinned[:, :, COCO17_FEET.index(f"{side}_{part}")] = bout.foot_contact[:, :, k]
    y = separate_persons(x, pinned)
    assert inter_person_penetration_mm(bout.gt.replace(xyz_m=y)).max() < 1.0
    np.testing.assert_array_equal(y[pinned], x[pinned])
    for a, b in bone_indices(COCO17_FEET, RIGID_BONES):
        np.testing.assert_allclose(
            np.linalg.norm(y[:, :, a] - y[:, :, b], axis=-1),
            np.linalg.norm(x[:, :, a] - x[:, :, b], axis=-1),
            atol=1e-6,
        )
    far = np.linalg.norm(centre[:, 0, 0] - centre[:, 1, 0], axis=-1) > 2.0
    np.testing.assert_allclose(y[far], x[far])  # persons far apart are left alone


def test_separation_keeps_a_limb_on_one_side_of_an_arm_it_dips_through() -> None:
    """A forearm dipping through the other boxer's forearm and back out is held above it
    the whole time. Pushing each frame to its own nearer side instead sends it under the
    arm in mid-dip and back over it: a jump of ~20 cm in one frame."""
    F = 41
    x = np.zeros((F, 2, len(COCO17_FEET), 3))
    x[:, 1, :, 0] = 10.0  # every other joint of boxer 1 far away
    le, lw = COCO17_FEET.index("left_elbow"), COCO17_FEET.index("left_wrist")
    x[:, 0, le] = (0.0, -0.15, 1.2)  # boxer 0's forearm along y, still
    x[:, 0, lw] = (0.0, 0.15, 1.2)
    z = 1.0 + 0.35 * np.abs(np.linspace(-1.0, 1.0, F))  # boxer 1's forearm along x: through and back
    x[:, 1, le] = np.stack([np.full(F, -0.15), np.zeros(F), z], axis=-1)
    x[:, 1, lw] = np.stack([np.full(F, 0.15), np.zeros(F), z], axis=-1)
    proxy = CapsuleProxy(segments=(("left_elbow", "left_wrist", 0.045),))
    y = separate_persons(x, np.zeros(x.shape[:3], dtype=bool), proxy=proxy)
    gap = y[:, 1, lw, 2] - y[:, 0, lw, 2]
    assert gap.min() > 0.09  # above the other forearm (radii 2 x 4.5 cm) in every frame
    assert np.abs(np.diff(y[:, 1, lw], axis=0)).max() < 0.03
