"""Config of the ``associate`` stage (defaults in one place)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class AssociateConfig:
    """Cross-view identity association.

    Costs are *relative*: a mean per-joint pixel distance divided by the detection's box
    size (max of width and height), so that the thresholds hold for any resolution and
    camera distance.
    """

    n_persons: int = 2
    """Number of athletes to keep (ids ``0 .. n_persons-1``); every other identity is ``-1``."""
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
