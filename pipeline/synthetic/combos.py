"""Randomised combinations, feints, counters and defences (``SyntheticConfig.variety``).

The base script (``pipeline.synthetic.choreo``) throws the same pattern in every phase
(jab-cross-hook, two hooks, two jabs), always out of range. With ``variety`` each
exchange, close and range phase gets instead, from its own random stream:

- a random combination of 1-4 punches of every kind (jab, cross, lead/rear hook,
  lead/rear uppercut, straight body shots), hands mostly alternating;
- the attacker closing the distance for it (0.9 m between stance centres for straight
  punches, 0.75 m when the combination holds a hook or an uppercut);
- an intended outcome per punch (``Punch.aim``): land, be blocked, be slipped or ducked
  (a ``Slip`` of the defender timed on the strike), or fall short (the defender pulls
  his head back, or a body shot stops short);
- often a feint first (the fist starts and comes back, ``Punch.amplitude`` < 1) and
  sometimes a counter by the defender (``Punch.counter``);
- with ``SyntheticConfig.parry_prob`` > 0, a jab or cross aimed to be blocked, in a phase
  thrown at straight-punch range, is parried instead with that probability (``Punch.parry``:
  the defender's glove slaps it sideways on its way out), drawn from a stream of its own so
  that nothing else changes.

The clinch phases, the circling and the drift of the pair are left as the base script
drew them (the base draws come first, from the base stream), so a bout differs from its
base version only by what is listed above.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pipeline.synthetic.choreo import NOMINAL_PATH_M, REAR_KINDS, Parry, Punch, PunchAim, PunchKind, Slip

LEAD_KINDS: tuple[PunchKind, ...] = ("jab", "lead_hook", "lead_uppercut", "body_jab")
REAR_KIND_LIST: tuple[PunchKind, ...] = ("cross", "rear_hook", "rear_uppercut", "body_cross")
CLOSE_KINDS = frozenset({"lead_hook", "rear_hook", "lead_uppercut", "rear_uppercut"})
STRAIGHT_ATTACK_M = 0.9
"""Distance between the stance centres while straight punches are thrown (they reach)."""
CLOSE_ATTACK_M = 0.75
"""Distance while hooks and uppercuts are thrown."""
SHORTFALL_M = (0.08, 0.14)
"""Range of how far before contact a short body shot stops."""
PULL_PITCH_RAD = -0.5
"""Backward lean of a defender pulling away from a punch at his head (the head moves
back ~0.3 m, so the straightened arm falls short)."""
SAME_HAND_GAP_S = 0.06
"""A punch leaves this long after the same hand's previous punch is back in guard."""
BACK_BY_MARGIN_S = 0.04
"""A punch (or feint) must be back in guard this long before the same hand's next one
leaves, whatever the speed calibration does to its duration (``Punch.back_by_s``)."""
FEINT_AMPLITUDE = (0.2, 0.35)
"""Range of the fraction of the path a feint travels."""
AIMS: dict[str, tuple[tuple[PunchAim, ...], tuple[float, ...]]] = {
    "straight": (("land", "block", "slip", "short"), (0.35, 0.25, 0.2, 0.2)),
    "hook": (("land", "block", "slip", "short"), (0.35, 0.25, 0.2, 0.2)),
    "uppercut": (("land", "short"), (0.6, 0.4)),
    "body": (("land", "short"), (0.65, 0.35)),
}
"""Intended outcomes per family of punch, with their probabilities."""
PARRIED_KINDS = frozenset({"jab", "cross"})
"""Punch kinds a ``block`` aim may turn into a parry (``SyntheticConfig.parry_prob``)."""
PARRY_AT_FRAC = (0.4, 0.5)
"""Range of the fraction of the outward stroke at which the parrying glove meets the punch."""
PARRY_SWEEP_M = (0.12, 0.2)
"""Range of the parrying glove's sideways slap (m)."""
PARRY_SWEEP_S = (0.08, 0.1)
"""Range of the slap's duration (s)."""
PARRY_DEFLECT_M = (0.16, 0.22)
"""Range of how far sideways the parried glove is pushed (m), reached at the strike."""
PARRY_LIFT = 0.2
"""The parried glove also rises by this fraction of ``Parry.deflect_m``: it rides up over the
defender's other glove and shoulder instead of into them."""
PARRY_CONTACT_AT = 0.8
"""Fraction of the parrying slap's duration at which it meets the punch: 94 % of its length,
at 40 % of its peak speed (the glove stops on the punch a centimetre further and goes back
instead of cutting into the arm behind it)."""
PARRY_IN_S = 0.1
"""A parrying glove moves from the guard to the start of its slap in this long (s)."""
PARRY_BACK_S = 0.15
"""... and from the end of its slap back to the guard in this long (s)."""
PARRY_FREE_MARGIN_S = 0.06
"""A block becomes a parry only when the defender throws nothing, parries nothing else and
does not slip or duck within this (s) of the parry's span (the speed calibration moves
punches by a few hundredths of a second)."""


def family(kind: str) -> str:
    if kind.startswith("body"):
        return "body"
    if kind.endswith("hook"):
        return "hook"
    if kind.endswith("uppercut"):
        return "uppercut"
    return "straight"


@dataclass
class _Plan:
    punches: list[Punch]
    slips: list[Slip]
    d_keys: list[tuple[float, float]]
    close: bool = False
    """The punches are thrown at ``CLOSE_ATTACK_M`` (a hook or an uppercut among them)."""


def _speed_punch(
    person: int, kind: PunchKind, t0: float, aim: PunchAim, rng: np.random.Generator, counter: bool = False
) -> Punch:
    v = float(rng.uniform(7.0, 8.5))
    out_s = 1.875 * NOMINAL_PATH_M[kind] / v
    short = float(rng.uniform(*SHORTFALL_M)) if aim == "short" else 0.0
    return Punch(person, kind, t0, out_s, 0.04, 1.6 * out_s, v, aim=aim, shortfall_m=short, counter=counter)


def _feint(person: int, t0: float, rng: np.random.Generator) -> Punch:
    kind: PunchKind = "jab" if rng.uniform() < 0.6 else "cross"
    amp = float(rng.uniform(*FEINT_AMPLITUDE))
    out_s = float(rng.uniform(0.08, 0.12))
    # Its speed is whatever the short path gives; it is not calibrated (``bout``).
    v = 1.875 * amp * NOMINAL_PATH_M[kind] / out_s
    return Punch(person, kind, t0, out_s, 0.0, 1.3 * out_s, v, aim="land", amplitude=amp)


def _kinds(n: int, pool: tuple[PunchKind, ...], rng: np.random.Generator) -> list[PunchKind]:
    """``n`` kinds from ``pool``, hands alternating with probability 0.8."""
    out: list[PunchKind] = []
    for i in range(n):
        cands = list(pool)
        if i > 0 and rng.uniform() < 0.8:
            rear_prev = out[-1] in REAR_KINDS
            cands = [k for k in pool if (k in REAR_KINDS) != rear_prev] or cands
        out.append(cands[int(rng.integers(len(cands)))])
    return out


def _schedule(
    person: int, kinds: list[PunchKind], t_start: float, t_stop: float, rng: np.random.Generator, counter: bool
) -> list[Punch]:
    """Punches of ``kinds`` from ``t_start``, each ending before ``t_stop``; a punch waits for the
    previous one's strike (other hand) and for the return of the last punch of its own hand
    (``SAME_HAND_GAP_S`` after it)."""
    out: list[Punch] = []
    t = t_start
    for kind in kinds:
        fam = family(kind)
        aims, probs = AIMS[fam]
        aim = aims[int(rng.choice(len(aims), p=probs))]
        hand = "right" if kind in REAR_KINDS else "left"
        if out:
            prev = out[-1]
            same = prev.hand == hand
            t = prev.end_s + SAME_HAND_GAP_S if same else prev.peak_s + float(rng.uniform(0.03, 0.12))
            t = max([t] + [q.end_s + SAME_HAND_GAP_S for q in out if q.hand == hand])
        p = _speed_punch(person, kind, t, aim, rng, counter)
        if p.end_s > t_stop:
            break
        out.append(p)
    return out


def _evasions(punches: list[Punch], slips: list[Slip], rng: np.random.Generator) -> list[Punch]:
    """The defender's move for every punch at the head aimed to be evaded: a ``Slip``
    sideways or a duck (``slip``), a pull back (``short``: the straight arm falls short).
    A punch whose defender is already moving (overlapping bumps would add up) is thrown
    at him as he is."""
    out: list[Punch] = []
    for p in punches:
        head = family(p.kind) != "body"
        if p.aim not in ("slip", "short") or not head or p.feint:
            out.append(p)
            continue
        d = 0.45
        t0 = p.peak_s - 0.5 * d
        busy = any(s.person == 1 - p.person and t0 < s.t0_s + s.duration_s and s.t0_s < t0 + d for s in slips)
        if busy:
            out.append(Punch(**{**p.__dict__, "aim": "land"}))
            continue
        if p.aim == "short":
            slips.append(Slip(1 - p.person, t0, d, 0.0, 0.0, roll_rad=0.0, pitch_rad=PULL_PITCH_RAD))
        elif family(p.kind) == "hook" or rng.uniform() < 0.4:  # duck under it
            slips.append(Slip(1 - p.person, t0, d, 0.0, float(rng.uniform(0.2, 0.24)), roll_rad=0.0))
        else:
            slips.append(Slip(1 - p.person, t0, d, float(rng.choice([-1.0, 1.0])), 0.05, roll_rad=0.5))
        out.append(p)
    return out


def _phase(kind: str, a: float, b: float, next_kind: str | None, rng: np.random.Generator) -> _Plan:
    att = int(rng.integers(2))
    pool: tuple[PunchKind, ...]
    if kind == "range":
        n, pool = int(rng.integers(1, 4)), ("jab", "cross", "body_jab")
    elif kind == "close":
        n, pool = int(rng.integers(2, 5)), ("lead_hook", "rear_hook", "lead_uppercut", "rear_uppercut", "body_jab", "body_cross")
    else:
        n, pool = int(rng.integers(2, 6)), LEAD_KINDS + REAR_KIND_LIST
    kinds = _kinds(n, pool, rng)
    if kind != "close" and rng.uniform() < 0.5:
        kinds[0] = "jab"
    t_first = a + float(rng.uniform(0.25, 0.4))
    punches: list[Punch] = []
    if rng.uniform() < 0.5:  # a feint while closing in
        punches.append(_feint(att, a + float(rng.uniform(0.0, 0.05)), rng))
        t_first = max(t_first, punches[-1].end_s + 0.04)
    combo = _schedule(att, kinds, t_first, b - 0.05, rng, False)
    punches += combo
    if combo and rng.uniform() < 0.6:  # the defender counters
        n_c = int(rng.integers(1, 3))
        pool_c: tuple[PunchKind, ...] = pool if kind != "range" else ("jab", "cross")
        t_c = combo[-1].peak_s + float(rng.uniform(0.08, 0.18))
        punches += _schedule(1 - att, _kinds(n_c, pool_c, rng), t_c, b - 0.05, rng, True)
    real = [p for p in punches if not p.feint]
    close = any(p.kind in CLOSE_KINDS for p in real)
    d_att = (CLOSE_ATTACK_M if close else STRAIGHT_ATTACK_M) + float(rng.uniform(-0.03, 0.03))
    d_exit = 1.15 if next_kind == "clinch" else float(rng.uniform(1.35, 1.6))
    keys: list[tuple[float, float]] = []
    if real:
        t_in = min(p.t0_s for p in real) - 0.08
        t_out = max(p.end_s for p in real)
        keys += [(t_in, d_att), (max(t_out, t_in + 0.05), d_att + 0.05)]
        keys.append((max(b - 0.1, keys[-1][0] + 0.05), d_exit))
    else:
        keys.append((b - 0.1, d_exit))
    return _Plan(punches, [], keys, close)


def parries(punches: list[Punch], slips: list[Slip], prob: float, rng: np.random.Generator | None) -> list[Punch]:
    """``punches`` with each jab or cross aimed ``block`` turned into a parry with probability
    ``prob`` (its shape drawn from ``rng``, one uniform per candidate punch), unless the
    defender is busy then: punching (a counter would tangle the arms), parrying the previous
    punch, or slipping or ducking (a parry is made standing; ``PARRY_FREE_MARGIN_S``).
    Unchanged, and ``rng`` untouched, when ``prob`` is 0."""
    if prob <= 0.0:
        return punches
    if rng is None:
        raise ValueError(f"combos.parries: parry_prob={prob} needs a random stream")
    out: list[Punch] = []
    for p in punches:
        if p.aim != "block" or p.kind not in PARRIED_KINDS or p.feint or rng.uniform() >= prob:
            out.append(p)
            continue
        parry = Parry(
            at_frac=float(rng.uniform(*PARRY_AT_FRAC)),
            sweep_m=float(rng.uniform(*PARRY_SWEEP_M)),
            sweep_s=float(rng.uniform(*PARRY_SWEEP_S)),
            deflect_m=float(rng.uniform(*PARRY_DEFLECT_M)),
        )
        q = dataclasses.replace(p, aim="parry", parry=parry)
        lo, hi = parry_span(q)
        lo, hi = lo - PARRY_FREE_MARGIN_S, hi + PARRY_FREE_MARGIN_S
        busy = any(o.person != p.person and o.t0_s < hi and lo < o.end_s for o in punches)
        busy |= any(v.person != p.person and v.t0_s < hi and lo < v.t0_s + v.duration_s for v in slips)
        busy |= any(o.parry is not None and o.person == p.person and parry_span(o)[1] > lo for o in out)
        out.append(p if busy else q)
    return out


def parry_span(p: Punch, contact_s: float | None = None) -> tuple[float, float]:
    """(start, end) in seconds of the parrying glove's move against the parried punch ``p``
    with its contact at ``contact_s`` (default ``p.parry_s``): from the guard, the slap
    (``Parry.sweep_s``, the contact ``PARRY_CONTACT_AT`` through it), back to the guard."""
    if p.parry is None:
        raise ValueError(f"parry_span: punch {p.kind} at {p.t0_s:.3f} s is not parried")
    t_c = p.parry_s if contact_s is None else contact_s
    before, after = PARRY_CONTACT_AT * p.parry.sweep_s, (1.0 - PARRY_CONTACT_AT) * p.parry.sweep_s
    return t_c - before - PARRY_IN_S, t_c + after + PARRY_BACK_S


def vary(
    phases: list[tuple[str, float, float]],
    base_d_keys: list[tuple[float, float]],
    rng: np.random.Generator,
    parry_prob: float = 0.0,
    rng_parry: np.random.Generator | None = None,
) -> tuple[list[tuple[float, float]], list[Punch], list[Slip]]:
    """The varied script: (distance keys, punches, slips). Clinch phases keep the base
    distance keys; every other phase is re-scripted (see the module docstring). Parries
    (``parries``) draw from ``rng_parry`` only, so ``parry_prob`` changes no other choice."""
    clinch = [(a, b) for k, a, b in phases if k == "clinch"]
    d_keys = [(t, d) for t, d in base_d_keys if t == 0.0 or any(a <= t <= b for a, b in clinch)]
    punches: list[Punch] = []
    slips: list[Slip] = []
    for i, (kind, a, b) in enumerate(phases):
        if kind == "clinch":
            continue
        nxt = phases[i + 1][0] if i + 1 < len(phases) else None
        plan = _phase(kind, a, b, nxt, rng)
        evaded = _evasions(plan.punches, slips, rng)
        # Parries at straight-punch range only: at close range the gloves start in each other's way.
        punches += evaded if plan.close else parries(evaded, slips, parry_prob, rng_parry)
        d_keys += plan.d_keys
    return d_keys, _back_in_time(punches), slips


def _back_in_time(punches: list[Punch]) -> list[Punch]:
    """``punches`` (same order) with ``back_by_s`` set: each fist back in guard
    ``BACK_BY_MARGIN_S`` before the same athlete's same hand leaves again (feints included)."""
    out = list(punches)
    for person in (0, 1):
        for hand in ("left", "right"):
            mine = [i for i, p in enumerate(out) if p.person == person and p.hand == hand]
            idx = sorted(mine, key=lambda i: out[i].t0_s)
            for i, j in zip(idx[:-1], idx[1:], strict=False):
                back_by = out[j].t0_s - BACK_BY_MARGIN_S
                if out[i].end_s > back_by + 1e-9:
                    raise ValueError(
                        f"combos: person {person} {hand} {out[i].kind} at {out[i].t0_s:.3f} s ends at "
                        f"{out[i].end_s:.3f} s, after the same hand's {out[j].kind} leaves at {out[j].t0_s:.3f} s"
                    )
                out[i] = dataclasses.replace(out[i], back_by_s=back_by)
    return out
