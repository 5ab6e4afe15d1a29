"""Punch types from the shape of the fist's path in shares of its chord (``classify``): a path
the 3D estimate shrinks keeps its type, a scoop is an uppercut even when it arrives flat or
bulges outwards, and a straight punch that sinks stays a body shot."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from pipeline.stages.analyze import AnalyzeInputs, TypeConfig, run
from pipeline.stages.analyze.classify import PathFeatures, path_features, punch_type
from tests.stages.analyze_fixtures import J, bezier, keypoints, minjerk, profile, straight, throw, two_boxers

GUARD = np.zeros(3)
# Left-hand paths from the guard (origin) in the facing frame (x forward, y left = outwards, z up), metres.
PATHS: dict[str, tuple[Callable[[np.ndarray], np.ndarray], float]] = {
    # (path, fist height at the strike over the opponent's hip-to-shoulder height)
    "lead_hook": (
        bezier(GUARD, np.array([0.1, 0.25, -0.02]), np.array([0.22, 0.28, 0.05]), np.array([0.3, 0.0, 0.05])),
        1.3,
    ),
    # drops from the guard and comes up into the chin, arriving lower than it started
    "lead_uppercut": (
        bezier(
            GUARD, np.array([0.02, 0.0, -0.18]), np.array([0.34, 0.05, -0.3]), np.array([0.42, 0.05, -0.05])
        ),
        1.0,
    ),
    "jab": (straight(GUARD, np.array([0.33, 0.0, 0.05])), 1.3),
    # drops first, then goes out to the body: it sags below its chord but does not climb
    "body_shot": (
        bezier(GUARD, np.array([0.0, 0.0, -0.3]), np.array([0.05, 0.0, -0.32]), np.array([0.3, 0.0, -0.3])),
        0.5,
    ),
}


def _features(kind: str, scale: float) -> tuple[str, PathFeatures]:
    path, level = PATHS[kind]
    r = scale * path(minjerk(np.linspace(0.0, 1.0, 8)))  # (frames, 3): the way out, 8 frames
    fastest = int(np.argmax(np.linalg.norm(np.diff(r, axis=0), axis=1)))
    f = path_features(
        r, 0, fastest, r.shape[0] - 1, "left", level, 0.0, 1.0
    )  # opponent's hips at 0, shoulders at 1 m
    return punch_type(f, True, TypeConfig()), f


@pytest.mark.parametrize("kind", sorted(PATHS))
@pytest.mark.parametrize("scale", [1.0, 0.3])
def test_a_shrunk_path_keeps_its_type(kind: str, scale: float) -> None:
    """A two-view fit moves the fist a fraction of the way: 0.3 of it leaves a hook 2-3 cm of
    bulge, under any absolute threshold that separates hooks from straight punches at full size."""
    got, f = _features(kind, scale)
    assert got == kind, (scale, f)


def test_a_sinking_straight_punch_is_no_uppercut() -> None:
    """The body shot's path sags below its chord as much as a scoop's: that it does not climb
    into the strike is what keeps it a body shot."""
    got, f = _features("body_shot", 1.0)
    cfg = TypeConfig()
    assert f.sag >= cfg.uppercut_min_sag and f.climb < cfg.uppercut_min_climb, f
    assert got == "body_shot"


def test_a_scoop_that_also_bulges_outwards_is_an_uppercut() -> None:
    """The fist drops, swings a little outwards and comes up into the target: the scoop decides."""
    path = bezier(
        GUARD, np.array([0.02, 0.12, -0.2]), np.array([0.25, 0.2, -0.3]), np.array([0.35, 0.05, 0.05])
    )
    r = path(minjerk(np.linspace(0.0, 1.0, 8)))
    fastest = int(np.argmax(np.linalg.norm(np.diff(r, axis=0), axis=1)))
    f = path_features(r, 0, fastest, 7, "left", 1.1, 0.0, 1.0)
    cfg = TypeConfig()
    assert f.bulge >= cfg.hook_min_bulge and f.sag >= cfg.uppercut_min_sag, f
    assert punch_type(f, True, cfg) == "lead_uppercut"
    assert punch_type(f, False, cfg) == "rear_uppercut"


def test_a_scooping_uppercut_that_arrives_flat_is_found_as_one() -> None:
    """End to end on hand-made boxers: the lead fist drops 0.2 m from the guard and comes up
    into the opponent's chin, its strike a little lower than its start and its arrival nearly
    level (the arrival-direction rule alone calls it a jab)."""
    n = 100
    xyz = two_boxers(n, distance_m=1.6)
    guard = xyz[0, 0, J["left_wrist"]].copy()
    path = bezier(guard, guard + [0.02, 0.0, -0.2], guard + [0.34, 0.05, -0.3], guard + [0.45, 0.05, -0.05])
    throw(xyz, 0, "left", profile(n, 0.6, 0.12), path)
    ev = run(AnalyzeInputs(keypoints(xyz))).events
    assert ev.n_punches == 1 and ev.punch_type.tolist() == ["lead_uppercut"], ev.punch_type


def test_a_rising_arrival_makes_an_uppercut_only_after_a_dip() -> None:
    """Both paths arrive steeply rising; the one that went straight up from the guard (the 3D
    estimate tilting a straight punch) is a jab or a cross, the one that dipped first an uppercut."""
    cfg = TypeConfig()
    frames = minjerk(np.linspace(0.0, 1.0, 8))
    tilted = straight(GUARD, np.array([0.15, 0.0, 0.22]))(frames)
    # dips a little (less than a scoop) before going up
    dipped = bezier(
        GUARD, np.array([0.03, 0.0, -0.04]), np.array([0.17, 0.0, 0.0]), np.array([0.2, 0.0, 0.22])
    )(frames)
    for r, lead, want in ((tilted, True, "jab"), (tilted, False, "cross"), (dipped, True, "lead_uppercut")):
        fastest = int(np.argmax(np.linalg.norm(np.diff(r, axis=0), axis=1)))
        f = path_features(r, 0, fastest, 7, "left", 1.2, 0.0, 1.0)
        assert f.rise >= cfg.uppercut_min_rise and f.sag < cfg.uppercut_min_sag, f
        assert punch_type(f, lead, cfg) == want, f


@pytest.mark.parametrize(
    "field", ["uppercut_min_sag", "uppercut_min_climb", "uppercut_min_rise", "hook_min_bulge"]
)
@pytest.mark.parametrize("value", [0.0, 1.0, -0.1])
def test_type_shares_outside_0_1_are_rejected(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        TypeConfig(**{field: value})
    if value != 0.0:
        with pytest.raises(ValueError, match="uppercut_rise_min_sag"):
            TypeConfig(uppercut_rise_min_sag=value)
