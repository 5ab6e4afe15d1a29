"""Blocks and parries: the defender's gloves and forearms meeting a punch (pure numpy).

Volumes are ``CapsuleProxy``'s (``pipeline.evaluate.glove_contact``): a glove is the sphere
around the fist, a forearm the elbow-wrist capsule; a gap is the distance between two volumes
minus their radii, and a gap up to ``OutcomeConfig.contact_tol_m`` is contact. Punches that
landed get neither (the glove reached the head or trunk first).

**Parry** (looked for first, on the way out: the punch's start to its strike): at the first
contact between a defender's glove and the punching forearm or glove,

1. that glove moves across the punch's line (horizontal, perpendicular to the line from the
   punching shoulder to the defender's head at the punch's start) at least
   ``DefenceConfig.parry_min_speed_mps`` (its mean lateral speed over the
   ``deflect_window_s`` before the contact), and
2. the punching glove is deflected the same way: over the ``deflect_window_s`` after the
   contact its sideways displacement exceeds what its sideways velocity before the contact
   would have carried it by at least ``parry_min_deflection_m``.

**Block** (otherwise): the punching glove and a defender's glove or forearm are in contact
within ``OutcomeConfig.window_frames`` of the strike.

When the physics stage ran (``OutcomeConfig.use_contacts``), its recorded contacts between
those bodies (``p{id}_{side}_hand`` = glove, ``p{id}_{side}_forearm``) decide where contact
is; where it recorded none between the two athletes in those frames, the 3D gaps do. The
movement tests of a parry always use the analysed 3D.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.evaluate.glove_contact import body_point, glove_volume
from pipeline.evaluate.physics_metrics import CapsuleProxy
from pipeline.geometry.segments import segment_distance
from pipeline.schema.results import PhysicsResult
from pipeline.stages.analyze.body import UP, Body
from pipeline.stages.analyze.config import AnalyzeConfig
from pipeline.stages.analyze.defence import Evade

FOREARM_RADIUS_M: float = next(
    r for a, b, r in CapsuleProxy().segments if (a, b) == ("left_elbow", "left_wrist")
)
"""Radius of the forearm capsule (metres), ``CapsuleProxy``'s."""

HANDS = ("left", "right")


def _body_part(name: str) -> tuple[int, str, str] | None:
    """(person id, side, part) of a humanoid body named ``p{id}_{side}_{part}``; None otherwise."""
    head, _, rest = name.partition("_")
    if not head.startswith("p") or not head[1:].isdigit():
        return None
    for side in HANDS:
        if rest.startswith(side + "_"):
            return int(head[1:]), side, rest[len(side) + 1 :]
    return int(head[1:]), "", rest


@dataclass(frozen=True)
class _Limb:
    """One athlete's glove sphere centre (frames, 3) and forearm (elbow, wrist) for a side."""

    glove: np.ndarray
    elbow: np.ndarray
    wrist: np.ndarray
    ok: np.ndarray
    r_glove: float


def _limb(body: Body, side: str) -> _Limb:
    point, r = glove_volume(side)
    ok = np.logical_and(body.point(f"{side}_elbow")[1], body.point(f"{side}_wrist")[1]).astype(bool)
    return _Limb(body_point(body.xyz, point, body.names), body.point(f"{side}_elbow")[0],
                 body.point(f"{side}_wrist")[0], ok, r)  # fmt: skip


def _gap_glove_to_limb(glove: np.ndarray, r_glove: float, limb: _Limb, rows: np.ndarray) -> np.ndarray:
    """(rows,) gap (m) between a glove sphere and the nearer of ``limb``'s glove and forearm."""
    g = glove[rows]
    to_glove = np.linalg.norm(g - limb.glove[rows], axis=1) - r_glove - limb.r_glove
    to_arm = segment_distance(g, g, limb.elbow[rows], limb.wrist[rows]) - r_glove - FOREARM_RADIUS_M
    return np.minimum(to_glove, to_arm)


def _physics_contacts(
    physics: PhysicsResult, frames: np.ndarray
) -> list[tuple[int, tuple[int, str, str], tuple[int, str, str]]]:
    """(video frame, part a, part b) of the recorded contacts between two athletes in ``frames``."""
    if physics.contact_frame.size == 0:
        return []
    video = physics.frame_indices[np.clip(physics.contact_frame, 0, physics.frame_indices.shape[0] - 1)]
    out = []
    for c in np.flatnonzero(np.isin(video, frames)):
        a, b = (_body_part(physics.body_names[int(i)]) for i in physics.contact_body[c])
        if a is not None and b is not None and a[0] != b[0]:
            out.append((int(video[c]), a, b))
    return out


def _contact_rows(
    pairs: list[tuple[int, tuple[int, str, str], tuple[int, str, str]]],
    frames: np.ndarray, me: tuple[int, str, tuple[str, ...]], other: tuple[int, tuple[str, ...]],
) -> np.ndarray:  # fmt: skip
    """Rows of ``frames`` (video frames) with a contact between ``me`` = (person, side, parts)
    and ``other`` = (person, parts) (either side)."""
    hit = set()
    for f, a, b in pairs:
        for x, y in ((a, b), (b, a)):
            if x[0] == me[0] and x[1] == me[1] and x[2] in me[2] and y[0] == other[0] and y[2] in other[1]:
                hit.add(f)
    return np.flatnonzero(np.isin(frames, sorted(hit)))


def _lateral_speed(x: np.ndarray, rows: np.ndarray, across: np.ndarray, fps: float) -> float:
    """Mean velocity (m/s) of ``x`` along ``across`` from the first to the last of ``rows``."""
    if rows.size < 2:
        return 0.0
    return float((x[rows[-1]] - x[rows[0]]) @ across * fps / (rows[-1] - rows[0]))


def _touch_rows(
    pairs: list[tuple[int, tuple[int, str, str], tuple[int, str, str]]], frames: np.ndarray, rows: np.ndarray,
    me: tuple[int, str, tuple[str, ...]], other: tuple[int, tuple[str, ...]], gaps: np.ndarray, tol: float,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(rows in contact, their gaps in m): the physics contacts when it recorded any between the
    athletes in ``rows``, else the 3D ``gaps`` (rows,) within ``tol``."""
    if any(f in set(frames[rows].tolist()) for f, _, _ in pairs):
        hit = _contact_rows(pairs, frames, me, other)
        hit = hit[np.isin(hit, rows)]
        return hit, np.zeros(hit.size)
    return rows[gaps <= tol], gaps[gaps <= tol]


def _deflection(
    glove: np.ndarray, c: int, before: np.ndarray, after: np.ndarray, across: np.ndarray, fps: float
) -> float:
    """Signed sideways displacement (m, along ``across``) of ``glove`` over ``after`` beyond what
    its sideways velocity over ``before`` (rows ending at the contact row ``c``) predicts."""
    v = _lateral_speed(glove, before, across, fps)
    return float((glove[after[-1]] - glove[c]) @ across) - v * (after[-1] - c) / fps


def _parry(
    punch: _Limb, guards: dict[str, _Limb], pairs: list[tuple[int, tuple[int, str, str], tuple[int, str, str]]],
    attacker_id: int, defender_id: int, start: int, peak: int, end: int, across: np.ndarray,
    frames: np.ndarray, k: int, fps: float, cfg: AnalyzeConfig,
) -> Evade | None:  # fmt: skip
    """The parry test of the module docstring on one set of limbs (rows ``start`` .. ``peak`` for
    the contact, ``k`` rows either side of it for the speeds), or None."""
    d, tol = cfg.defence, cfg.outcome.contact_tol_m
    out_rows = np.arange(start, peak + 1)
    for side, g in guards.items():
        ok = out_rows[g.ok[out_rows] & punch.ok[out_rows]]
        touch, _ = _touch_rows(pairs, frames, ok, (defender_id, side, ("hand",)),
                               (attacker_id, ("hand", "forearm")), _gap_glove_to_limb(g.glove, g.r_glove, punch, ok), tol)  # fmt: skip
        if touch.size == 0:
            continue
        c = int(touch[0])
        before = np.arange(max(start, c - k), c + 1)
        after = np.arange(c, min(end, c + k) + 1)
        if before.size < 2 or after.size < 2 or not (g.ok[before].all() and punch.ok[after].all() and punch.ok[before].all()):
            continue
        v_guard = _lateral_speed(g.glove, before, across, fps)
        deflection = _deflection(punch.glove, c, before, after, across, fps)
        if (abs(v_guard) >= d.parry_min_speed_mps and np.sign(deflection) == np.sign(v_guard)
                and abs(deflection) >= d.parry_min_deflection_m):  # fmt: skip
            return Evade("parry", int(before[0]), c, int(after[-1]), abs(deflection))
    return None


def defend(
    attacker: Body, defender: Body, hand: str, start: int, peak: int, end: int,
    physics: PhysicsResult | None, frames: np.ndarray, cfg: AnalyzeConfig,
    measured: tuple[Body, Body] | None = None,
) -> Evade | None:  # fmt: skip
    """The defender's parry or block of ``attacker``'s punch with ``hand`` (rows ``start`` ..
    ``peak`` .. ``end`` of the analysed ``frames``), or None (module docstring). Call it for
    punches that did not land. ``measured``: (attacker, defender) from the raw triangulation on
    the same rows; with ``DefenceConfig.parry_measured`` the parry test also runs on them."""
    n = attacker.n_frames
    tol, d = cfg.outcome.contact_tol_m, cfg.defence
    k = max(1, int(round(d.deflect_window_s * attacker.fps)))
    punch = _limb(attacker, hand)
    guards = {side: _limb(defender, side) for side in HANDS}
    sh, sok = attacker.point(f"{hand}_shoulder")
    head, hok = defender.point("mid:left_ear+right_ear")
    line = head[start] - sh[start] if (sok[start] and hok[start]) else np.zeros(3)
    line[2] = 0.0
    if np.linalg.norm(line) < 1e-6:
        return None
    across = np.cross(UP, line / np.linalg.norm(line))
    pairs = _physics_contacts(physics, frames) if physics is not None and cfg.outcome.use_contacts else []

    # Parry: first contact of a defender's glove with the punching forearm or glove on the way out,
    # in the analysed 3D, else in the raw triangulation (the fit pulls the gloves apart).
    sources = [(punch, guards, pairs)]
    if measured is not None and d.parry_measured:
        sources.append((_limb(measured[0], hand), {side: _limb(measured[1], side) for side in HANDS}, []))
    for p_limb, g_limbs, src_pairs in sources:
        parry = _parry(p_limb, g_limbs, src_pairs, attacker.person_id, defender.person_id, start, peak, end,
                       across, frames, k, attacker.fps, cfg)  # fmt: skip
        if parry is not None:
            return parry

    # Block: the punching glove on a defender's glove or forearm around the strike.
    w = cfg.outcome.window_frames
    rows = np.arange(max(0, peak - w), min(n, peak + w + 1))
    best: tuple[float, np.ndarray] | None = None
    for g in guards.values():
        ok = rows[g.ok[rows] & punch.ok[rows]]
        touch, gaps = _touch_rows(pairs, frames, ok, (attacker.person_id, hand, ("hand",)),
                                  (defender.person_id, ("hand", "forearm")), _gap_glove_to_limb(punch.glove, punch.r_glove, g, ok), tol)  # fmt: skip
        if touch.size and (best is None or gaps.min() < best[0]):
            best = (float(gaps.min()), touch[np.argsort(gaps, kind="stable")])
    if best is None:
        return None
    touch = best[1]
    c0, c1 = int(touch.min()), int(touch.max())
    before = np.arange(max(0, c0 - k), c0 + 1)
    after = np.arange(c0, min(n - 1, c0 + k) + 1)
    deflection = _deflection(punch.glove, c0, before, after, across, attacker.fps) if after.size >= 2 else 0.0
    return Evade("block", c0, int(touch[0]), c1, abs(deflection))


def deflection_at(
    attacker: Body, hand: str, defender: Body, start: int, contact: int, cfg: AnalyzeConfig
) -> float:
    """Sideways deflection (m, >= 0) of ``attacker``'s ``hand`` glove after a contact at row
    ``contact`` of his punch starting at row ``start`` (``_deflection``, across the line from
    his shoulder to ``defender``'s head at ``start``); 0 where the 3D does not tell."""
    k = max(1, int(round(cfg.defence.deflect_window_s * attacker.fps)))
    sh, sok = attacker.point(f"{hand}_shoulder")
    head, hok = defender.point("mid:left_ear+right_ear")
    punch = _limb(attacker, hand)
    before = np.arange(max(0, contact - k), contact + 1)
    after = np.arange(contact, min(attacker.n_frames - 1, contact + k) + 1)
    line = head[start] - sh[start]
    line[2] = 0.0
    if (
        not (sok[start] and hok[start] and punch.ok[before].all() and punch.ok[after].all())
        or min(before.size, after.size) < 2
    ):
        return 0.0
    if np.linalg.norm(line) < 1e-6:
        return 0.0
    across = np.cross(UP, line / np.linalg.norm(line))
    return abs(_deflection(punch.glove, contact, before, after, across, attacker.fps))
