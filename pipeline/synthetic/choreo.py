"""The bout script: where the two boxers stand, whom they face, and when they punch,
slip and clinch.

Phases cycle ``exchange -> clinch -> range`` (a clinch-free bout replaces the clinch by a
close-range exchange). The distance between the boxers, the circling rate, the clinch
weight and the stance squareness are keyframed per phase and interpolated with PCHIP
(C1, no overshoot); the midpoint of the pair drifts slowly inside the ring.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from pipeline.schema.joints import other_side
from pipeline.synthetic.curves import keyframes, minjerk

PunchKind = Literal[
    "jab", "cross", "lead_hook", "rear_hook", "lead_uppercut", "rear_uppercut", "body_jab", "body_cross"
]
PunchAim = Literal["legacy", "land", "block", "slip", "short", "parry"]
"""How a punch's strike point is placed. ``legacy``: the original script (straights at the
head where it was when the punch started, stopped 0.12 m short; the lead hook on a fixed
arc). The others (``pipeline.synthetic.combos``, placed by ``pipeline.synthetic.strikes``):
``land`` at contact with the target at the strike frame (the defender's guard opens),
``block`` onto the defender's glove put in the way, ``slip`` at where the head was before
the defender slipped or ducked, ``short`` at the head the defender pulls back (a body shot
stops ``shortfall_m`` before contact)."""

REAR_KINDS: frozenset[str] = frozenset({"cross", "rear_hook", "rear_uppercut", "body_cross"})
"""Punch kinds thrown with the rear (right, both boxers are orthodox) hand."""

PHASE_S: dict[str, tuple[float, float]] = {
    "exchange": (1.1, 1.4),
    "clinch": (1.8, 2.2),
    "close": (1.2, 1.5),
    "range": (1.3, 1.7),
}
"""Duration range (seconds) of each phase kind."""

CLINCH_DISTANCE_M = 0.45
"""Distance between the two stance centres while clinching (torsos then ~0.35 m apart)."""

NOMINAL_PATH_M: dict[str, float] = {
    "jab": 0.45,
    "cross": 0.6,
    "lead_hook": 0.62,
    "rear_hook": 0.62,
    "lead_uppercut": 0.5,
    "rear_uppercut": 0.55,
    "body_jab": 0.5,
    "body_cross": 0.62,
}
"""Rough fist path length per punch kind (first guess of the punch duration)."""


@dataclass(frozen=True)
class Parry:
    """How the defender parries a punch (``Punch.aim == "parry"``): his glove on the side the
    punch arrives on sweeps across its line and meets its glove on the way out, which is then
    pushed sideways and misses (``pipeline.synthetic.motion``)."""

    at_frac: float
    """Fraction of the punch's outward stroke (time), in (0, 1), from which on the gloves meet
    as soon as the defender can reach the punch (``motion.parry_contacts``)."""
    sweep_m: float
    """Length (m) of the parrying glove's sideways slap (``strikes.parry_sweep``)."""
    sweep_s: float
    """Duration (s) of the slap; the glove then goes back to the guard."""
    deflect_m: float
    """Sideways displacement (m) of the punching glove at the strike, built up from the contact
    (``strikes.parried_stroke``)."""

    def __post_init__(self) -> None:
        if not (0.0 < self.at_frac < 1.0 and self.sweep_m > 0 and self.sweep_s > 0 and self.deflect_m > 0):
            raise ValueError(
                f"Parry needs at_frac in (0, 1) and positive sweep_m, sweep_s, deflect_m; got {self}"
            )


@dataclass(frozen=True)
class Punch:
    """One punch: the fist leaves the guard at ``t0_s``, reaches the strike point after
    ``out_s`` (minimum jerk), holds ``hold_s`` and returns in ``back_s``."""

    person: int
    kind: PunchKind
    t0_s: float
    out_s: float
    hold_s: float
    back_s: float
    target_speed_mps: float
    aim: PunchAim = "legacy"
    amplitude: float = 1.0
    """Fraction of the path travelled; < 1 is a feint (the fist starts and comes back)."""
    shortfall_m: float = 0.0
    """``aim="short"``: how far before contact the glove stops (metres)."""
    counter: bool = False
    """Thrown in answer to the opponent's combination."""
    parry: Parry | None = None
    """``aim="parry"``: how the defender parries it (None otherwise)."""
    lead: str = "left"
    """The thrower's lead hand: ``left`` orthodox, ``right`` southpaw (``with_stances``)."""
    back_by_s: float = float("inf")
    """Time (s) by which the fist must be back in guard: the same hand's next punch leaves
    then. A duration that would end later (the speed calibration stretches punches) is
    scaled down, ``out_s`` and ``back_s`` alike, to end exactly then."""

    def __post_init__(self) -> None:
        if self.lead not in ("left", "right"):
            raise ValueError(f"Punch {self.kind} at {self.t0_s:.3f} s: lead must be 'left' or 'right', got {self.lead!r}")
        if (self.aim == "parry") != (self.parry is not None):
            raise ValueError(f"Punch {self.kind} at {self.t0_s:.3f} s: aim={self.aim!r} with parry={self.parry}")
        if self.end_s > self.back_by_s + 1e-9:
            room = self.back_by_s - self.t0_s - self.hold_s
            if room <= 0.0:
                raise ValueError(
                    f"Punch {self.kind} at {self.t0_s:.3f} s: back_by_s={self.back_by_s:.3f} s leaves "
                    f"no time for the punch (hold ends at {self.t0_s + self.hold_s:.3f} s)"
                )
            k = room / (self.out_s + self.back_s)
            object.__setattr__(self, "out_s", self.out_s * k)
            object.__setattr__(self, "back_s", self.back_s * k)

    @property
    def hand(self) -> str:
        """Hand that throws it: the rear hand for ``REAR_KINDS``, else the ``lead`` hand."""
        if self.kind in REAR_KINDS:
            return other_side(self.lead)
        return self.lead

    @property
    def feint(self) -> bool:
        return self.amplitude < 1.0

    @property
    def peak_s(self) -> float:
        """Time of the strike (full extension)."""
        return self.t0_s + self.out_s

    @property
    def end_s(self) -> float:
        return self.t0_s + self.out_s + self.hold_s + self.back_s

    @property
    def parry_s(self) -> float:
        """Earliest time of the parry's contact (s, ``Parry.at_frac``); ``ValueError`` when the
        punch is not parried."""
        if self.parry is None:
            raise ValueError(f"Punch {self.kind} at {self.t0_s:.3f} s is not parried (aim={self.aim!r})")
        return self.t0_s + self.parry.at_frac * self.out_s

    def profile(self, t_s: np.ndarray) -> np.ndarray:
        """Extension 0 (guard) -> 1 (strike) -> 0 over time (C2)."""
        out = minjerk((t_s - self.t0_s) / self.out_s)
        back = minjerk((t_s - self.t0_s - self.out_s - self.hold_s) / self.back_s)
        return self.amplitude * (out - back)


@dataclass(frozen=True)
class Slip:
    """A defensive slip/roll: the trunk leans sideways (``side`` +1 = own left) and dips."""

    person: int
    t0_s: float
    duration_s: float
    side: float
    depth_m: float
    roll_rad: float = 0.28
    """Peak sideways lean of the trunk (0 with a deep ``depth_m`` is a duck)."""
    pitch_rad: float = 0.1
    """Peak forward lean added to the trunk (negative: a pull back, away from a punch)."""


@dataclass(frozen=True)
class BoxerIntent:
    """Where one boxer wants to be (the feet follow by discrete steps).

    Fields (F = frames): centre_xy (F, 2) stance centre; facing (F,) yaw towards the
    opponent; square (F,) 0 = bladed orthodox stance, 1 = square clinch stance;
    clinch_w (F,) 0..1 weight of the clinch grip.
    """

    centre_xy: np.ndarray
    facing: np.ndarray
    square: np.ndarray
    clinch_w: np.ndarray


@dataclass(frozen=True)
class Choreography:
    """The whole script. ``phases`` rows are (kind, start_s, end_s)."""

    t_s: np.ndarray
    boxers: tuple[BoxerIntent, BoxerIntent]
    punches: tuple[Punch, ...]
    slips: tuple[Slip, ...]
    phases: tuple[tuple[str, float, float], ...]
    southpaw: tuple[bool, bool] = (False, False)
    """Per boxer, whether he fights southpaw (``with_stances``; the script is written for two
    orthodox boxers)."""


def _phases(total_s: float, clinch: bool, rng: np.random.Generator) -> list[tuple[str, float, float]]:
    kinds = ["exchange", "clinch" if clinch else "close", "range"]
    out: list[tuple[str, float, float]] = []
    t, i = 0.0, 0
    while t < total_s:
        kind = kinds[i % 3]
        lo, hi = PHASE_S[kind]
        d = float(rng.uniform(lo, hi))
        out.append((kind, t, t + d))
        t += d
        i += 1
    return out


def _punch(person: int, kind: PunchKind, t0: float, rng: np.random.Generator) -> Punch:
    v = float(rng.uniform(7.0, 8.5))
    out_s = 1.875 * NOMINAL_PATH_M[kind] / v  # peak speed of a min-jerk ramp is 1.875 d / T
    return Punch(person, kind, t0, out_s, 0.04, 1.6 * out_s, v)


Vary = Callable[
    [list[tuple[str, float, float]], list[tuple[float, float]]],
    tuple[list[tuple[float, float]], list[Punch], list[Slip]],
]
"""``(phases, distance keys) -> (distance keys, punches, slips)``: re-scripts a bout
(``pipeline.synthetic.combos.vary`` with its own random stream)."""


def make_choreography(
    n_frames: int, fps: float, clinch: bool, rng: np.random.Generator, vary: Vary | None = None
) -> Choreography:
    """Script a bout of ``n_frames`` frames. Deterministic for a given ``rng`` state.

    ``vary`` replaces the punches, slips and distance keys after the base script is drawn,
    so the base draws (phases, circling, drift) are the same with and without it."""
    t = np.arange(n_frames) / fps
    total = float(t[-1]) if n_frames > 1 else 0.0
    phases = _phases(total + 1e-6, clinch, rng)

    d_keys: list[tuple[float, float]] = [(0.0, 1.55)]
    w_keys: list[tuple[float, float]] = [(0.0, 0.0)]
    q_keys: list[tuple[float, float]] = [(0.0, 0.0)]
    om_keys: list[tuple[float, float]] = []
    punches: list[Punch] = []
    slips: list[Slip] = []
    for kind, a, b in phases:
        sign = float(rng.choice([-1.0, 1.0]))
        mid = 0.5 * (a + b)
        if kind == "exchange":
            d_keys += [(a + 0.05, 1.55), (b - 0.1, 1.15)]
            om_keys.append((mid, sign * rng.uniform(0.05, 0.15)))
            att = int(rng.integers(2))
            tj = a + 0.1 + rng.uniform(0.0, 0.1)
            tc = tj + 0.28 + rng.uniform(0.0, 0.06)
            th = tc + 0.35 + rng.uniform(0.0, 0.1)
            punches += [
                _punch(att, "jab", tj, rng),
                _punch(att, "cross", tc, rng),
                _punch(1 - att, "lead_hook", th, rng),
            ]
            slips += [
                Slip(1 - att, tj - 0.03, 0.5, float(rng.choice([-1.0, 1.0])), 0.05),
                Slip(att, th - 0.02, 0.45, 1.0, 0.09),
            ]
        elif kind == "clinch":
            d_keys += [(a + 0.45, CLINCH_DISTANCE_M), (b - 0.5, CLINCH_DISTANCE_M), (b - 0.05, 1.15)]
            w_keys += [(a + 0.15, 0.0), (a + 0.5, 1.0), (b - 0.55, 1.0), (b - 0.3, 0.0)]
            q_keys += [(a, 0.0), (a + 0.4, 1.0), (b - 0.4, 1.0), (b, 0.0)]
            om_keys.append((mid, sign * rng.uniform(0.15, 0.3)))
        elif kind == "close":
            d_keys += [(a + 0.35, 1.0), (b - 0.3, 1.0), (b - 0.05, 1.2)]
            om_keys.append((mid, sign * rng.uniform(0.1, 0.2)))
            first = int(rng.integers(2))
            t1 = a + 0.3 + rng.uniform(0.0, 0.1)
            t2 = t1 + 0.45 + rng.uniform(0.0, 0.1)
            punches += [_punch(first, "lead_hook", t1, rng), _punch(1 - first, "lead_hook", t2, rng)]
            slips += [Slip(1 - first, t1 - 0.02, 0.45, 1.0, 0.09), Slip(first, t2 - 0.02, 0.45, 1.0, 0.09)]
        else:  # range
            d_keys += [(a + 0.45, 1.7), (b, 1.6)]
            om_keys.append((mid, sign * rng.uniform(0.3, 0.45)))
            first = int(rng.integers(2))
            t1 = a + 0.5 + rng.uniform(0.0, 0.2)
            t2 = t1 + 0.5 + rng.uniform(0.0, 0.15)
            punches += [_punch(first, "jab", t1, rng), _punch(1 - first, "jab", t2, rng)]
            slips += [Slip(1 - first, t1 - 0.03, 0.5, float(rng.choice([-1.0, 1.0])), 0.05)]
    if vary is not None:
        d_keys, punches, slips = vary(phases, d_keys)
    punches = [p for p in punches if p.t0_s >= 0.05 and p.end_s + 0.1 < total]
    slips = [s for s in slips if s.t0_s >= 0.0 and s.t0_s + s.duration_s < total]

    dist = keyframes(t, *map(list, zip(*d_keys, strict=True)))
    clinch_w = keyframes(t, *map(list, zip(*w_keys, strict=True)))
    square = keyframes(t, *map(list, zip(*q_keys, strict=True)))
    omega = keyframes(t, *map(list, zip(*om_keys, strict=True))) if om_keys else np.zeros_like(t)
    psi = float(rng.uniform(-np.pi, np.pi)) + np.concatenate(
        [[0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) / fps)]
    )

    # Midpoint of the pair: slow drift through random points inside a 0.5 m disc.
    n_keys = max(2, int(np.ceil(total / 1.5)) + 1)
    key_t = list(np.linspace(0.0, max(total, 1e-3), n_keys))
    ang = rng.uniform(-np.pi, np.pi, n_keys)
    rad = 0.5 * np.sqrt(rng.uniform(0.0, 1.0, n_keys))
    mx = keyframes(t, key_t, list(rad * np.cos(ang)))
    my = keyframes(t, key_t, list(rad * np.sin(ang)))
    midpoint = np.stack([mx, my], axis=1)

    u = np.stack([np.cos(psi), np.sin(psi)], axis=1)
    boxers = (
        BoxerIntent(midpoint - 0.5 * dist[:, None] * u, psi.copy(), square, clinch_w),
        BoxerIntent(midpoint + 0.5 * dist[:, None] * u, psi + np.pi, square.copy(), clinch_w.copy()),
    )
    return Choreography(t, boxers, tuple(punches), tuple(slips), tuple(phases))


def with_stances(ch: Choreography, southpaw: tuple[bool, bool]) -> Choreography:
    """``ch`` with boxer ``i`` southpaw where ``southpaw[i]``: each of his punches is thrown with
    the other hand (a jab with the right). The script only asks whether two punches share a
    hand, which exchanging both hands keeps, so every time and choice of ``ch`` stays; his
    stance, guard and trunk twists are mirrored where the motion is built (``motion``)."""
    punches = tuple(dataclasses.replace(p, lead="right") if southpaw[p.person] else p for p in ch.punches)
    return dataclasses.replace(ch, punches=punches, southpaw=(bool(southpaw[0]), bool(southpaw[1])))
