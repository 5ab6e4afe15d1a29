"""Southpaw bouts (``SyntheticConfig.southpaw``): the orthodox bout of the same seed in a
mirror, labelled with the hands as performed, and read back as southpaw by the analytics."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.schema.analytics import STANCE_CODES
from pipeline.schema.joints import COCO17_FEET, mirror_joints
from pipeline.stages.analyze import AnalyzeConfig, AnalyzeInputs
from pipeline.stages.analyze import run as analyze
from pipeline.synthetic import SyntheticBout, SyntheticConfig, make_bout
from pipeline.synthetic.mirror import mirror_feet

SEED = 14
"""A varied bout with punches of both hands, lead and rear (held-out seed of bench analytics)."""


def _bout(southpaw: bool) -> SyntheticBout:
    return make_bout(
        SyntheticConfig(seed=SEED, n_frames=300, n_cameras=2, variety=True, bystander=False, southpaw=southpaw)
    )


@pytest.fixture(scope="module")
def pair() -> tuple[SyntheticBout, SyntheticBout]:
    return _bout(False), _bout(True)


def test_mirror_is_a_reflection_with_sides_exchanged() -> None:
    xyz = np.random.default_rng(0).normal(size=(3, 2, len(COCO17_FEET), 3))
    m = mirror_joints(xyz)
    li, ri = COCO17_FEET.index("left_wrist"), COCO17_FEET.index("right_wrist")
    np.testing.assert_array_equal(m[..., li, 0], -xyz[..., ri, 0])
    np.testing.assert_array_equal(m[..., li, 1:], xyz[..., ri, 1:])
    nose = COCO17_FEET.index("nose")
    np.testing.assert_array_equal(m[..., nose, 1:], xyz[..., nose, 1:])
    np.testing.assert_array_equal(mirror_joints(m), xyz)  # twice is the identity
    # Distances within and between persons are kept.
    d = np.linalg.norm(xyz[:, 0, :, None] - xyz[:, 1, None, :], axis=-1)
    dm = np.linalg.norm(m[:, 0, :, None] - m[:, 1, None, :], axis=-1)
    order = [COCO17_FEET.index(n.replace("left", "#").replace("right", "left").replace("#", "right")) for n in COCO17_FEET]
    np.testing.assert_allclose(dm, d[:, order][:, :, order])
    np.testing.assert_array_equal(mirror_feet(np.array([[True, False]])), [[False, True]])


def test_southpaw_bout_is_the_orthodox_one_mirrored(pair: tuple[SyntheticBout, SyntheticBout]) -> None:
    orth, south = pair
    np.testing.assert_array_equal(south.gt.xyz_m, mirror_joints(orth.gt.xyz_m))
    np.testing.assert_array_equal(south.foot_contact, orth.foot_contact[..., ::-1])
    a, b = orth.truth, south.truth
    assert a.n_punches == b.n_punches > 0
    assert set(a.punch_hand.tolist()) == {"left", "right"}
    np.testing.assert_array_equal(b.punch_hand, np.where(a.punch_hand == "left", "right", "left"))
    for name in ("punch_type", "punch_start_frame", "punch_peak_frame", "punch_outcome", "clinch"):
        np.testing.assert_array_equal(getattr(b, name), getattr(a, name))
    # Jabs are thrown with the right hand, crosses with the left.
    types = dict(zip(b.punch_type.tolist(), b.punch_hand.tolist(), strict=False))
    assert types.get("jab", "right") == "right" and types.get("cross", "left") == "left"


def test_analytics_read_the_mirror_as_southpaw(pair: tuple[SyntheticBout, SyntheticBout]) -> None:
    """On the ground-truth joints the analytics find the same punches, with the other hand and
    the same lead / rear type, and the stance flips from orthodox to southpaw."""
    cfg = AnalyzeConfig()
    (eo, so), (es, ss) = ((r.events, r.series) for r in (analyze(AnalyzeInputs(b.gt), cfg) for b in pair))
    assert eo.n_punches >= 5
    np.testing.assert_array_equal(es.punch_peak_frame, eo.punch_peak_frame)
    np.testing.assert_array_equal(es.punch_type, eo.punch_type)
    np.testing.assert_array_equal(es.punch_hand, np.where(eo.punch_hand == "left", "right", "left"))
    code = {v: k for k, v in STANCE_CODES.items()}
    for p in range(2):
        assert np.mean(so.stance[:, p] == code["orthodox"]) > 0.7
        assert np.mean(ss.stance[:, p] == code["southpaw"]) > 0.7
        np.testing.assert_array_equal(ss.stance[:, p] == code["southpaw"], so.stance[:, p] == code["orthodox"])
