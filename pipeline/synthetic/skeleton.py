"""Body proportions, local landmark offsets and analytic two-bone IK.

Segment lengths follow the anthropometric ratios of Drillis & Contini (as tabulated by
Winter, *Biomechanics and Motor Control of Human Movement*): hip height 0.530 H, shank
0.246 H, ankle height 0.039 H, upper arm 0.186 H, forearm 0.146 H, shoulder height
0.818 H. Every joint is placed by forward kinematics from rigid offsets or by two-bone
IK with exact segment lengths, so bone lengths are constant by construction.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from pipeline.schema.joints import COCO17_FEET
from pipeline.synthetic.curves import soft_clamp_max, soft_clamp_min

J: dict[str, int] = {n: i for i, n in enumerate(COCO17_FEET)}
"""Joint name -> index in ``COCO17_FEET``."""

SOLE_HEIGHT_M = 0.02
"""Height of the heel and toe keypoints above the ground while the foot is flat on it (the
keypoints sit on the skin, not on the sole)."""


@dataclass(frozen=True)
class BodyDims:
    """Segment lengths of one person (metres; left and right sides are symmetric)."""

    height_m: float
    thigh_m: float
    shank_m: float
    ankle_height_m: float
    torso_m: float
    neck_m: float
    shoulder_half_m: float
    hip_half_m: float
    upper_arm_m: float
    forearm_m: float
    heel_back_m: float
    toe_fwd_m: float
    head_radius_m: float
    torso_radius_m: float
    limb_radius_m: float

    @property
    def scale(self) -> float:
        """Height relative to a 1.75 m reference person (scales choreography offsets)."""
        return self.height_m / 1.75

    @property
    def leg_m(self) -> float:
        return self.thigh_m + self.shank_m

    @property
    def arm_m(self) -> float:
        return self.upper_arm_m + self.forearm_m

    @property
    def hip_height_m(self) -> float:
        """Hip-joint height when standing straight."""
        return self.ankle_height_m + self.leg_m

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}


def make_body(height_m: float, arm_ratio: float, rng: np.random.Generator) -> BodyDims:
    """Body of the given height with anthropometric ratios, jittered by up to ~2% per segment.

    ``arm_ratio`` scales both arm segments (a rangy boxer has ``> 1``).
    """
    h = float(height_m)

    def jit() -> float:
        return float(1.0 + rng.uniform(-0.02, 0.02))

    ankle = 0.039 * h
    shank = 0.246 * h * jit()
    thigh = 0.530 * h * jit() - ankle - shank  # hip height 0.530 H minus shank and ankle
    torso = 0.288 * h * jit()
    return BodyDims(
        height_m=h,
        thigh_m=thigh,
        shank_m=shank,
        ankle_height_m=ankle,
        torso_m=torso,
        neck_m=0.097 * h,
        shoulder_half_m=0.105 * h * jit(),
        hip_half_m=0.068 * h * jit(),
        upper_arm_m=0.186 * h * arm_ratio * jit(),
        forearm_m=0.146 * h * arm_ratio * jit(),
        heel_back_m=0.030 * h,
        toe_fwd_m=0.115 * h,
        head_radius_m=0.043 * h,
        torso_radius_m=0.063 * h,
        limb_radius_m=0.029 * h,
    )


def face_offsets(body: BodyDims) -> dict[str, np.ndarray]:
    """Face landmarks in the head frame (x forward, y left, z up) around the head centre.

    They lie just outside the head sphere (radius ``head_radius_m``), so the sphere hides
    them from cameras behind the head but not from cameras in front.
    """
    r = body.head_radius_m
    return {
        "nose": np.array([1.25 * r, 0.0, -0.2 * r]),
        "left_eye": np.array([1.0 * r, 0.42 * r, 0.27 * r]),
        "right_eye": np.array([1.0 * r, -0.42 * r, 0.27 * r]),
        "left_ear": np.array([-0.05 * r, 1.1 * r, 0.0]),
        "right_ear": np.array([-0.05 * r, -1.1 * r, 0.0]),
    }


def foot_offsets(body: BodyDims, side: str) -> dict[str, np.ndarray]:
    """Ankle and foot keypoints in the foot frame (origin on the ground under the ankle,
    x along the foot, y left, z up). The big toe is on the medial side."""
    medial = -1.0 if side == "left" else 1.0
    toe = body.toe_fwd_m
    return {
        f"{side}_ankle": np.array([0.0, 0.0, body.ankle_height_m]),
        f"{side}_heel": np.array([-body.heel_back_m, 0.0, SOLE_HEIGHT_M]),
        f"{side}_big_toe": np.array([toe, 0.15 * toe * medial, SOLE_HEIGHT_M]),
        f"{side}_small_toe": np.array([0.78 * toe, -0.25 * toe * medial, SOLE_HEIGHT_M]),
    }


def two_bone_ik(
    root: np.ndarray,
    target: np.ndarray,
    pole: np.ndarray,
    len_a: float,
    len_b: float,
    knee_frac: float = 0.92,
    max_frac: float = 0.985,
) -> tuple[np.ndarray, np.ndarray]:
    """Analytic two-bone IK (shoulder-elbow-wrist, hip-knee-ankle), vectorised over frames.

    Args:
        root: (F, 3) first joint; target: (F, 3) desired end point; pole: (F, 3) direction
            the middle joint bends towards (need not be orthogonal to root->target).
        len_a, len_b: segment lengths (exact in the result).
        knee_frac, max_frac: beyond ``knee_frac * (len_a + len_b)`` the root-to-end distance
            saturates smoothly (C2) towards ``max_frac * (len_a + len_b)``, so an
            out-of-reach target never straightens the limb fully.
    Returns:
        mid (F, 3), end (F, 3). ``end == target`` (to rounding) while the target is within
        ``knee_frac`` of the reach and farther than the minimal fold.
    """
    delta = target - root
    d = np.linalg.norm(delta, axis=-1)
    u = delta / np.maximum(d, 1e-9)[:, None]
    d_max = max_frac * (len_a + len_b)
    d_min = abs(len_a - len_b) + 0.05 * (len_a + len_b)
    d_eff = soft_clamp_max(d, knee_frac * (len_a + len_b), d_max)
    d_eff = soft_clamp_min(d_eff, d_min + 0.05 * (len_a + len_b), d_min)
    x = (len_a**2 - len_b**2 + d_eff**2) / (2.0 * d_eff)
    h = np.sqrt(np.maximum(len_a**2 - x**2, 0.0))
    w = pole - np.sum(pole * u, axis=-1, keepdims=True) * u
    wn = np.linalg.norm(w, axis=-1)
    if np.any(wn < 1e-6):
        bad = int(np.flatnonzero(wn < 1e-6)[0])
        raise ValueError(f"two_bone_ik: pole is parallel to the limb at frame {bad}")
    w = w / wn[:, None]
    mid = root + x[:, None] * u + h[:, None] * w
    end = root + d_eff[:, None] * u
    return mid, end
