"""Target region and outcome of a punch.

From the 3D bodies: the gaps between the thrower's glove and the opponent's head, trunk
and arms (``pipeline.evaluate.glove_contact``: ``CapsuleProxy``'s volumes), smallest over
the frames around the strike (``OutcomeConfig.window_frames``):

- **landed** when the head or trunk gap is within ``contact_tol_m`` and no larger than the
  arms' gap (the glove got there first);
- **blocked** when only the arms (gloves, forearms, upper arms) are within ``contact_tol_m``;
- **missed** otherwise.

The target region is the one touched (arms -> ``guard``); for a missed punch the nearest
region within ``target_radius_m``, else ``none``.

From the physics stage, when it recorded contacts between the thrower's hand or forearm
and the opponent in those frames, they decide: a head or trunk body touched -> landed,
only arm bodies -> blocked.
"""

from __future__ import annotations

import numpy as np

from pipeline.schema.results import PhysicsResult
from pipeline.stages.analyze.config import OutcomeConfig

_PARTS: dict[str, str] = {
    "head": "head", "neck": "head",
    "pelvis": "body", "spine": "body", "torso": "body", "clavicle": "body", "chest": "body",
    "upper_arm": "arms", "forearm": "arms", "hand": "arms", "lower_arm": "arms",
}  # fmt: skip
"""MuJoCo humanoid body name (without ``p{id}_`` and the side) -> region."""


def body_region(name: str) -> tuple[int, str, str] | None:
    """(person id, side or "", region) of a humanoid body named ``p{id}_[left_|right_]part``;
    None for the world, legs or an unknown name."""
    head, _, rest = name.partition("_")
    if not head.startswith("p") or not head[1:].isdigit():
        return None
    side = ""
    for s in ("left_", "right_"):
        if rest.startswith(s):
            side, rest = s[:-1], rest[len(s) :]
    region = _PARTS.get(rest)
    return (int(head[1:]), side, region) if region else None


def contact_regions(physics: PhysicsResult, attacker: int, hand: str, opponent: int, frames: np.ndarray) -> set[str]:
    """Regions of ``opponent`` touched by ``attacker``'s ``hand`` (hand or forearm body) in
    the video ``frames``, according to the physics stage's recorded contacts."""
    if physics.contact_frame.size == 0:
        return set()
    video = physics.frame_indices[np.clip(physics.contact_frame, 0, physics.frame_indices.shape[0] - 1)]
    sel = np.flatnonzero(np.isin(video, frames))
    out: set[str] = set()
    for c in sel:
        a, b = (body_region(physics.body_names[int(i)]) for i in physics.contact_body[c])
        for me, other in ((a, b), (b, a)):
            if me is None or other is None:
                continue
            if me[0] == attacker and me[1] == hand and me[2] == "arms" and other[0] == opponent:
                out.add(other[2])
    return out


def from_gaps(gaps: dict[str, float], cfg: OutcomeConfig) -> tuple[str, str]:
    """(target, outcome) from the smallest gaps (metres) to ``head``, ``body`` and ``arms``."""
    target_gap = min(gaps["head"], gaps["body"])
    near = "head" if gaps["head"] <= gaps["body"] else "body"
    if target_gap <= cfg.contact_tol_m and target_gap <= gaps["arms"]:
        return near, "landed"
    if gaps["arms"] <= cfg.contact_tol_m:
        return "guard", "blocked"
    best = min(gaps, key=lambda k: gaps[k])
    if gaps[best] <= cfg.target_radius_m:
        return ("guard" if best == "arms" else best), "missed"
    return "none", "missed"


def from_contacts(regions: set[str]) -> tuple[str, str] | None:
    """(target, outcome) from the physics contacts' regions; None when there are none."""
    if "head" in regions:
        return "head", "landed"
    if "body" in regions:
        return "body", "landed"
    if "arms" in regions:
        return "guard", "blocked"
    return None
