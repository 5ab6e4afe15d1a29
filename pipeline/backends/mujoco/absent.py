"""Persons absent from the input (not yet in view, or gone) in a multi-person scene.

Such a person is still simulated, so that the simulation stays one continuous state, but
neither output nor scored; their stand-in must not touch the athletes who are there. Three
places would let it: the simulated contacts (``AbsentContacts`` switches the stand-in's geoms
to collide with the floor and stand-ins only), the tracking cost's collision term and the reference's
separation (both read inter-person contacts through a geom -> person map, in which
``geom_groups`` hides the absent persons).

Contact bits (MuJoCo collides two geoms when ``contype1 & conaffinity2`` or
``contype2 & conaffinity1``): the floor has ``contype`` 1 and every ``conaffinity`` bit; an
athlete's geoms have ``conaffinity`` ``PERSON_AFFINITY`` (every bit but ``ABSENT_BIT``), so a
stand-in whose ``contype`` and ``conaffinity`` are ``ABSENT_BIT`` touches the floor, itself (as
built: the excluded pairs stay excluded) and other stand-ins, and no athlete in view.
"""

from __future__ import annotations

import mujoco
import numpy as np

ABSENT_BIT = 1 << 30
"""The contact bit of an absent person's geoms: only the floor's conaffinity has it."""
PERSON_AFFINITY = 0x3FFFFFFF
"""An athlete's geoms' conaffinity: every contact bit but ``ABSENT_BIT``."""


def out_of_view(weight: np.ndarray) -> np.ndarray:
    """(frames, persons) bool: no weighted site of the person in the frame (``weight``:
    (frames, persons, sites) >= 0, 0 where the joint was not observed)."""
    return np.asarray(~(weight > 0).any(axis=2), dtype=bool)


def absent_persons(weight: np.ndarray, first: int, stop: int) -> np.ndarray:
    """(persons,) bool: ``out_of_view`` in every frame from ``first`` to ``stop - 1``."""
    return np.asarray(out_of_view(weight[first:stop]).all(axis=0), dtype=bool)


def geom_groups(geom_person: np.ndarray, absent: np.ndarray) -> np.ndarray:
    """``geom_person`` (ngeom,) person index per geom, -1 = not a person, with the geoms of
    the ``absent`` (persons,) persons set to -1 too: inter-person contacts then leave them out."""
    if not absent.any():
        return geom_person
    return np.where((geom_person >= 0) & absent[np.maximum(geom_person, 0)], -1, geom_person)


class AbsentContacts:
    """Switches the simulated contacts of absent persons to the floor and themselves, in
    ``model`` (changed in place; ``restore`` puts every geom back)."""

    def __init__(self, model: mujoco.MjModel, geom_person: np.ndarray) -> None:
        self._model = model
        self._geom_person = np.asarray(geom_person)
        self._contype = model.geom_contype.copy()
        self._conaffinity = model.geom_conaffinity.copy()

    def apply(self, absent: np.ndarray) -> None:
        """Geoms of the ``absent`` (persons,) persons touch the floor and stand-ins only; all
        others as built."""
        self.restore()
        if absent.any():
            g = (self._geom_person >= 0) & absent[np.maximum(self._geom_person, 0)]
            self._model.geom_contype[g] = ABSENT_BIT
            self._model.geom_conaffinity[g] = ABSENT_BIT

    def restore(self) -> None:
        """Every geom's contact bits as the model was built."""
        self._model.geom_contype[:] = self._contype
        self._model.geom_conaffinity[:] = self._conaffinity
