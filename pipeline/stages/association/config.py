"""Config of the ``associate`` stage (defaults in one place)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np


@dataclass(frozen=True)
class AssociateConfig:
    """Cross-view identity association.

    Costs are *relative*: a mean per-joint pixel distance divided by the detection's box
    size (max of width and height), so that the thresholds hold for any resolution and
    camera distance.
    """

    n_persons: int | Literal["athletes", "auto"] = "athletes"
    """How many persons to keep (ids ``0 .. n-1``; every other identity is ``-1``): a number
    (>= 1); ``"athletes"``, one per name of the session's ``athletes`` list; or ``"auto"``,
    every identity seen in >= 2 views for ``auto_min_support_s`` inside the capture volume."""
    auto_min_support_s: float = 2.0
    """``"auto"``: an identity counts when seen in >= 2 views for this long (s, > 0), capped
    at ``auto_min_support_frac`` of the bout so that a short clip keeps its persons."""
    auto_min_support_frac: float = 0.3
    """``"auto"``: cap of ``auto_min_support_s`` as a fraction of the bout's duration, in (0, 1]."""
    bystander_view_frac: float = 0.6
    """An identity whose mean position lies in the field of view of fewer than this fraction
    of the cameras is a bystander (standing outside the capture volume), in [0, 1]; such
    identities are never chosen in ``"auto"`` mode and rank last in the other modes."""
    min_keypoint_conf: float = 0.2
    """Joints below this 2D confidence are ignored for association."""
    gate: float = 0.25
    """Largest relative reprojection cost for a detection to be attached to a 3D person."""
    joint_cap: float = 0.6
    """Per-joint relative distances are clipped at this value (robust to a few wrong joints)."""
    min_joints: int = 3
    """A cost needs at least this many joints shared by the detection and the person."""
    track_bonus: float = 0.03
    """Cost reduction for keeping a per-view track's previous identity (a tie-breaker only:
    geometry overrides it, which is what catches per-view track id swaps)."""
    birth_epipolar: float = 0.06
    """Largest relative pose epipolar distance for two detections to propose a new person."""
    birth_min_views: int = 2
    """A new person needs consistent detections in at least this many views."""
    duplicate_dist_m: float = 0.3
    """A proposal whose centroid is this close to an existing person is not a new person."""
    assign_chunk_s: float = 0.06
    """Frames are assigned in chunks this long against persons predicted to each frame,
    with one 3D refresh per chunk (0 = refresh every frame). 3 frames at 50 fps."""
    max_speed_mps: float = 6.0
    """Cap of the centroid speed used to predict a person into the next frame."""
    max_missing_s: float = 1.0
    """A 3D person not seen for longer ends (a later return starts a new fragment)."""
    merge_max_gap_s: float = 3.0
    """Fragments separated by at most this gap may be merged into one identity."""
    merge_speed_mps: float = 3.0
    """... when the later one starts within ``merge_slack_m + merge_speed_mps * gap`` of
    where the earlier one ended (or when they share a per-view track)."""
    merge_slack_m: float = 0.5
    """See ``merge_speed_mps``."""
    min_support_frames: int = 3
    """An identity seen in two or more views in fewer frames than this is never an athlete."""
    support_tolerance: float = 0.2
    """Identities within this relative margin of the best multi-view support are ranked by
    how close they stay to where the cameras look (the ring centre) instead."""

    def __post_init__(self) -> None:
        n = self.n_persons
        if isinstance(n, bool) or not (isinstance(n, int) and n >= 1 or n in ("athletes", "auto")):
            raise ValueError(f'AssociateConfig.n_persons must be an integer >= 1, "athletes" or "auto", got {n!r}')
        for name, lo, hi in (("auto_min_support_s", 0.0, np.inf), ("auto_min_support_frac", 0.0, 1.0)):
            v = getattr(self, name)
            if not (np.isfinite(v) and lo < v <= hi):
                raise ValueError(f"AssociateConfig.{name} must be in ({lo}, {hi}], got {v!r}")
        if not 0.0 <= self.bystander_view_frac <= 1.0:
            raise ValueError(f"AssociateConfig.bystander_view_frac must be in [0, 1], got {self.bystander_view_frac!r}")
