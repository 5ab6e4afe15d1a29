"""A straight punch turned aside by a parry keeps its type (``classify``, issue 39).

The parry meets the glove halfway out and pushes it inwards: its path then bulges from its
chord as much as a hook's, but until the contact it heads at the opponent, where a hook swings
out from the start (``TypeConfig.hook_min_swing_deg``)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from pipeline.stages.analyze import AnalyzeInputs, TypeConfig, run
from pipeline.stages.analyze.classify import path_features, punch_type, swing_deg
from tests.stages.analyze_fixtures import J, bezier, keypoints, minjerk, profile, throw, two_boxers

CONTACT_AT = 0.45
"""Share of the way out at which the parry meets the glove (the synthetic bout: 0.4-0.5)."""


def deflected(
    start: np.ndarray, target: np.ndarray, hand: str, push_m: float = 0.19
) -> Callable[[np.ndarray], np.ndarray]:
    """The glove goes straight from ``start`` at ``target``; from ``CONTACT_AT`` of the way it is
    pushed ``push_m`` inwards (horizontally, across its line) and covers only 0.3 of the rest."""
    line = target - start
    inward = np.cross([0.0, 0.0, 1.0], line)
    inward *= (-1.0 if hand == "left" else 1.0) / np.linalg.norm(inward)

    def f(p: np.ndarray) -> np.ndarray:
        past = np.clip((p - CONTACT_AT) / (1.0 - CONTACT_AT), 0.0, 1.0)[:, None]
        reach = np.minimum(p, CONTACT_AT)[:, None] + 0.3 * (1.0 - CONTACT_AT) * past
        return start + reach * line + push_m * past * inward

    return f


# Relative to the thrower's neck in the facing frame (x towards the opponent, y left, z up), metres:
# the orthodox guard of ``analyze_fixtures`` and the point of the opponent's head the punches go at.
LEAD_GUARD, REAR_GUARD = np.array([0.3, 0.12, 0.0]), np.array([0.2, -0.1, 0.03])
HEAD = np.array([0.75, 0.0, 0.12])
HOOKS = {
    "left": bezier(LEAD_GUARD, np.array([0.4, 0.3, 0.02]), np.array([0.62, 0.28, 0.1]), HEAD),
    "right": bezier(REAR_GUARD, np.array([0.3, -0.22, 0.04]), np.array([0.58, -0.3, 0.1]), HEAD),
}


def _type(
    path: Callable[[np.ndarray], np.ndarray], hand: str, lead: bool, scale: float = 1.0
) -> tuple[str, float, float]:
    r = path(minjerk(np.linspace(0.0, 1.0, 8)))
    r = r[0] + scale * (r - r[0])  # a 2-view fit shortens the way out around its start
    fastest = int(np.argmax(np.linalg.norm(np.diff(r, axis=0), axis=1)))
    cfg = TypeConfig()
    f = path_features(r, 0, fastest, r.shape[0] - 1, hand, 1.3, 0.0, 1.0)
    return punch_type(f, lead, cfg), f.bulge, swing_deg(f, cfg)


@pytest.mark.parametrize("scale", [1.0, 0.5])
@pytest.mark.parametrize(("hand", "lead", "want"), [("left", True, "jab"), ("right", False, "cross")])
def test_a_straight_punch_turned_aside_halfway_keeps_its_type(
    hand: str, lead: bool, want: str, scale: float
) -> None:
    start = LEAD_GUARD if lead else REAR_GUARD
    got, bulge, swing = _type(deflected(start, HEAD, hand), hand, lead, scale)
    # the bulge alone would make it a hook: the heading before the contact decides
    assert bulge >= TypeConfig().hook_min_bulge, bulge
    assert got == want, (bulge, swing)


@pytest.mark.parametrize("scale", [1.0, 0.5])
@pytest.mark.parametrize(
    ("hand", "lead", "want"), [("left", True, "lead_hook"), ("right", False, "rear_hook")]
)
def test_a_hook_that_swings_out_from_the_guard_stays_a_hook(
    hand: str, lead: bool, want: str, scale: float
) -> None:
    got, bulge, swing = _type(HOOKS[hand], hand, lead, scale)
    assert got == want, (bulge, swing)


def test_a_parried_jab_and_a_hook_end_to_end() -> None:
    """On hand-made boxers (necks 1 m apart): a jab the opponent turns aside halfway, then a lead
    hook, then a parried cross, each typed from its path before the contact."""
    n = 160
    xyz = two_boxers(n, distance_m=1.0)
    neck = 0.5 * (xyz[0, 0, J["left_shoulder"]] + xyz[0, 0, J["right_shoulder"]])
    head = neck + HEAD
    jab = deflected(xyz[0, 0, J["left_wrist"]].copy(), head, "left")
    _throw_at(xyz, "left", profile(n, 0.3, 0.12), jab)
    _throw_at(xyz, "left", profile(n, 1.3, 0.14), lambda p: neck + HOOKS["left"](p))
    _throw_at(
        xyz, "right", profile(n, 2.3, 0.12), deflected(xyz[0, 0, J["right_wrist"]].copy(), head, "right")
    )
    ev = run(AnalyzeInputs(keypoints(xyz))).events
    mine = ev.punch_person == 0
    assert ev.punch_type[mine].tolist() == ["jab", "lead_hook", "cross"], (ev.punch_type, ev.punch_peak_frame)


def _throw_at(xyz: np.ndarray, hand: str, prof: np.ndarray, path: Callable[[np.ndarray], np.ndarray]) -> None:
    """``throw`` by athlete 0 over the frames where ``prof`` > 0 only (several punches of one hand)."""
    rows = prof > 0
    part = xyz[rows].copy()
    throw(part, 0, hand, prof[rows], path)
    xyz[rows] = part


@pytest.mark.parametrize(("field", "value"), [("hook_min_swing_deg", -1.0), ("hook_min_swing_deg", 90.0),
                                              ("aim_ahead_m", 0.2), ("aim_ahead_m", 5.0)])  # fmt: skip
def test_swing_settings_out_of_range_are_rejected(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        TypeConfig(**{field: value})
