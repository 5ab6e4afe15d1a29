"""Forward kinematics of the synthetic persons: trunk, legs and head first, arms second.

Each person is a rigid trunk (hips and shoulders in one frame, rotating about the
mid-hip), a head on top, legs placed by two-bone IK onto planted/swinging feet and arms
placed by two-bone IK onto fist targets (guard, punches, clinch grips). The arm pass
needs both boxers' trunks, because clinch grips are anchored on the opponent's back.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from pipeline.schema.joints import other_side
from pipeline.synthetic.choreo import CLINCH_DISTANCE_M, Choreography, Punch
from pipeline.synthetic.combos import PARRY_BACK_S, PARRY_IN_S, PARRY_LIFT, family, parry_span
from pipeline.synthetic.curves import apply, bump, minjerk, rot_z, rot_zyx, softmin
from pipeline.synthetic.footwork import FeetTrack, StepParams, plan_feet
from pipeline.synthetic.skeleton import BodyDims, J, face_offsets, foot_offsets, two_bone_ik
from pipeline.synthetic.strikes import (
    GLOVE_PAST_WRIST,
    R_GLOVE_M,
    frame_at,
    glove_centre,
    guard_weight,
    hook_offset,
    parried_stroke,
    parry_geometry,
    parry_sweep,
    plan_strike,
    uppercut_offset,
    wrist_for_glove,
)

SIDES = ("left", "right")

# Orthodox stance in the facing frame (x towards the opponent, y left), for a 1.75 m boxer:
# (bladed guard, square clinch) foot positions and foot yaw offsets.
GUARD_FEET_XY = np.array([[0.22, 0.13], [-0.22, -0.15]])
SQUARE_FEET_XY = np.array([[0.09, 0.17], [-0.09, -0.17]])
GUARD_FEET_YAW = np.array([-0.25, -0.9])
SQUARE_FEET_YAW = np.array([-0.2, -0.5])
# Fists in guard, relative to the neck in the facing frame (lead = left).
GUARD_FIST = {"left": np.array([0.30, 0.03, 0.05]), "right": np.array([0.20, -0.09, 0.08])}
MIRROR_Y = np.array([1.0, -1.0, 1.0])
"""Reflects a facing-frame offset in the boxer's own sagittal plane (y -> -y)."""


def guard_fist(side: str, southpaw: bool) -> np.ndarray:
    """(3,) ``side`` fist in guard (``GUARD_FIST``), for a southpaw the mirror of the other one."""
    if not southpaw:
        return GUARD_FIST[side]
    return GUARD_FIST[other_side(side)] * MIRROR_Y


def guard_feet(southpaw: bool) -> tuple[np.ndarray, np.ndarray]:
    """(left, right) foot positions (2, 2) and yaw offsets (2,) of the bladed stance
    (``GUARD_FEET_XY`` / ``GUARD_FEET_YAW``); for a southpaw each foot takes the mirror of the
    other's (right foot in front). The square clinch stance is the same for both."""
    if not southpaw:
        return GUARD_FEET_XY, GUARD_FEET_YAW
    return GUARD_FEET_XY[::-1] * MIRROR_Y[:2], -GUARD_FEET_YAW[::-1]


# Lead hook: cubic Bezier control points (facing frame, relative to the neck, 1.75 m boxer)
# from the guard around to in front of the chin line; no cusp, so the fist keeps moving.
HOOK_CTRL = np.array([GUARD_FIST["left"], [0.42, 0.30, 0.02], [0.60, 0.22, 0.02], [0.55, -0.05, 0.05]])
TWIST_RAD = {
    "jab": -0.12,
    "cross": 0.65,
    "lead_hook": -0.5,
    "rear_hook": 0.55,
    "lead_uppercut": -0.3,
    "rear_uppercut": 0.4,
    "body_jab": -0.12,
    "body_cross": 0.6,
}
"""Trunk rotation added at full extension of each punch kind."""
BODY_SHOT_DIP_M = 0.08
"""A body shot is thrown with bent knees: the pelvis drops this much at full extension
(1.75 m boxer) and the trunk leans 0.1 rad further forward."""
OPEN_GUARD_M = {"head": np.array([-0.08, 0.12, -0.2]), "body": np.array([-0.05, 0.15, 0.12])}
"""Where a defender's fists go (facing frame, y outwards, 1.75 m boxer) while a punch
scripted to land (or to be slipped) reaches his head (down and out of its way) or his
body (up and out: the elbows leave the ribs)."""
PARRY_REACH = 0.9
"""A parry meets the punch where the parrying glove is within this fraction of the
defender's arm (shoulder to glove centre) from his shoulder (the arm IK follows exactly up
to 0.92 of it)."""
PARRY_OVERLAP_M = 0.05
"""The parrying glove is aimed this far into the punching glove at the contact (the bodies'
separation then leaves them touching)."""
PARRY_AHEAD_RAD = -0.3
"""At a parry's contact the parrying glove touches the punching glove from the side, turned
this far (rad) from the sideways direction towards the defender (negative: towards the
attacker), so that a frame later the punching glove is past it, not running into it."""


@dataclass(frozen=True)
class Trunk:
    """Trunk-level pose of one person over F frames (arms not yet placed).

    Fields: joints (F, 23, 3) with legs, hips, shoulders and face set (arm joints zero);
    pelvis (F, 3) mid-hip; neck (F, 3) mid-shoulder; head (F, 3) head-sphere centre;
    R_trunk (F, 3, 3) trunk orientation (x forward, y left, z up); R_guard (F, 3, 3) the
    facing frame tilted with the trunk (guard positions live there); feet: FeetTrack.
    """

    joints: np.ndarray
    pelvis: np.ndarray
    neck: np.ndarray
    head: np.ndarray
    R_trunk: np.ndarray
    R_guard: np.ndarray
    feet: FeetTrack


def build_trunk(
    body: BodyDims,
    centre_xy: np.ndarray,
    facing: np.ndarray,
    trunk_yaw_offset: np.ndarray,
    pitch: np.ndarray,
    roll: np.ndarray,
    crouch_m: np.ndarray,
    feet_xy_local: np.ndarray,
    feet_yaw_offset: np.ndarray,
    step: StepParams,
    fps: float,
) -> Trunk:
    """Place trunk, head and legs. ``feet_xy_local`` (F, 2, 2) and ``feet_yaw_offset`` (F, 2)
    give the ideal foot placement in the facing frame; the feet follow by planted steps.

    Raises ``ValueError`` if a planted foot ends up out of reach of its hip (a scripting bug).
    """
    n = facing.shape[0]
    Rf = rot_z(facing)
    ideal_xy = centre_xy[:, None, :] + np.einsum("fij,fkj->fki", Rf[:, :2, :2], feet_xy_local)
    ideal_yaw = facing[:, None] + feet_yaw_offset
    feet = plan_feet(ideal_xy, ideal_yaw, fps, step)
    # The pelvis sits over the stance centre implied by the actual feet (it shifts with a
    # swinging foot, like a weight transfer); smooth because the feet are.
    implied = feet.origin_m[:, :, :2] - np.einsum("fij,fkj->fki", Rf[:, :2, :2], feet_xy_local)
    pelvis_xy = implied.mean(axis=1)

    R = rot_zyx(facing + trunk_yaw_offset, pitch, roll)
    hip_off = [apply(R, np.array([0.0, s * body.hip_half_m, 0.0])) for s in (1.0, -1.0)]
    ankle = feet.origin_m + np.array([0.0, 0.0, body.ankle_height_m])
    reach = 0.985 * body.leg_m
    z_caps = [body.hip_height_m - crouch_m]
    for k in range(2):
        dxy = np.linalg.norm(pelvis_xy + hip_off[k][:, :2] - ankle[:, k, :2], axis=1)
        if np.any(dxy > reach - 0.02):
            f = int(np.argmax(dxy))
            raise ValueError(f"synthetic motion: {SIDES[k]} foot out of reach at frame {f} ({dxy[f]:.3f} m)")
        z_caps.append(ankle[:, k, 2] - hip_off[k][:, 2] + np.sqrt(reach**2 - dxy**2))
    pelvis = np.concatenate([pelvis_xy, softmin(z_caps, 0.01)[:, None]], axis=1)

    joints = np.zeros((n, len(J), 3))
    neck = pelvis + apply(R, np.array([0.0, 0.0, body.torso_m]))
    for s, side in ((1.0, "left"), (-1.0, "right")):
        joints[:, J[f"{side}_shoulder"]] = neck + apply(R, np.array([0.0, s * body.shoulder_half_m, 0.0]))
    joints[:, J["left_hip"]] = pelvis + hip_off[0]
    joints[:, J["right_hip"]] = pelvis + hip_off[1]

    head = neck + apply(R, np.array([0.01 * body.height_m, 0.0, body.neck_m]))
    R_head = rot_zyx(facing, 0.1 + 0.3 * pitch, 0.6 * roll)
    for name, off in face_offsets(body).items():
        joints[:, J[name]] = head + apply(R_head, off)

    trunk_fwd = R[:, :, 0] * np.array([1.0, 1.0, 0.0])
    for k, side in enumerate(SIDES):
        Rfoot = rot_z(feet.yaw[:, k])
        for name, off in foot_offsets(body, side).items():
            joints[:, J[name]] = feet.origin_m[:, k] + apply(Rfoot, off)
        out = 1.0 if side == "left" else -1.0
        pole = Rfoot[:, :, 0] + 0.5 * trunk_fwd + 0.2 * out * Rfoot[:, :, 1]
        knee, ank = two_bone_ik(
            joints[:, J[f"{side}_hip"]],
            ankle[:, k],
            pole,
            body.thigh_m,
            body.shank_m,
            knee_frac=0.99,
            max_frac=0.998,
        )
        joints[:, J[f"{side}_knee"]] = knee
        joints[:, J[f"{side}_ankle"]] = ankle[:, k]  # == ank (within reach by construction)
        if np.max(np.abs(ank - ankle[:, k])) > 1e-9:
            raise ValueError(f"synthetic motion: {side} ankle IK left the planted foot")
    R_guard = rot_zyx(facing, pitch, roll)
    return Trunk(joints, pelvis, neck, head, R, R_guard, feet)


def place_arm(
    joints: np.ndarray, body: BodyDims, side: str, wrist_target: np.ndarray, elbow_pole: np.ndarray
) -> None:
    """Two-bone IK of one arm onto ``wrist_target`` (F, 3); writes elbow and wrist in place."""
    elbow, wrist = two_bone_ik(
        joints[:, J[f"{side}_shoulder"]], wrist_target, elbow_pole, body.upper_arm_m, body.forearm_m
    )
    joints[:, J[f"{side}_elbow"]] = elbow
    joints[:, J[f"{side}_wrist"]] = wrist


def boxer_scalars(ch: Choreography, person: int, body: BodyDims) -> dict[str, np.ndarray]:
    """Trunk angles and crouch of one boxer from stance, punches, slips and clinch."""
    it = ch.boxers[person]
    t = ch.t_s
    q = it.square
    # A southpaw turns the other way: his bladed stance and each punch's twist are mirrored;
    # the square clinch stance is not (both boxers lean and turn alike so that the heads pass).
    turn = -1.0 if ch.southpaw[person] else 1.0
    yaw_off = -0.5 * turn * (1.0 - q) - 0.12 * q
    pitch = 0.12 + 0.18 * it.clinch_w
    roll = -0.15 * it.clinch_w  # lean to the own left: the heads pass each other
    crouch = (0.06 + 0.02 * it.clinch_w) * body.scale + 0.012 * np.sin(2 * np.pi * 1.8 * t + 1.3 * person)
    for p in ch.punches:
        if p.person == person:
            yaw_off = yaw_off + turn * TWIST_RAD[p.kind] * p.profile(t)
            if p.kind.startswith("body"):
                crouch = crouch + BODY_SHOT_DIP_M * body.scale * p.profile(t)
                pitch = pitch + 0.1 * p.profile(t)
    for s in ch.slips:
        if s.person == person:
            b = bump(t, s.t0_s, s.duration_s)
            roll = roll - s.roll_rad * s.side * b
            pitch = pitch + s.pitch_rad * b
            crouch = crouch + s.depth_m * b
    return {"yaw_off": yaw_off, "pitch": pitch, "roll": roll, "crouch": crouch}


def boxer_trunk(ch: Choreography, person: int, body: BodyDims, fps: float) -> Trunk:
    """Trunk, head and legs of one boxer: orthodox (or southpaw, ``Choreography.southpaw``)
    stance blending into a square clinch stance, footwork by planted steps (``StepParams``
    defaults)."""
    it = ch.boxers[person]
    sc = boxer_scalars(ch, person, body)
    q = it.square[:, None]
    stance_xy, stance_yaw = guard_feet(ch.southpaw[person])
    feet_xy = ((1 - q)[:, :, None] * stance_xy + q[:, :, None] * SQUARE_FEET_XY) * body.scale
    feet_yaw = (1 - q) * stance_yaw + q * SQUARE_FEET_YAW
    return build_trunk(
        body,
        it.centre_xy,
        it.facing,
        sc["yaw_off"],
        sc["pitch"],
        sc["roll"],
        sc["crouch"],
        feet_xy,
        feet_yaw,
        StepParams(),
        fps,
    )


def _bezier(u: np.ndarray) -> np.ndarray:
    c = HOOK_CTRL
    u = u[:, None]
    return (1 - u) ** 3 * c[0] + 3 * (1 - u) ** 2 * u * c[1] + 3 * (1 - u) * u**2 * c[2] + u**3 * c[3]


_U = np.linspace(0.0, 1.0, 257)
_ARC = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(_bezier(_U), axis=0), axis=1))])
_ARC_TO_U = PchipInterpolator(_ARC / _ARC[-1], _U)
HOOK_PATH_M = float(_ARC[-1])
"""Length of the hook path for a 1.75 m boxer."""


def hook_path(arc_frac: np.ndarray) -> np.ndarray:
    """(F,) fraction of the hook's arc length -> (F, 3) point on it (C1 in the fraction)."""
    return _bezier(_ARC_TO_U(np.clip(arc_frac, 0.0, 1.0)))


def boxer_arms(
    ch: Choreography,
    person: int,
    body: BodyDims,
    me: Trunk,
    opp: Trunk,
    opp_body: BodyDims,
    opp_arms: np.ndarray | None = None,
    contacts: dict[int, int] | None = None,
) -> np.ndarray:
    """Joints (F, 23, 3) of a boxer with arms placed (guard, punches, clinch grips).

    Parries (``Punch.parry``) need ``contacts`` (row of ``ch.punches`` -> contact frame,
    ``parry_contacts``) and ``opp_arms`` (F, 23, 3), the opponent's joints with his arms
    placed: without them parried punches fly unparried and the defender's gloves stay in
    guard (the first of ``make_bout``'s two passes)."""
    t = ch.t_s
    joints = me.joints.copy()
    s = body.scale
    w = ch.boxers[person].clinch_w[:, None]
    grips = {  # over the opponent's right shoulder (lead) / under his left arm (rear)
        "left": opp.neck + apply(opp.R_trunk, np.array([-0.10, -0.13, -0.04]) * opp_body.scale),
        "right": opp.pelvis + apply(opp.R_trunk, np.array([-0.10, 0.13, 0.20]) * opp_body.scale),
    }
    gap = np.linalg.norm(ch.boxers[0].centre_xy - ch.boxers[1].centre_xy, axis=1)
    tight = 0.5 + 0.5 * minjerk((gap - CLINCH_DISTANCE_M) / 0.8)
    for side in SIDES:
        out = 1.0 if side == "left" else -1.0
        guard = np.tile(guard_fist(side, ch.southpaw[person]) * s, (len(t), 1))
        guard[:, 0] *= tight  # at close range the fists are pulled in towards the face
        target = me.neck + apply(me.R_guard, guard)
        pole = apply(me.R_guard, np.array([-0.2, 0.35 * out, -1.0]))
        shoulder = joints[:, J[f"{side}_shoulder"]]
        punches = [(k, p) for k, p in enumerate(ch.punches) if p.person == person and p.hand == side]
        aimed: list[tuple[np.ndarray, np.ndarray, int]] = []  # (weight (F,), glove centre (3,), frame)
        for k, p in punches:
            prof = p.profile(t)[:, None]
            fp = frame_at(t, p.t0_s + p.out_s)
            if p.aim != "legacy":
                f_c = None if contacts is None else contacts.get(k)
                target, pole = _aimed_punch(p, prof, t, body, me, opp, target, pole, aimed, f_c)
            elif p.kind == "lead_hook":
                # Horizontal arc in the facing frame, travelled at arc-length rate ``prof``.
                local = hook_path(prof[:, 0]) - HOOK_CTRL[0]  # a left hook: a right one is its mirror
                target = target + apply(me.R_guard, local * (s if side == "left" else s * MIRROR_Y))
                pole = pole + 2.5 * prof * apply(me.R_guard, np.array([0.0, out, 0.3]))
            else:
                aim = opp.head[frame_at(t, p.t0_s)] - shoulder[fp]
                dist = float(np.linalg.norm(aim))
                # Full extension, or stop at the opponent's face when he is closer.
                reach = float(np.clip(dist - 0.12, 0.3 * body.arm_m, 0.9 * body.arm_m))
                strike = shoulder[fp] + aim / dist * reach
                target = target + prof * (strike - target)
        # Entering/leaving the grip the hand goes around the opponent, not through him: the
        # lead hand over his shoulder and the rear hand under his arm, so the arms pass
        # each other on the sides they grip from (``separate_persons`` keeps a limb on the
        # side of another limb it first meets).
        parried = (opp_arms, contacts) if opp_arms is not None and contacts is not None else None
        target = _guard_moves(ch, person, side, body, me, opp, target, aimed, parried)
        detour = 4.0 * w * (1 - w) * apply(me.R_guard, np.array([0.0, 0.3 * out, 0.15 * out]) * s)
        target = (1 - w) * target + w * grips[side] + detour
        pole = (1 - w) * pole + w * apply(me.R_guard, np.array([0.0, out, -0.3]))
        place_arm(joints, body, side, target, pole)
        for _ in range(2 if aimed else 0):
            # The glove sits past the wrist along the forearm the IK chose: move the wrist
            # target until the glove is where the strike (or block) wants it.
            g = glove_centre(joints, side)
            for weight, want, f in aimed:
                target = target + weight[:, None] * (want - g[f])
            place_arm(joints, body, side, target, pole)
    return joints


def _aimed_punch(
    p: Punch,
    prof: np.ndarray,
    t: np.ndarray,
    body: BodyDims,
    me: Trunk,
    opp: Trunk,
    target: np.ndarray,
    pole: np.ndarray,
    aimed: list[tuple[np.ndarray, np.ndarray, int]],
    contact: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Wrist target and elbow pole with an aimed punch (``pipeline.synthetic.strikes``) added;
    a parried one is turned aside from the frame ``contact`` on (unparried without it)."""
    st = plan_strike(p, t, me.joints, me.R_guard, opp.joints)
    wrist = wrist_for_glove(st.glove, st.u, body.forearm_m)
    fam = family(p.kind)
    out = 1.0 if p.hand == "left" else -1.0
    f = st.frame
    if fam in ("hook", "uppercut"):
        Rt = me.R_guard[f].T
        start, end = Rt @ (target[f] - me.neck[f]), Rt @ (wrist - me.neck[f])
        if fam == "hook":
            local = hook_offset(prof[:, 0], start, end, out, body.scale)
            pole = pole + 2.5 * prof * apply(me.R_guard, np.array([0.0, out, 0.3]))
        else:
            local = uppercut_offset(prof[:, 0], start, end, body.scale)
        target = target + apply(me.R_guard, local)
    elif p.parry is not None and contact is not None:  # turned aside (no glove correction: it misses)
        n, _ = parry_geometry(p, t, me.joints, opp.joints)
        reach, side = parried_stroke(t, p, float(t[contact]))
        shift = p.parry.deflect_m * (n + np.array([0.0, 0.0, PARRY_LIFT]))
        return target + reach[:, None] * (wrist - target) + side[:, None] * shift, pole
    else:
        target = target + prof * (wrist - target)
    if not p.feint:
        aimed.append((prof[:, 0], st.glove, f))
    return target, pole


def _guard_moves(
    ch: Choreography,
    person: int,
    side: str,
    body: BodyDims,
    me: Trunk,
    opp: Trunk,
    target: np.ndarray,
    aimed: list[tuple[np.ndarray, np.ndarray, int]],
    parried: tuple[np.ndarray, dict[int, int]] | None,
) -> np.ndarray:
    """The defender's ``side`` fist answering the opponent's aimed punches: onto the contact
    point of a punch scripted to be blocked (the hand on the side it arrives on: opposite
    the punching hand), out of the way of one scripted to land or to be slipped (both hands),
    across the way of one scripted to be parried (that same hand; ``_parry_move``, given
    ``parried`` = (the opponent's joints with arms, the contact frames)."""
    t = ch.t_s
    out = 1.0 if side == "left" else -1.0
    for k, p in enumerate(ch.punches):
        if p.person == person or p.aim not in ("block", "land", "slip", "parry") or p.feint:
            continue
        if p.aim == "parry":
            if side != p.hand and parried is not None and k in parried[1]:
                target = _parry_move(p, t, body, me, opp, parried[0], parried[1][k], side, target, aimed)
            continue
        weight = guard_weight(t, p)
        if p.aim in ("land", "slip"):
            off = OPEN_GUARD_M["body" if p.kind.startswith("body") else "head"] * np.array([1.0, out, 1.0])
            target = target + weight[:, None] * apply(me.R_guard, off * body.scale)
            continue
        if side == p.hand or p.kind.endswith("uppercut") or p.kind.startswith("body"):
            continue  # the attacker's left arrives on the defender's right, and vice versa
        st = plan_strike(p, t, opp.joints, opp.R_guard, me.joints)
        spot = st.target - st.u * st.contact_m
        shoulder = me.joints[st.frame, J[f"{side}_shoulder"]]
        d = (spot - shoulder) / np.linalg.norm(spot - shoulder)
        target = target + weight[:, None] * (wrist_for_glove(spot, d, body.forearm_m) - target)
        aimed.append((weight, spot, st.frame))
    return target


def _parry_move(
    p: Punch,
    t: np.ndarray,
    body: BodyDims,
    me: Trunk,
    opp: Trunk,
    opp_arms: np.ndarray,
    f_c: int,
    side: str,
    target: np.ndarray,
    aimed: list[tuple[np.ndarray, np.ndarray, int]],
) -> np.ndarray:
    """Wrist target of the defender's ``side`` glove parrying ``p``: from the guard to the start
    of a sideways slap of ``Parry.sweep_m`` along the direction the punch is pushed, onto the
    punching glove (``opp_arms``) at the contact frame ``f_c``, back to the guard."""
    if p.parry is None:
        raise ValueError(f"_parry_move: punch {p.kind} at {p.t0_s:.3f} s is not parried")
    n, fwd = parry_geometry(p, t, opp.joints, me.joints)
    t_c = float(t[f_c])
    sweep = parry_sweep(t, p, t_c)
    contact = _parry_point(glove_centre(opp_arms, p.hand)[f_c], n, fwd)
    glove = contact[None] + (sweep * p.parry.sweep_m)[:, None] * n[None]
    lo, hi = parry_span(p, t_c)
    weight = minjerk((t - lo) / PARRY_IN_S) - minjerk((t - hi + PARRY_BACK_S) / PARRY_BACK_S)
    d = glove - me.joints[:, J[f"{side}_shoulder"]]
    wrist = wrist_for_glove(glove, d / np.linalg.norm(d, axis=1, keepdims=True), body.forearm_m)
    aimed.append((weight, contact, f_c))
    return target + weight[:, None] * (wrist - target)


def _parry_point(punch_glove: np.ndarray, n: np.ndarray, fwd: np.ndarray) -> np.ndarray:
    """(..., 3) where the parrying glove's centre meets the punching glove's ``punch_glove``
    (``PARRY_AHEAD_RAD``, ``PARRY_OVERLAP_M``; ``n`` and ``fwd`` from ``parry_geometry``)."""
    side_dir = -n * np.cos(PARRY_AHEAD_RAD) + fwd * np.sin(PARRY_AHEAD_RAD)
    return punch_glove + (2.0 * R_GLOVE_M - PARRY_OVERLAP_M) * side_dir


def parry_contacts(
    ch: Choreography, joints: list[np.ndarray], trunks: list[Trunk], bodies: list[BodyDims]
) -> dict[int, int]:
    """Row of ``ch.punches`` -> contact frame of every parried punch, from the first pass
    (``joints``: both boxers' (F, 23, 3), punches unparried): the first frame from
    ``Parry.at_frac`` of its way out on at which the parrying glove would be within
    ``PARRY_REACH`` of the defender's arm, two frames before the strike at the latest; where
    none is, the frame before the strike at which it comes nearest (it may fall short)."""
    t = ch.t_s
    out: dict[int, int] = {}
    for k, p in enumerate(ch.punches):
        if p.parry is None:
            continue
        a, d = p.person, 1 - p.person
        side = other_side(p.hand)
        n, fwd = parry_geometry(p, t, trunks[a].joints, trunks[d].joints)
        start, first, peak = frame_at(t, p.t0_s), frame_at(t, p.parry_s), frame_at(t, p.peak_s)
        rows = np.arange(start + 1, max(peak, start + 2))
        point = _parry_point(glove_centre(joints[a][rows], p.hand), n, fwd)
        arm = bodies[d].upper_arm_m + bodies[d].forearm_m * (1.0 + GLOVE_PAST_WRIST)
        ratio = np.linalg.norm(point - trunks[d].joints[rows, J[f"{side}_shoulder"]], axis=1) / arm
        ok = rows[(ratio <= PARRY_REACH) & (rows >= first) & (rows <= peak - 2)]
        out[k] = int(ok[0]) if ok.size else int(rows[np.argmin(ratio)])
    return out


def punch_peak_speeds(
    joints: np.ndarray, punches: tuple[Punch, ...], person: int, t_s: np.ndarray, fps: float
) -> list[float]:
    """Peak wrist speed (m/s, finite differences) within each punch of ``person``."""
    out = []
    for p in punches:
        if p.person != person:
            continue
        w = joints[:, J[f"{p.hand}_wrist"]]
        v = np.linalg.norm(np.diff(w, axis=0), axis=1) * fps
        sel = (t_s[:-1] >= p.t0_s - 0.02) & (t_s[:-1] <= p.end_s)
        out.append(float(v[sel].max()) if np.any(sel) else 0.0)
    return out
