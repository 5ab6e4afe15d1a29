"""The fit's overlap term between athletes (torch) against the numpy metric."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from pipeline.backends.fitting.contacts import ProxyOverlap, _segment_distance  # noqa: E402
from pipeline.evaluate.physics_metrics import inter_person_penetration_mm  # noqa: E402
from pipeline.geometry.segments import segment_distance  # noqa: E402
from pipeline.schema.joints import COCO17_FEET  # noqa: E402
from pipeline.schema.keypoints3d import Keypoints3D  # noqa: E402


def test_segment_distance_matches_the_numpy_geometry() -> None:
    rng = np.random.default_rng(0)
    p0, p1, q0, q1 = (rng.normal(size=(500, 3)) for _ in range(4))
    q1[:20] = q0[:20]  # degenerate second segments (points)
    p1[20:40] = p0[20:40]
    q1[40:60] = q0[40:60] + 0.5 * (p1[40:60] - p0[40:60])  # parallel
    want = segment_distance(p0, p1, q0, q1)
    got = _segment_distance(*(torch.as_tensor(x) for x in (p0, p1, q0, q1))).numpy()
    np.testing.assert_allclose(got, want, atol=1e-9)


def _pair(gap_m: float) -> np.ndarray:
    """(2, 1, J, 3): two identical standing 'persons' (a vertical stack of joints),
    ``gap_m`` apart along x."""
    base = np.zeros((len(COCO17_FEET), 3))
    base[:, 2] = np.linspace(0.1, 1.6, len(COCO17_FEET))
    base[:, 1] = np.where(np.arange(len(COCO17_FEET)) % 2 == 0, 0.1, -0.1)
    return np.stack([base, base + [gap_m, 0.0, 0.0]])[:, None]


def test_overlap_is_the_metric_squared_and_pushes_apart() -> None:
    term = ProxyOverlap()
    present = torch.ones((2, 1), dtype=torch.bool)
    far = torch.as_tensor(_pair(2.0))
    assert float(term(far, present)) == 0.0
    near = torch.as_tensor(_pair(0.1), dtype=torch.float64).requires_grad_(True)
    value = term(near, present)
    assert float(value.detach()) > 0.0
    # The deepest overlap the metric reports is one of the overlaps the term squares.
    kp = Keypoints3D(
        joint_names=COCO17_FEET, person_ids=np.array([0, 1]), frame_indices=np.arange(1), fps=50.0,
        xyz_m=_pair(0.1).transpose(1, 0, 2, 3), valid=np.ones((1, 2, len(COCO17_FEET)), bool),
        confidence=np.ones((1, 2, len(COCO17_FEET))), n_views=np.zeros((1, 2, len(COCO17_FEET)), np.int64),
        reproj_err_px=np.full((1, 2, len(COCO17_FEET)), np.nan), source="fit",
    )
    deepest_m = inter_person_penetration_mm(kp)[0] / 1000.0
    assert deepest_m**2 <= float(value.detach()) + 1e-12
    value.backward()
    grad = near.grad
    assert grad is not None and torch.isfinite(grad).all()
    # Descending the term moves person 0 toward -x and person 1 toward +x.
    assert float(grad[0, ..., 0].sum()) > 0.0 and float(grad[1, ..., 0].sum()) < 0.0
    # Frames where one person is absent do not count.
    assert float(term(torch.as_tensor(_pair(0.1)), torch.tensor([[True], [False]]))) == 0.0
