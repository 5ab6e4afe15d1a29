"""Ground-truth events of a synthetic bout, recorded from its script.

Every scripted punch (feints apart) becomes a labelled punch:

- athlete, hand, type: from the script (``body_jab`` / ``body_cross`` are ``body_shot``);
- start / peak / end frame: the frames nearest the fist leaving the guard, the strike
  (full extension: the end of the fist's outward stroke) and the fist back in the guard.
  The script's strike is when the stroke reaches its strike point; a strike point out of
  the arm's reach is never reached: the arm straightens (``FULL_EXTENSION``) before and
  the fist stops there, so the strike frame is the first frame of the straight-arm run
  before the scripted strike at which the glove has stopped (``strike_frame``);
- peak speed: the ground-truth wrist's peak speed (``SyntheticBout.punch_peak_speed_mps``);
- target: the region the script aims at (head, or body for body shots);
- outcome: what the glove touches on the ground-truth bodies over the strike's frames
  (the strike frame - 1 .. + 2, the hold): ``landed`` when the glove sphere is within
  ``CONTACT_TOL_M`` of the opponent's head or trunk and no farther from them than from
  his arms; ``blocked`` when it is within ``CONTACT_TOL_M`` of his arms or gloves only;
  ``missed`` otherwise. The volumes are ``CapsuleProxy``'s, those the bout's bodies are
  separated with, so a touch is a gap of ~0. The script intends an outcome for every
  varied punch (``Punch.aim``: land, block, slip, short) and shapes the motion for it
  (the defender's guard opens, blocks, or the head slips or ducks); ``intent`` keeps
  that, and where the bodies disagree (a slipped punch that grazes the guard) the contact
  on the bodies wins.

Parries (``SyntheticConfig.parry_prob``): a jab or cross scripted to be parried has intent
``parry`` and its outcome from the contact, as every punch: its glove is pushed sideways and
stops short, clear of the head and trunk, so ``missed``, or ``blocked`` where it still
touches the defender's gloves or arms around the strike (the strike a frame or two after the
parry's contact, or the glove brushing his other glove). The parry itself is a row of
``parry_*`` when the bodies show it: the defender's glove on the side the punch arrives on
within ``CONTACT_TOL_M`` of the punching glove or forearm between the punch's start and its
strike; its frame is the first such frame (the contact). A parry whose glove fell short
(out of the defender's reach) has intent ``parry`` and no row.

Feints, evasions (slips: sideways, ducks: down; with the punch they answer) and the clinch
frames (the script's clinch grip weight >= 0.5) are recorded too. None of this comes from
the analytics stage.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.evaluate.glove_contact import glove_gaps
from pipeline.evaluate.physics_metrics import CapsuleProxy
from pipeline.geometry.segments import segment_distance
from pipeline.schema.analytics import EVADE_KINDS, HANDS, OUTCOMES, PUNCH_TYPES, TARGETS
from pipeline.schema.base import check_array
from pipeline.schema.joints import COCO17_FEET, other_side
from pipeline.synthetic.choreo import Choreography, Punch
from pipeline.synthetic.strikes import R_GLOVE_M, frame_at, glove_centre

CONTACT_TOL_M = 0.025
"""A glove within this of a volume touches it (the bodies' separation leaves touching
volumes 2-20 mm apart: its smoothed rounds aim 2 cm out)."""
CLINCH_GRIP_MIN = 0.5
"""Frames whose scripted clinch grip weight is at least this are clinch frames."""
INTENTS: tuple[str, ...] = ("legacy", "land", "block", "slip", "short", "parry")
R_FOREARM_M = next(r for a, b, r in CapsuleProxy().segments if (a, b) == ("left_elbow", "left_wrist"))
"""Radius (m) of ``CapsuleProxy``'s forearm capsule."""
FULL_EXTENSION = 0.95
"""Shoulder-to-wrist distance, as a fraction of the arm's length, of a straight arm (the
arm IK follows targets within 0.92 of the arm and saturates towards 0.985 beyond; the
bodies' separation can pull a straight arm back a little)."""
STOPPED_FRAC = 0.25
"""A glove slower than this fraction of its punch's peak speed has stopped."""


def strike_frame(xyz_m: np.ndarray, person: int, hand: str, start: int, peak: int) -> int:
    """The frame the fist arrives: ``peak`` (the scripted strike frame), unless ``person``'s
    ``hand`` arm is straight (extension >= ``FULL_EXTENSION`` on the joints ``xyz_m``
    (frames, 2, 23, 3)) from an earlier frame through ``peak``: then the first frame of
    that run at which the glove is slower than ``STOPPED_FRAC`` of its peak speed since
    ``start`` (a straightened arm still sweeping round is still on its way)."""
    j = {k: COCO17_FEET.index(f"{hand}_{k}") for k in ("shoulder", "elbow", "wrist")}
    arm = xyz_m[:, person]
    lo, hi = max(start - 1, 0), min(peak + 2, arm.shape[0])
    a = arm[lo:hi]
    length = np.linalg.norm(a[:, j["elbow"]] - a[:, j["shoulder"]], axis=1) + np.linalg.norm(
        a[:, j["wrist"]] - a[:, j["elbow"]], axis=1
    )
    straight = np.linalg.norm(a[:, j["wrist"]] - a[:, j["shoulder"]], axis=1) >= FULL_EXTENSION * length
    f0 = peak
    while f0 > start + 1 and straight[f0 - lo] and straight[f0 - 1 - lo]:
        f0 -= 1
    if f0 == peak:
        return peak
    g = glove_centre(a, hand)
    speed = np.zeros(len(g))
    speed[1:-1] = np.linalg.norm(g[2:] - g[:-2], axis=1)  # per two frames: only ratios are used
    top = float(speed[start - lo : peak - lo + 1].max())
    slow = [f for f in range(f0, peak + 1) if speed[f - lo] < STOPPED_FRAC * top]
    return slow[0] if slow else peak


@dataclass(frozen=True)
class BoutTruth:
    """Labelled events of one synthetic bout (rows: ``punches``, ``feints``, ``evades``).

    Fields:
        fps: frame rate (Hz); frames are indices into the bout's frames.
        punch_person / punch_hand / punch_type: (punches,) who, which hand
            (``HANDS``), which type (``PUNCH_TYPES``).
        punch_start_frame / punch_peak_frame / punch_end_frame: (punches,) frames.
        punch_peak_speed_mps: (punches,) peak speed of the ground-truth wrist, m/s.
        punch_target: (punches,) aimed region, ``head`` or ``body``.
        punch_outcome: (punches,) ``OUTCOMES``, from the contact on the bodies.
        punch_intent: (punches,) the script's aim (``INTENTS``; ``legacy`` = base script).
        punch_counter: (punches,) bool, thrown in answer to a combination.
        feint_person / feint_hand / feint_start_frame / feint_peak_frame / feint_end_frame:
            (feints,) the feints.
        evade_person / evade_kind / evade_start_frame / evade_peak_frame / evade_end_frame:
            (evades,) slips and ducks (``EVADE_KINDS``); evade_punch: (evades,) row of
            the punch evaded (-1 when none was thrown at that moment).
        clinch: (frames,) bool clinch frames.
        parry_person / parry_hand / parry_punch / parry_frame: (parries,) the defender, the
            glove he parries with (``HANDS``), the row of the punch parried and the frame of
            the contact (module docstring).
    """

    fps: float
    punch_person: np.ndarray
    punch_hand: np.ndarray
    punch_type: np.ndarray
    punch_start_frame: np.ndarray
    punch_peak_frame: np.ndarray
    punch_end_frame: np.ndarray
    punch_peak_speed_mps: np.ndarray
    punch_target: np.ndarray
    punch_outcome: np.ndarray
    punch_intent: np.ndarray
    punch_counter: np.ndarray
    feint_person: np.ndarray
    feint_hand: np.ndarray
    feint_start_frame: np.ndarray
    feint_peak_frame: np.ndarray
    feint_end_frame: np.ndarray
    evade_person: np.ndarray
    evade_kind: np.ndarray
    evade_start_frame: np.ndarray
    evade_peak_frame: np.ndarray
    evade_end_frame: np.ndarray
    evade_punch: np.ndarray
    clinch: np.ndarray
    parry_person: np.ndarray
    parry_hand: np.ndarray
    parry_punch: np.ndarray
    parry_frame: np.ndarray

    def __post_init__(self) -> None:
        n = self.punch_person.shape[0] if isinstance(self.punch_person, np.ndarray) else -1
        for name, vocab in (
            ("punch_hand", HANDS), ("punch_type", PUNCH_TYPES), ("punch_target", TARGETS),
            ("punch_outcome", OUTCOMES), ("punch_intent", INTENTS),
        ):  # fmt: skip
            arr = check_array(f"BoutTruth.{name}", getattr(self, name), (n,), "U")
            bad = sorted(set(arr.tolist()) - set(vocab))
            if bad:
                raise ValueError(f"BoutTruth.{name}: unknown values {bad}; expected {vocab}")
        for name in ("punch_person", "punch_start_frame", "punch_peak_frame", "punch_end_frame"):
            check_array(f"BoutTruth.{name}", getattr(self, name), (n,), "iu")
        check_array("BoutTruth.punch_peak_speed_mps", self.punch_peak_speed_mps, (n,), "f", finite=True)
        check_array("BoutTruth.punch_counter", self.punch_counter, (n,), "b")
        k = self.feint_person.shape[0] if isinstance(self.feint_person, np.ndarray) else -1
        check_array("BoutTruth.feint_hand", self.feint_hand, (k,), "U")
        for name in ("feint_person", "feint_start_frame", "feint_peak_frame", "feint_end_frame"):
            check_array(f"BoutTruth.{name}", getattr(self, name), (k,), "iu")
        m = self.evade_person.shape[0] if isinstance(self.evade_person, np.ndarray) else -1
        kinds = check_array("BoutTruth.evade_kind", self.evade_kind, (m,), "U")
        if set(kinds.tolist()) - set(EVADE_KINDS):
            raise ValueError(f"BoutTruth.evade_kind: unknown values {sorted(set(kinds.tolist()) - set(EVADE_KINDS))}")
        for name in ("evade_person", "evade_start_frame", "evade_peak_frame", "evade_end_frame", "evade_punch"):
            check_array(f"BoutTruth.{name}", getattr(self, name), (m,), "iu")
        check_array("BoutTruth.clinch", self.clinch, (None,), "b")
        q = self.parry_person.shape[0] if isinstance(self.parry_person, np.ndarray) else -1
        hands = check_array("BoutTruth.parry_hand", self.parry_hand, (q,), "U")
        if set(hands.tolist()) - set(HANDS):
            raise ValueError(f"BoutTruth.parry_hand: unknown values {sorted(set(hands.tolist()) - set(HANDS))}")
        for name in ("parry_person", "parry_punch", "parry_frame"):
            check_array(f"BoutTruth.{name}", getattr(self, name), (q,), "iu")
        if q and not (0 <= self.parry_punch.min() and self.parry_punch.max() < n):
            raise ValueError(f"BoutTruth.parry_punch: rows {self.parry_punch.tolist()} outside 0..{n - 1}")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"BoutTruth.fps must be positive, got {self.fps}")

    @property
    def n_punches(self) -> int:
        return int(self.punch_person.shape[0])


def punch_type(p: Punch) -> str:
    """The analytics vocabulary's type of a scripted punch kind."""
    return "body_shot" if p.kind.startswith("body") else p.kind


def contact_outcome(xyz_m: np.ndarray, person: int, hand: str, frames: np.ndarray) -> tuple[str, str]:
    """(outcome, region touched or "none") of ``person``'s ``hand`` glove over ``frames`` on
    the ground-truth joints ``xyz_m`` (frames, 2, 23, 3) (see the module docstring)."""
    gaps = glove_gaps(xyz_m[frames, person], hand, xyz_m[frames, 1 - person], COCO17_FEET)
    g = {k: float(v.min()) for k, v in gaps.items()}
    target = min(g["head"], g["body"])
    if target <= CONTACT_TOL_M and target <= g["arms"]:
        return "landed", "head" if g["head"] <= g["body"] else "body"
    if g["arms"] <= CONTACT_TOL_M:
        return "blocked", "guard"
    return "missed", "none"


def parry_contact(xyz_m: np.ndarray, person: int, hand: str, side: str, frames: np.ndarray) -> int:
    """First of ``frames`` at which the other athlete's ``side`` glove is within ``CONTACT_TOL_M``
    of ``person``'s ``hand`` glove or forearm (joints ``xyz_m`` (frames, 2, 23, 3)); -1 if none."""
    x = xyz_m[frames]
    g = glove_centre(x[:, 1 - person], side)
    punch = glove_centre(x[:, person], hand)
    el = x[:, person, COCO17_FEET.index(f"{hand}_elbow")]
    wr = x[:, person, COCO17_FEET.index(f"{hand}_wrist")]
    to_glove = np.linalg.norm(g - punch, axis=1) - 2.0 * R_GLOVE_M
    to_arm = segment_distance(g, g, el, wr) - R_GLOVE_M - R_FOREARM_M
    hit = np.flatnonzero(np.minimum(to_glove, to_arm) <= CONTACT_TOL_M)
    return int(frames[hit[0]]) if hit.size else -1


def record_truth(ch: Choreography, xyz_m: np.ndarray, peak_speed_mps: np.ndarray, fps: float) -> BoutTruth:
    """Label the scripted events of ``ch`` on its ground-truth joints ``xyz_m`` (frames, 2, 23, 3).

    ``peak_speed_mps`` (len(ch.punches),) is every scripted punch's (feints too) peak
    wrist speed. Raises ``ValueError`` on mismatched lengths.
    """
    if len(peak_speed_mps) != len(ch.punches):
        raise ValueError(f"record_truth: {len(peak_speed_mps)} speeds for {len(ch.punches)} punches")
    t, n_f = ch.t_s, xyz_m.shape[0]
    rows: list[dict] = []
    feints: list[dict] = []
    parries: list[dict] = []
    for p, v in zip(ch.punches, peak_speed_mps, strict=True):
        fr = {"start": frame_at(t, p.t0_s), "peak": frame_at(t, p.peak_s), "end": frame_at(t, p.end_s)}
        if p.feint:
            feints.append({"person": p.person, "hand": p.hand, **fr})
            continue
        fr["peak"] = strike_frame(xyz_m, p.person, p.hand, fr["start"], fr["peak"])
        win = np.arange(max(fr["peak"] - 1, 0), min(fr["peak"] + 3, n_f))
        outcome, _ = contact_outcome(xyz_m, p.person, p.hand, win)
        if p.aim == "parry":
            side = other_side(p.hand)
            c = parry_contact(xyz_m, p.person, p.hand, side, np.arange(fr["start"], fr["peak"] + 1))
            if c >= 0:
                parries.append({"person": 1 - p.person, "hand": side, "punch": len(rows), "frame": c})
        rows.append(
            {
                "person": p.person, "hand": p.hand, "type": punch_type(p), **fr, "speed": float(v),
                "target": "body" if p.kind.startswith("body") else "head", "outcome": outcome,
                "intent": p.aim, "counter": p.counter,
            }
        )  # fmt: skip
    evades: list[dict] = []
    for s in ch.slips:
        if s.pitch_rad < 0:
            continue  # a pull back (the analytics know slips and ducks only)
        peak = frame_at(t, s.t0_s + 0.5 * s.duration_s)
        hit = [
            i for i, r in enumerate(rows)
            if r["person"] == 1 - s.person and abs(r["peak"] - peak) <= round(0.5 * s.duration_s * fps)
        ]  # fmt: skip
        evades.append(
            {
                "person": s.person, "kind": "duck" if s.roll_rad * abs(s.side) < 0.1 else "slip",
                "start": frame_at(t, s.t0_s), "peak": peak, "end": frame_at(t, s.t0_s + s.duration_s),
                "punch": min(hit, key=lambda i: abs(rows[i]["peak"] - peak)) if hit else -1,
            }
        )  # fmt: skip
    w = np.minimum(ch.boxers[0].clinch_w, ch.boxers[1].clinch_w)

    def col(items: list[dict], key: str, dtype: object) -> np.ndarray:
        if dtype is str:
            return np.array([r[key] for r in items], dtype=np.str_) if items else np.zeros(0, dtype="<U1")
        return np.array([r[key] for r in items], dtype=dtype)  # type: ignore[call-overload]

    return BoutTruth(
        fps=float(fps),
        punch_person=col(rows, "person", np.int64), punch_hand=col(rows, "hand", str), punch_type=col(rows, "type", str),
        punch_start_frame=col(rows, "start", np.int64), punch_peak_frame=col(rows, "peak", np.int64),
        punch_end_frame=col(rows, "end", np.int64), punch_peak_speed_mps=col(rows, "speed", np.float64),
        punch_target=col(rows, "target", str), punch_outcome=col(rows, "outcome", str),
        punch_intent=col(rows, "intent", str), punch_counter=col(rows, "counter", bool),
        feint_person=col(feints, "person", np.int64), feint_hand=col(feints, "hand", str),
        feint_start_frame=col(feints, "start", np.int64), feint_peak_frame=col(feints, "peak", np.int64),
        feint_end_frame=col(feints, "end", np.int64),
        evade_person=col(evades, "person", np.int64), evade_kind=col(evades, "kind", str),
        evade_start_frame=col(evades, "start", np.int64), evade_peak_frame=col(evades, "peak", np.int64),
        evade_end_frame=col(evades, "end", np.int64), evade_punch=col(evades, "punch", np.int64),
        clinch=w >= CLINCH_GRIP_MIN,
        parry_person=col(parries, "person", np.int64), parry_hand=col(parries, "hand", str),
        parry_punch=col(parries, "punch", np.int64), parry_frame=col(parries, "frame", np.int64),
    )  # fmt: skip
