"""Defence: slips and ducks (the head leaving a punch's line) and clinches.

**Evasions.** For every punch at the head that did not land, the defender's head
(midpoint of the ears) is compared with where it was ``evade_before_s`` before the strike
(the defender reads the punch and moves first), with the horizontal part of his
footwork (the mid-hip's displacement) taken out. A sideways displacement across the
punch's line of at least ``slip_min_m`` is a slip, a drop of at least ``duck_min_m`` a duck
(whichever is larger relative to its threshold), at its largest up to 0.1 s after the strike.

**Clinches.** Frames where the torso centres (mean of shoulders and hips) are closer than
``clinch_torso_m`` and each athlete holds the other: a wrist within ``clinch_wrap_m`` of the
other's torso centre that reaches, along the line between the torso centres, at least as far
as that centre less ``clinch_reach_m`` (the arms go around him; a guard held up between two
close bodies stays in front of him); runs shorter than ``clinch_min_s`` are bridged when they
are gaps and dropped when they are clinches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.stages.analyze.body import UP, Body
from pipeline.stages.analyze.config import DefenceConfig


@dataclass(frozen=True)
class Evade:
    """One slip or duck: rows of the analysed frames, the displacement in metres."""

    kind: str
    start: int
    peak: int
    end: int
    displacement_m: float


def evade(
    defender: Body, attacker: Body, hand: str, start: int, peak: int, cfg: DefenceConfig
) -> Evade | None:
    """The defender's slip or duck of the punch thrown with ``hand`` from ``start`` to
    ``peak`` (rows); None when the head stayed on the line."""
    head, hok = defender.point("mid:left_ear+right_ear")
    hip, pok = defender.point("mid:left_hip+right_hip")
    sh, sok = attacker.point(f"{hand}_shoulder")
    n = defender.n_frames
    k0 = max(0, min(start, peak - int(round(cfg.evade_before_s * defender.fps))))
    k1 = min(n - 1, peak + int(round(0.1 * defender.fps)))
    if not (hok[k0] and pok[k0] and sok[k0]):
        return None
    u = head[k0] - sh[k0]
    u[2] = 0.0
    if np.linalg.norm(u) < 1e-6:
        return None
    u /= np.linalg.norm(u)
    across = np.cross(UP, u)
    rows = np.arange(k0, k1 + 1)
    d = head[rows] - head[k0]
    d[:, :2] -= hip[rows, :2] - hip[k0, :2]
    side = np.abs(d @ across)
    down = -d[:, 2]
    score = np.where(hok[rows] & pok[rows], np.maximum(side / cfg.slip_min_m, down / cfg.duck_min_m), 0.0)
    i = int(np.argmax(score))
    if score[i] < 1.0:
        return None
    kind = "duck" if down[i] / cfg.duck_min_m >= side[i] / cfg.slip_min_m else "slip"
    amount = float(down[i] if kind == "duck" else side[i])
    lo = i
    while lo > 0 and score[lo - 1] >= 0.3 * score[i]:
        lo -= 1
    hi = i
    while hi + 1 < rows.size and score[hi + 1] >= 0.3 * score[i]:
        hi += 1
    return Evade(kind, int(rows[lo]), int(rows[i]), int(rows[hi]), amount)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1).tolist(), (np.flatnonzero(d == -1) - 1).tolist(), strict=True))


def clean_runs(mask: np.ndarray, min_len: int) -> np.ndarray:
    """``mask`` with interior gaps shorter than ``min_len`` filled, then runs shorter than
    ``min_len`` removed."""
    out = mask.copy()
    runs = _runs(out)
    for (_, e0), (s1, _) in zip(runs[:-1], runs[1:], strict=True):
        if s1 - e0 - 1 < min_len:
            out[e0 + 1 : s1] = True
    for s, e in _runs(out):
        if e - s + 1 < min_len:
            out[s : e + 1] = False
    return out


def clinch_frames(a: Body, b: Body, cfg: DefenceConfig, arms_around: bool = True) -> np.ndarray:
    """(frames,) bool: the two athletes clinch (see the module docstring). ``arms_around=False``
    drops the reach condition: the bodies are close and each has a hand at the other's torso
    (taking, holding or leaving a grip)."""
    names = ("left_shoulder", "right_shoulder", "left_hip", "right_hip")
    pts = [[body.point(n) for n in names] for body in (a, b)]
    centre = [np.mean([p for p, _ in ps], axis=0) for ps in pts]
    ok = np.logical_and.reduce([k for ps in pts for _, k in ps])
    gap = np.linalg.norm(centre[1] - centre[0], axis=1)
    close = gap < cfg.clinch_torso_m
    wraps = []
    for me, mine, other in ((a, 0, 1), (b, 1, 0)):
        towards = (centre[other] - centre[mine]) / np.maximum(gap, 1e-9)[:, None]
        near = np.zeros(a.n_frames, dtype=bool)
        for hand in ("left", "right"):
            w, wok = me.point(f"{hand}_wrist")
            reach = np.sum((w - centre[mine]) * towards, axis=1)
            holds = np.linalg.norm(w - centre[other], axis=1) < cfg.clinch_wrap_m
            if arms_around:
                holds &= reach >= gap - cfg.clinch_reach_m
            near |= wok & holds
        wraps.append(near)
    raw = ok & close & wraps[0] & wraps[1]
    return clean_runs(raw, max(1, int(round(cfg.clinch_min_s * a.fps))))


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Inclusive (start, end) rows of the True runs of ``mask``."""
    return _runs(mask)
