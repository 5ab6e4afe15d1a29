"""The internal joint set: COCO-17, optionally extended with six foot points.

The foot points follow COCO-WholeBody's order (and anny's COCO regressor): for each
foot the big toe, the small toe and the heel. A 2D source that provides only some of
them (BlazePose gives heel and "foot index" ~ big toe, but no small toe) marks the
others invalid; a source without feet (MoveNet, COCO-18 OpenPose) uses ``COCO17``.

See ``pipeline/schema/CONVENTIONS.md`` for units and frames.
"""

from __future__ import annotations

import numpy as np

COCO17: tuple[str, ...] = (
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
)

FEET6: tuple[str, ...] = (
    "left_big_toe",
    "left_small_toe",
    "left_heel",
    "right_big_toe",
    "right_small_toe",
    "right_heel",
)

COCO17_FEET: tuple[str, ...] = COCO17 + FEET6
"""The full internal joint set (23 joints)."""

JOINT_SETS: dict[str, tuple[str, ...]] = {"coco17": COCO17, "coco17_feet": COCO17_FEET}

# Limbs scored by PCP on Campus/Shelf-style evaluation (10 limbs for COCO joints).
PCP_LIMBS: tuple[tuple[str, str], ...] = (
    ("left_shoulder", "left_elbow"),
    ("left_elbow", "left_wrist"),
    ("right_shoulder", "right_elbow"),
    ("right_elbow", "right_wrist"),
    ("left_hip", "left_knee"),
    ("left_knee", "left_ankle"),
    ("right_hip", "right_knee"),
    ("right_knee", "right_ankle"),
    ("left_shoulder", "right_shoulder"),
    ("left_hip", "right_hip"),
)

# The PCP limbs plus both torso sides: the segments whose lengths are (nearly) pose
# independent (shape initialisation, re-identification, capsule proxies).
BODY_LIMBS: tuple[tuple[str, str], ...] = PCP_LIMBS + (("left_shoulder", "left_hip"), ("right_shoulder", "right_hip"))

# Bones used for drawing and for bone-length consistency.
BONES: tuple[tuple[str, str], ...] = (
    ("nose", "left_eye"),
    ("nose", "right_eye"),
    ("left_eye", "left_ear"),
    ("right_eye", "right_ear"),
    ("left_shoulder", "right_shoulder"),
    ("left_shoulder", "left_elbow"),
    ("left_elbow", "left_wrist"),
    ("right_shoulder", "right_elbow"),
    ("right_elbow", "right_wrist"),
    ("left_shoulder", "left_hip"),
    ("right_shoulder", "right_hip"),
    ("left_hip", "right_hip"),
    ("left_hip", "left_knee"),
    ("left_knee", "left_ankle"),
    ("right_hip", "right_knee"),
    ("right_knee", "right_ankle"),
    ("left_ankle", "left_heel"),
    ("left_ankle", "left_big_toe"),
    ("left_ankle", "left_small_toe"),
    ("right_ankle", "right_heel"),
    ("right_ankle", "right_big_toe"),
    ("right_ankle", "right_small_toe"),
)

# Rigid bones whose length must not change over time (face bones excluded: the
# nose/eye/ear detections are too close to each other to be informative).
RIGID_BONES: tuple[tuple[str, str], ...] = tuple(b for b in BONES if "eye" not in b[0] + b[1] and "nose" not in b[0])

FOOT_JOINTS: tuple[str, ...] = ("left_ankle", "right_ankle") + FEET6


def bone_indices(names: tuple[str, ...], bones: tuple[tuple[str, str], ...] = BONES) -> list[tuple[int, int]]:
    """Index pairs of the bones whose both ends are in ``names``."""
    return [(names.index(a), names.index(b)) for a, b in bones if a in names and b in names]


def flip_pairs(names: tuple[str, ...]) -> list[tuple[int, int]]:
    """Index pairs (left, right) for horizontal flips and left/right checks."""
    out = []
    for i, n in enumerate(names):
        if n.startswith("left_"):
            r = "right_" + n[len("left_") :]
            if r in names:
                out.append((i, names.index(r)))
    return out


def other_side(side: str) -> str:
    """``"right"`` for ``"left"`` and ``"left"`` for ``"right"`` (a hand, a foot, a joint's side);
    ``ValueError`` for anything else."""
    if side not in ("left", "right"):
        raise ValueError(f"side must be 'left' or 'right', got {side!r}")
    return "right" if side == "left" else "left"


def mirror_joints(xyz: np.ndarray, names: tuple[str, ...] = COCO17_FEET) -> np.ndarray:
    """Mirror image of (..., len(names), 3) joints: x -> -x and every ``left_*`` joint
    exchanged with its ``right_*`` twin (``flip_pairs``); a new array of the same dtype."""
    order = np.arange(len(names))
    for i, j in flip_pairs(names):
        order[i], order[j] = j, i
    out = np.asarray(xyz)[..., order, :].copy()
    out[..., 0] *= -1
    return out
