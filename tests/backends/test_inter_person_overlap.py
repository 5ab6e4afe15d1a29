"""The physics stage's deepest inter-person overlap leaves out persons absent from the input:
they are still simulated, but neither output nor scored (a phantom athlete standing where the
real one walks is not an overlap of the bout)."""

from __future__ import annotations

import numpy as np

from pipeline.backends.mujoco.physics import FrameContacts, deepest_inter_person_mm


def _contacts() -> FrameContacts:
    # frame 0: persons 5 and 7 overlap 30 mm; frame 1: 5 and 9 overlap 60 mm; frame 1: 7 on the ground 4 mm
    return FrameContacts(
        frame=np.array([0, 1, 1]),
        person=np.array([[5, 7], [5, 9], [7, -1]]),
        body=np.zeros((3, 2), dtype=np.int64),
        depth_m=np.array([0.030, 0.060, 0.004]),
        body_names=("torso",),
    )


def test_every_person_counts_without_an_observed_mask() -> None:
    np.testing.assert_allclose(deepest_inter_person_mm(_contacts(), 3), [30.0, 60.0, 0.0])


def test_a_contact_with_an_absent_person_does_not_count() -> None:
    observed = np.array([[True, True, True], [True, True, False], [True, True, True]])  # person 9 absent in frame 1
    out = deepest_inter_person_mm(_contacts(), 3, observed, np.array([5, 7, 9]))
    np.testing.assert_allclose(out, [30.0, 0.0, 0.0])
    observed[0, 1] = False  # person 7 absent in frame 0 as well
    np.testing.assert_allclose(deepest_inter_person_mm(_contacts(), 3, observed, np.array([5, 7, 9])), [0.0, 0.0, 0.0])
