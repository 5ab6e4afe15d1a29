"""The punch rules on the raw triangulation's measured glove speed (``PunchConfig``
``min_measured_speed_mps`` and ``fast_measured_mps``), on hand-made jabs whose analysed and raw
tracks disagree the way a slow feint and a fit from two views make them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.schema.analytics import BoutEvents
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.stages.analyze import AnalyzeConfig, AnalyzeInputs, PunchConfig, run
from pipeline.stages.analyze.body import bodies, facing_frames
from pipeline.stages.analyze.punches import candidates, hand_track, rule_failed
from pipeline.stages.analyze.stage import _raw_wrists
from tests.stages.analyze_fixtures import keypoints, profile, straight, throw, two_boxers

N = 100
GUARD_L = np.array([0.3, 0.12, 1.45])
TARGET = np.array([0.7, 0.0, 1.62])  # 0.3 m short of athlete 1's head, 1 m away
REACH_M = float(np.linalg.norm(TARGET - GUARD_L))


def _jab(out_s: float, t0_s: float = 0.6) -> np.ndarray:
    """(frames, 2, 23, 3) athlete 0 jabs from the guard towards athlete 1's head in ``out_s``
    (min-jerk: peak speed 1.875 x reach / out_s), holds 0.1 s and comes back slower."""
    xyz = two_boxers(N, distance_m=1.0)
    throw(xyz, 0, "left", profile(N, t0_s, out_s, hold_s=0.1, back_s=0.5), straight(GUARD_L, TARGET))
    return xyz


def _raw(xyz: np.ndarray, unseen: slice = slice(0, 0)) -> Keypoints3D:
    """``xyz`` as a raw triangulation from two views, without any joint in frames ``unseen``."""
    raw = keypoints(xyz, "raw")
    valid = raw.valid.copy()
    valid[unseen] = False
    return dataclasses.replace(raw, n_views=np.where(valid, 2, 0), valid=valid)


def _rules(
    fit: np.ndarray, raw: np.ndarray | None, cfg: PunchConfig = PunchConfig(), unseen: slice = slice(0, 0)
) -> list[str | None]:
    """First failed rule of each candidate of athlete 0's left fist, the raw track's speed measured."""
    kp = keypoints(fit)
    bs = bodies(kp, cfg.max_gap_frames)
    R, ok = facing_frames(bs[0], bs[1])
    h = hand_track(bs[0], R, ok, "left", cfg)
    tracks = _raw_wrists(_raw(raw, unseen), kp, 0) if raw is not None else {}
    return [rule_failed(c, cfg, bs[0].fps) for c in candidates(bs[0], h, cfg, None, tracks.get("left"))]


def _events(fit: np.ndarray, raw: np.ndarray | None, cfg: PunchConfig = PunchConfig()) -> BoutEvents:
    inp = AnalyzeInputs(keypoints(fit), raw=_raw(raw) if raw is not None else None)
    return run(inp, AnalyzeConfig(punch=cfg)).events


def test_a_slow_jab_the_raw_triangulation_measures_slow_is_no_punch() -> None:
    # 3.5 m/s: fast enough for the rules on the analysed track (3 m/s), as slow as a feint or a
    # glove moved up to block; measured so by the raw triangulation, it is rejected.
    slow = _jab(out_s=1.875 * REACH_M / 3.5)
    assert _rules(slow, None) == [None]  # without a measurement the analysed rules decide
    assert _events(slow, None).n_punches == 1
    assert _rules(slow, slow) == ["measured_speed"]
    assert _events(slow, slow).n_punches == 0
    assert _rules(slow, slow, PunchConfig(min_measured_speed_mps=3.0)) == [None]
    # Where the raw triangulation lost the wrist on the way out (a gap bridged by a straight line
    # reads low), its speed does not reject.
    assert _rules(slow, slow, unseen=slice(36, 38)) == [None]
    # A real jab (8 m/s) measured as fast stays a punch, its speed the measured one.
    fast = _jab(out_s=1.875 * REACH_M / 8.0)
    assert _rules(fast, fast) == [None]
    ev = _events(fast, fast)
    assert ev.n_punches == 1 and ev.punch_peak_speed_mps[0] > PunchConfig().min_measured_speed_mps


def test_a_jab_the_fit_slowed_passes_the_speed_rules_on_its_raw_speed() -> None:
    # The analysed track (a fit from two views) moves the fist the whole way, but at 2.9 m/s; the
    # raw triangulation sees it arrive in 0.1 s (~8 m/s, kept within twice the analysed speed).
    slowed = _jab(out_s=1.875 * REACH_M / 2.9)
    raw = _jab(out_s=0.1, t0_s=0.68)
    assert _rules(slowed, None) == ["peak_speed"]
    assert _events(slowed, None).n_punches == 0
    assert _rules(slowed, raw) == [None]
    ev = _events(slowed, raw)
    assert ev.n_punches == 1
    assert PunchConfig().fast_measured_mps <= ev.punch_peak_speed_mps[0] <= 2.0 * 2.9 + 0.1
    # Above the threshold only: a raw track as slow as the fit rescues nothing.
    assert _rules(slowed, raw, PunchConfig(fast_measured_mps=99.0)) == ["peak_speed"]
    assert _rules(slowed, slowed) == ["peak_speed"]


def test_measured_speed_thresholds_are_checked() -> None:
    with pytest.raises(ValueError, match="min_measured_speed_mps"):
        PunchConfig(min_measured_speed_mps=-1.0)
    with pytest.raises(ValueError, match="fast_measured_mps"):
        PunchConfig(fast_measured_mps=0.0)
    with pytest.raises(ValueError, match="fast_min_excursion_m"):
        PunchConfig(fast_min_excursion_m=0.0)


def test_a_short_jab_measured_fast_needs_a_smaller_excursion() -> None:
    # A jab going 0.25 m from the guard estimate, against an excursion threshold of 0.3 m (a fist
    # shortened by a two-view fit, or a guard estimate pulled out by a fist held at the target
    # before): too short for a punch, unless the raw triangulation measures it fast.
    cfg = PunchConfig(min_excursion_m=0.3)
    end = GUARD_L + 0.25 * (TARGET - GUARD_L) / REACH_M
    xyz = two_boxers(N, distance_m=1.0)
    throw(xyz, 0, "left", profile(N, 0.6, 1.875 * 0.25 / 8.0, hold_s=0.1, back_s=0.5), straight(GUARD_L, end))
    assert _rules(xyz, None, cfg) == []  # no candidate without a measured speed
    assert _events(xyz, None, cfg).n_punches == 0
    assert _rules(xyz, xyz, cfg) == [None]
    assert _events(xyz, xyz, cfg).n_punches == 1
    assert _rules(xyz, xyz, dataclasses.replace(cfg, fast_min_excursion_m=0.3)) == []
    # The same move at a feint's speed (3 m/s) is a candidate only.
    slow = two_boxers(N, distance_m=1.0)
    throw(
        slow, 0, "left", profile(N, 0.6, 1.875 * 0.25 / 3.0, hold_s=0.1, back_s=0.5), straight(GUARD_L, end)
    )
    assert _rules(slow, slow, cfg) == ["excursion"]
    assert _events(slow, slow, cfg).n_punches == 0
