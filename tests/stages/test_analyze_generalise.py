"""The analyze stage's glove speed along the analysed path, the clinch's arms-around test and the
two-view reach of the outcome test, on hand-made trajectories and boxers."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pipeline.stages.analyze import AnalyzeConfig, AnalyzeInputs, run
from pipeline.stages.analyze.config import DefenceConfig
from pipeline.stages.analyze.punches import raw_peak_speed
from tests.stages.analyze_fixtures import FPS, J, keypoints, minjerk, profile, straight, throw, two_boxers

GUARD_L = np.array([0.3, 0.12, 1.45])


def _speed(*args: object) -> float:
    """``raw_peak_speed(*args)``, which must measure one."""
    v = raw_peak_speed(*args)  # type: ignore[arg-type]
    assert v is not None
    return v


def _punch_path(n: int, reach_m: float, out_s: float) -> tuple[np.ndarray, float]:
    """(frames, 3) a wrist thrown reach_m along a slanted line in out_s (min-jerk) from frame 20,
    and its peak speed (m/s; a min-jerk move peaks at 1.875 x its mean speed)."""
    t = np.arange(n) / FPS
    u = np.array([0.8, 0.3, -0.2]) / np.linalg.norm([0.8, 0.3, -0.2])
    x = np.array([0.3, 0.1, 1.4]) + reach_m * minjerk((t - 20 / FPS) / out_s)[:, None] * u
    return x, 1.875 * reach_m / out_s


def test_raw_speed_along_the_path_recovers_a_noisy_punch() -> None:
    n, start, strike = 50, 20, 26
    x, truth = _punch_path(n, 0.4, 0.12)
    # The analysed path: the same line, shrunk and late as a smoothed fit's (only its direction is used).
    smooth, _ = _punch_path(n + 2, 0.28, 0.16)
    ok, views = np.ones(n, dtype=bool), np.full(n, 3)
    exact = _speed(x, ok, views, start, strike, FPS, smooth[:n])
    assert exact == pytest.approx(_speed(x, ok, views, start, strike, FPS), rel=1e-9)  # straight: along = norm
    assert exact == pytest.approx(truth, rel=0.05)
    # Error across the path (a two-view DLT's is stretched along the viewing rays, with outliers):
    # the projection drops it whole, the norm grows with it.
    rng = np.random.default_rng(0)
    u = np.diff(x, axis=0)[start]
    across = np.cross(u, [0.0, 0.0, 1.0]) / np.linalg.norm(np.cross(u, [0.0, 0.0, 1.0]))
    skewed = x + rng.normal(0.0, 0.06, (n, 1)) * across
    assert raw_peak_speed(skewed, ok, views, start, strike, FPS, smooth[:n]) == pytest.approx(exact, rel=1e-9)
    assert _speed(skewed, ok, views, start, strike, FPS) > 1.1 * exact
    # Isotropic noise (2 cm per axis): unbiased within 5 % over many throws.
    err = [_speed(x + rng.normal(0.0, 0.02, x.shape), ok, views, start, strike, FPS, smooth[:n]) / truth - 1
           for _ in range(300)]  # fmt: skip
    assert abs(float(np.mean(err))) < 0.05


def _clinch_boxers(n: int, arms_around: bool) -> np.ndarray:
    """Two boxers 0.4 m apart over frames 20-70 (1.5 m apart otherwise), with both wrists of each at
    the other's torso centre (around him) or kept up in the guard in front of their own face."""
    xyz = two_boxers(n, distance_m=1.5)
    inside = slice(20, 71)
    xyz[inside, 1, :, 0] -= 1.1
    if arms_around:
        for p, other in ((0, 1), (1, 0)):
            trunk = [J["left_shoulder"], J["right_shoulder"], J["left_hip"], J["right_hip"]]
            centre = xyz[inside, other][:, trunk].mean(axis=1)
            xyz[inside, p, J["left_wrist"]] = centre + np.array([0.0, 0.15, 0.1])
            xyz[inside, p, J["right_wrist"]] = centre + np.array([0.0, -0.15, 0.1])
    return xyz


def test_a_clinch_needs_the_arms_around_the_other() -> None:
    held = run(AnalyzeInputs(keypoints(_clinch_boxers(100, arms_around=True)))).events
    assert held.n_clinches == 1 and (int(held.clinch_start_frame[0]), int(held.clinch_end_frame[0])) == (20, 70)
    # Guards up between two close bodies: the wrists are within the wrap distance of the other's
    # torso centre (0.3 m) but stay in front of him; without the reach test this is a clinch.
    xyz = _clinch_boxers(100, arms_around=False)
    guard = run(AnalyzeInputs(keypoints(xyz))).events
    assert guard.n_clinches == 0 and guard.n_punches == 0
    no_reach = AnalyzeConfig(defence=DefenceConfig(clinch_reach_m=10.0))
    assert run(AnalyzeInputs(keypoints(xyz)), no_reach).events.n_clinches == 1
    with pytest.raises(ValueError, match="clinch_reach_m"):
        DefenceConfig(clinch_reach_m=-0.1)


def test_a_jab_the_two_view_fit_shortened_lands_by_the_filtered_glove() -> None:
    d, n = 1.0, 100
    head = np.array([d, 0.0, 1.62])
    end = head - np.array([0.1 + 0.065 + 0.05, 0.0, 0.0])  # the glove on the chin (as test_analyze)
    truth = two_boxers(n, distance_m=d)
    for hand, side in (("left", -1.0), ("right", 1.0)):  # the defender's guard is down
        for joint, drop in (("wrist", 0.35), ("elbow", 0.15)):
            truth[:, 1, J[f"{hand}_{joint}"]] += np.array([0.1, 0.1 * side, -drop])
    fit = truth.copy()
    throw(truth, 0, "left", profile(n, 0.6, 0.1), straight(GUARD_L, end))
    throw(fit, 0, "left", profile(n, 0.6, 0.1), straight(GUARD_L, end - np.array([0.09, 0.0, 0.0])))  # 9 cm short
    filtered = keypoints(truth, source="filtered")
    for views, want in ((2, "landed"), (4, "missed")):
        raw = keypoints(truth, source="raw")
        raw = replace(raw, n_views=np.full_like(raw.n_views, views))
        ev = run(AnalyzeInputs(keypoints(fit), raw=raw, filtered=filtered)).events
        assert ev.punch_outcome.tolist() == [want], views
    off = AnalyzeConfig(outcome=replace(AnalyzeConfig().outcome, filtered_reach=False))
    raw2 = replace(keypoints(truth, source="raw"), n_views=np.full((n, 2, truth.shape[2]), 2))
    assert run(AnalyzeInputs(keypoints(fit), raw=raw2, filtered=filtered), off).events.punch_outcome.tolist() == ["missed"]
