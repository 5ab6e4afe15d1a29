"""Southpaw bouts: the whole bout seen in a mirror (``SyntheticConfig.southpaw``).

The script is written for two orthodox boxers (lead = left). Reflecting every joint of both
boxers in the world plane x = 0 and swapping the left and right labels
(``schema.joints.mirror_joints``) turns each of them into a southpaw (lead = right, right foot
in front) without re-scripting anything: a reflection keeps every distance, so every contact,
outcome, clinch and strike frame of the script holds in the mirror too. Only the hands change names: a jab is thrown with the right
hand. Both boxers are southpaws (for one southpaw against an orthodox boxer:
``SyntheticConfig.mixed_stance``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.schema.analytics import HANDS
from pipeline.synthetic.truth import BoutTruth


def mirror_feet(contact: np.ndarray) -> np.ndarray:
    """(..., 2) (left, right) foot flags of the mirrored bout: the two exchanged."""
    return np.asarray(contact)[..., ::-1].copy()


def _other_hand(hands: np.ndarray) -> np.ndarray:
    left, right = HANDS
    return np.where(hands == left, right, np.where(hands == right, left, hands))


def mirror_truth(truth: BoutTruth) -> BoutTruth:
    """``truth`` of the mirrored bout: every hand (punches, feints, parries) is the other one;
    types (lead / rear), frames, targets and outcomes are unchanged."""
    return dataclasses.replace(
        truth,
        punch_hand=_other_hand(truth.punch_hand),
        feint_hand=_other_hand(truth.feint_hand),
        parry_hand=_other_hand(truth.parry_hand),
    )
