"""Per-person bone lengths a stage estimated over a bout (and may hold on its next run)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.schema.base import check_array


@dataclass(frozen=True)
class BoneLengths:
    """Median bone lengths per person, as the temporal filter used them.

    Fields:
        person_ids: (persons,) global person ids.
        rigid_m: (persons, rigid bones) lengths in metres of ``filtering.RIGID_BONES`` present
            in the joint set (the outlier check); NaN for a bone never seen.
        limbs_m: (persons, bones) lengths in metres of ``filtering.BONES`` present (the
            single-view ray placement); NaN for a bone never seen.
    """

    person_ids: np.ndarray
    rigid_m: np.ndarray
    limbs_m: np.ndarray

    def __post_init__(self) -> None:
        p = self.person_ids.shape[0] if isinstance(self.person_ids, np.ndarray) else -1
        check_array("BoneLengths.person_ids", self.person_ids, (p,), "iu")
        check_array("BoneLengths.rigid_m", self.rigid_m, (p, None), "f")
        check_array("BoneLengths.limbs_m", self.limbs_m, (p, None), "f")
