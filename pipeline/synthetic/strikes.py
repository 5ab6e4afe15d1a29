"""Aimed strikes of the varied script (``Punch.aim`` other than ``legacy``) and the
defender's guard moves that answer them.

A strike is planned at its strike frame from both trunks (arms are placed afterwards):
the target point (the head sphere's centre, or the middle of the trunk at mid height for
body shots), the direction the glove arrives from (straights: from the shoulder; hooks:
across, from the punching side; uppercuts: from below) and the distance from the target
at which the glove sphere touches the target's volumes (``CapsuleProxy``). The glove is
then sent to that contact point (``land``), two glove radii further out (``block``: the
defender's glove takes the contact point), ``shortfall_m`` further out (``short``), or
at where the head was before the defender started to evade (``slip``, and ``short`` at
the head: the defender pulls back); a short body shot stops ``shortfall_m`` before contact.
A parried punch (``parry``) is aimed to land; ``parry_geometry`` gives the direction its
glove is pushed at the parry's contact: horizontal, across the line from the punching
shoulder to the defender's head at the punch's start, towards the defender's inside (the
glove of his that parries sweeps that way).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.evaluate.glove_contact import body_point, glove_volume, region_volumes
from pipeline.geometry.segments import segment_distance
from pipeline.schema.joints import COCO17_FEET
from pipeline.synthetic.choreo import Punch
from pipeline.synthetic.combos import PARRY_CONTACT_AT, family
from pipeline.synthetic.curves import apply, minjerk
from pipeline.synthetic.skeleton import J

GLOVE_POINT, R_GLOVE_M = glove_volume("left")
GLOVE_PAST_WRIST = float(GLOVE_POINT.split(",")[-1]) - 1.0
"""Glove centre past the wrist, as a fraction of the forearm (``CapsuleProxy``)."""
SLIP_AIM_BEFORE_S = 0.3
"""A punch that is slipped is aimed at the head where it was this long before the strike
(before the evasion started: the defender reads it and moves first)."""
LAND_THROUGH_M = 0.02
"""A punch scripted to land is aimed this far through the contact point (the bodies'
separation then leaves it touching)."""
PARRY_KEEP = 0.3
"""A parried punch (aimed at the head) travels this fraction of the rest of its way out
after the parry's contact: the slap costs the arm its reach as well as its line."""


@dataclass(frozen=True)
class Strike:
    """Plan of one aimed strike at frame ``frame``: ``target`` (3,) world point, ``u`` (3,)
    unit direction of arrival, ``contact_m`` glove-centre distance from ``target`` along
    ``-u`` at contact, ``glove`` (3,) where the attacker's glove centre is sent."""

    frame: int
    target: np.ndarray
    u: np.ndarray
    contact_m: float
    glove: np.ndarray


def frame_at(t_s: np.ndarray, time_s: float) -> int:
    """Nearest frame index of ``time_s`` on the uniform frame clock ``t_s``."""
    return int(np.clip(np.round(time_s * (len(t_s) - 1) / max(t_s[-1], 1e-9)), 0, len(t_s) - 1))


def _target(p: Punch, opp_joints: np.ndarray, f: int) -> tuple[np.ndarray, str]:
    if family(p.kind) == "body":
        mid_hip = body_point(opp_joints[f], "mid:left_hip+right_hip", COCO17_FEET)
        mid_sh = body_point(opp_joints[f], "mid:left_shoulder+right_shoulder", COCO17_FEET)
        return mid_hip + 0.55 * (mid_sh - mid_hip), "body"
    return body_point(opp_joints[f], "mid:left_ear+right_ear", COCO17_FEET), "head"


def _contact_distance(target: np.ndarray, u: np.ndarray, opp: np.ndarray, region: str) -> float:
    """Largest distance ``s`` along ``-u`` from ``target`` at which the glove sphere touches
    the opponent's ``region`` volumes (joints ``opp`` (23, 3) at the strike frame)."""
    s = np.arange(0.8, 0.0, -0.002)
    pts = target[None] - s[:, None] * u[None]
    gap = np.full(s.shape, np.inf)
    for a, b, r in region_volumes()[region]:
        pa, pb = body_point(opp, a, COCO17_FEET), body_point(opp, b, COCO17_FEET)
        gap = np.minimum(gap, segment_distance(pts, pts, pa[None], pb[None]) - r - R_GLOVE_M)
    hit = np.flatnonzero(gap <= 0.0)
    return float(s[hit[0]]) if hit.size else 0.0


def plan_strike(
    p: Punch, t_s: np.ndarray, me_joints: np.ndarray, R_guard: np.ndarray, opp_joints: np.ndarray
) -> Strike:
    """Where ``p``'s glove goes (``me_joints`` / ``opp_joints``: (F, 23, 3) trunk joints of
    the attacker and the defender; ``R_guard`` (F, 3, 3) the attacker's guard frame)."""
    f = frame_at(t_s, p.peak_s)
    target, region = _target(p, opp_joints, f)
    if p.aim in ("slip", "short") and region == "head":  # at the head before it moved
        f_aim = frame_at(t_s, p.peak_s - SLIP_AIM_BEFORE_S)
        target, _ = _target(p, opp_joints, f_aim)
    else:
        f_aim = f
    out = 1.0 if p.hand == "left" else -1.0
    fam = family(p.kind)
    if fam == "hook":
        u = apply(R_guard[f : f + 1], np.array([0.35, -out, 0.0]))[0]
    elif fam == "uppercut":
        u = apply(R_guard[f : f + 1], np.array([0.5, -0.15 * out, 1.0]))[0]
    else:
        u = target - me_joints[f, J[f"{p.hand}_shoulder"]]
    u = u / np.linalg.norm(u)
    s_c = _contact_distance(target, u, opp_joints[f_aim], region)
    short = p.shortfall_m if region == "body" else 0.0
    extra = {
        "land": -LAND_THROUGH_M, "parry": 0.0, "block": 2.0 * R_GLOVE_M - LAND_THROUGH_M,
        "short": short, "slip": 0.0,
    }[p.aim]  # fmt: skip
    return Strike(f, target, u, s_c, target - u * (s_c + extra))


def parry_geometry(p: Punch, t_s: np.ndarray, att_joints: np.ndarray, def_joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(``n`` (3,), ``fwd`` (3,)) of the parried punch ``p`` (``att_joints`` / ``def_joints``:
    (F, 23, 3) trunk joints of the attacker and the defender). ``fwd`` is the horizontal unit
    direction from the punching shoulder to the defender's head at the punch's start; ``n``
    the horizontal unit normal to it the punching glove is pushed along (the attacker's right
    for a left-hand punch, his left for a right-hand one)."""
    f0 = frame_at(t_s, p.t0_s)
    head = body_point(def_joints[f0], "mid:left_ear+right_ear", COCO17_FEET)
    line = head - att_joints[f0, J[f"{p.hand}_shoulder"]]
    line[2] = 0.0
    fwd = line / np.linalg.norm(line)
    left = np.cross(np.array([0.0, 0.0, 1.0]), fwd)
    return (-left if p.hand == "left" else left), fwd


def parried_stroke(t_s: np.ndarray, p: Punch, t_contact_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(F,) profiles of the parried punch ``p`` on the clock ``t_s``, contact at ``t_contact_s``:
    ``reach`` 0 (guard) -> strike -> 0, its ``Punch.profile`` until the contact and then only
    ``PARRY_KEEP`` of the rest of the way out; ``side`` 0 -> 1 -> 0, the sideways push, in
    step with the rest of the way out from the contact (held, back with the fist). The glove
    is thus turned aside at the contact, without slowing down before it."""
    if p.parry is None:
        raise ValueError(f"parried_stroke: punch {p.kind} at {p.t0_s:.3f} s is not parried")
    out = minjerk((t_s - p.t0_s) / p.out_s)
    back = minjerk((t_s - p.t0_s - p.out_s - p.hold_s) / p.back_s)
    out_c = float(minjerk(np.array((t_contact_s - p.t0_s) / p.out_s)))
    past = np.clip((out - out_c) / max(1.0 - out_c, 1e-6), 0.0, 1.0)
    reach_out = np.minimum(out, out_c) + PARRY_KEEP * (1.0 - out_c) * past
    end = out_c + PARRY_KEEP * (1.0 - out_c)
    return reach_out - end * back, past * (1.0 - back)


def parry_sweep(t_s: np.ndarray, p: Punch, t_contact_s: float) -> np.ndarray:
    """(F,) the parrying glove's slap against ``p`` on the clock ``t_s``: a minimum-jerk ramp
    over ``Parry.sweep_s`` in units of ``Parry.sweep_m``, shifted to 0 at the contact
    ``t_contact_s``, which is ``PARRY_CONTACT_AT`` of the way through it in time."""
    if p.parry is None:
        raise ValueError(f"parry_sweep: punch {p.kind} at {p.t0_s:.3f} s is not parried")
    at = np.array(PARRY_CONTACT_AT)
    return minjerk((t_s - t_contact_s) / p.parry.sweep_s + at) - minjerk(at)


def wrist_for_glove(glove: np.ndarray, u: np.ndarray, forearm_m: float) -> np.ndarray:
    """First guess of the wrist that puts the glove centre at ``glove`` with the forearm along ``u``."""
    return glove - u * GLOVE_PAST_WRIST * forearm_m


def glove_centre(joints: np.ndarray, hand: str) -> np.ndarray:
    """(F, 3) glove-sphere centre of ``hand`` in joints (F, 23, 3)."""
    return body_point(joints, GLOVE_POINT.replace("left", hand), COCO17_FEET)


def guard_weight(t_s: np.ndarray, p: Punch) -> np.ndarray:
    """(F,) 0 -> 1 -> 0 weight of a defender's guard move answering ``p``: in place just
    before the strike, held through it, back over 0.2 s."""
    up = minjerk((t_s - (p.t0_s - 0.08)) / max(p.out_s + 0.05, 1e-3))
    down = minjerk((t_s - (p.peak_s + p.hold_s + 0.05)) / 0.2)
    return up - down


def hook_offset(prof: np.ndarray, start_local: np.ndarray, end_local: np.ndarray, out: float, s: float) -> np.ndarray:
    """(F, 3) offset from the guard along a hook's Bezier arc in the guard frame: out to the
    punching side, then across to ``end_local`` (reached at ``prof`` = 1)."""
    c1 = start_local + np.array([0.1, 0.25 * out, -0.02]) * s
    c2 = end_local + np.array([-0.08, 0.28 * out, 0.0]) * s
    return _bezier(prof, start_local, c1, c2, end_local) - start_local


def uppercut_offset(prof: np.ndarray, start_local: np.ndarray, end_local: np.ndarray, s: float) -> np.ndarray:
    """(F, 3) offset along an uppercut's arc: down from the guard, then up into the target."""
    c1 = start_local + np.array([0.02, 0.0, -0.18]) * s
    c2 = end_local + np.array([-0.08, 0.0, -0.22]) * s
    return _bezier(prof, start_local, c1, c2, end_local) - start_local


def _bezier(u: np.ndarray, c0: np.ndarray, c1: np.ndarray, c2: np.ndarray, c3: np.ndarray) -> np.ndarray:
    x = np.clip(u, 0.0, 1.0)[:, None]
    return (1 - x) ** 3 * c0 + 3 * (1 - x) ** 2 * x * c1 + 3 * (1 - x) * x**2 * c2 + x**3 * c3
