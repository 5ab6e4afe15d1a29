"""A bystander walking a small loop outside the camera circle (behind one camera), so only
the cameras on the far side of the ring see it."""

from __future__ import annotations

import numpy as np

from pipeline.synthetic.curves import apply
from pipeline.synthetic.footwork import StepParams
from pipeline.synthetic.motion import SIDES, build_trunk, place_arm
from pipeline.synthetic.skeleton import BodyDims, J

WALK_SPEED_MPS = 0.9
WALK_STEP = StepParams(swing_s=0.36, double_support_s=0.1, trigger_m=0.03, lift_m=0.07, land_ahead_s=0.23)


def walker_joints(
    body: BodyDims,
    loop_centre_xy: np.ndarray,
    loop_radius_m: float,
    phase: float,
    t_s: np.ndarray,
    fps: float,
) -> np.ndarray:
    """Joints (F, 23, 3) of a person walking counter-clockwise around a circle (centre
    ``loop_centre_xy``, radius ``loop_radius_m``), starting at angle ``phase``. A closed
    loop keeps the heading smooth (no turn-on-the-spot) and the walker in one place for
    bouts of any length."""
    ang = phase + WALK_SPEED_MPS * t_s / loop_radius_m
    centre = loop_centre_xy + loop_radius_m * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    heading = ang + 0.5 * np.pi
    n = t_s.shape[0]
    feet_xy = np.broadcast_to(np.array([[0.0, 0.1], [0.0, -0.1]]) * body.scale, (n, 2, 2)).copy()
    zeros = np.zeros(n)
    tr = build_trunk(
        body,
        centre,
        heading,
        zeros,
        np.full(n, 0.04),
        zeros,
        np.full(n, 0.01),
        feet_xy,
        np.zeros((n, 2)),
        WALK_STEP,
        fps,
    )
    joints = tr.joints.copy()
    # Arms swing against the legs: driven by the feet's fore-aft separation (C1 like the feet).
    fwd = tr.R_trunk[:, :2, 0]
    sep = np.einsum("fi,fi->f", tr.feet.origin_m[:, 1, :2] - tr.feet.origin_m[:, 0, :2], fwd)
    for k, side in enumerate(SIDES):
        out = 1.0 if side == "left" else -1.0
        swing = (0.35 if k == 0 else -0.35) * np.tanh(sep / 0.5) * body.arm_m
        local = np.stack([swing, np.full(n, 0.07 * out), np.full(n, -0.95 * body.arm_m)], axis=1)
        target = joints[:, J[f"{side}_shoulder"]] + apply(tr.R_trunk, local)
        pole = apply(tr.R_trunk, np.array([-1.0, 0.3 * out, 0.0]))
        place_arm(joints, body, side, target, pole)
    return joints
