"""Punches the body fit flattened, recovered from the filtered triangulation
(``pipeline.stages.analyze.motion``), on hand-made tracks: a jab nearly erased in the fit but
whole in the filtered track is found; a filtered spike or a drift without a two-view
measurement is not a punch."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.schema import Keypoints3D
from pipeline.stages.analyze import AnalyzeConfig, AnalyzeInputs, PunchConfig, run
from pipeline.stages.analyze.body import bodies, facing_frames
from pipeline.stages.analyze.motion import motion_failed
from pipeline.stages.analyze.punches import candidates, hand_track
from tests.stages.analyze_fixtures import J, keypoints, profile, straight, throw, two_boxers

N = 100
GUARD_L = np.array([0.3, 0.12, 1.45])
AT_HEAD = np.array([0.7, 0.0, 1.62])  # 0.3 m short of athlete 1's head, 1 m away
ON = PunchConfig(flattened=True)


def _jab(scale: float) -> np.ndarray:
    """Athlete 0 throws a left jab at 0.6 s (0.1 s out), ``scale`` of its full path."""
    xyz = two_boxers(N, distance_m=1.0)
    throw(xyz, 0, "left", profile(N, 0.6, 0.1), straight(GUARD_L, GUARD_L + scale * (AT_HEAD - GUARD_L)))
    return xyz


def _raw(xyz: np.ndarray, seen: np.ndarray | None = None) -> Keypoints3D:
    """Two-view raw triangulation of ``xyz``; ``seen`` (frames,) False where the left wrist
    was seen by one view only (no raw estimate)."""
    kp = keypoints(xyz, source="raw")
    valid = kp.valid.copy()
    if seen is not None:
        valid[:, 0, J["left_wrist"]] = seen
    return dataclasses.replace(kp, valid=valid, n_views=np.where(valid, 2, 0))


def _punches(
    fit: np.ndarray, filtered: np.ndarray | None, raw: Keypoints3D, cfg: PunchConfig = ON
) -> list[int]:
    inp = AnalyzeInputs(
        keypoints(fit), raw=raw, filtered=None if filtered is None else keypoints(filtered, "filtered")
    )
    ev = run(inp, AnalyzeConfig(punch=cfg)).events
    return ev.punch_peak_frame[(ev.punch_person == 0) & (ev.punch_hand == "left")].tolist()


def _failed(fit: np.ndarray, filtered: np.ndarray, raw: Keypoints3D) -> list[str | None]:
    """``motion_failed`` of every candidate of athlete 0's left fist on the filtered track."""
    cfg = ON
    fb, mb = bodies(keypoints(fit), cfg.max_gap_frames), bodies(keypoints(filtered), cfg.max_gap_frames)
    hf = hand_track(fb[0], *facing_frames(fb[0], fb[1]), "left", cfg)
    hm = hand_track(mb[0], *facing_frames(mb[0], mb[1]), "left", cfg)
    j = J["left_wrist"]
    rw = (raw.xyz_m[:, 0, j], raw.valid[:, 0, j], raw.n_views[:, 0, j])
    fit_cands = candidates(fb[0], hf, cfg)
    return [motion_failed(c, hf, hm, fit_cands, rw, cfg, fb[0].fps) for c in candidates(mb[0], hm, cfg)]


def test_a_jab_flattened_in_the_fit_is_found_on_the_filtered_track() -> None:
    fit, filtered = _jab(0.15), _jab(1.0)  # the fit's wrist moves 6 cm, the filtered 0.4 m
    raw = _raw(filtered)
    assert _punches(fit, None, raw) == []  # the fit alone misses it
    strikes = _punches(fit, filtered, raw)
    assert len(strikes) == 1 and abs(strikes[0] - 35) <= 3  # out from frame 30 to 35
    assert _failed(fit, filtered, raw) == [None]
    assert _punches(fit, filtered, raw, PunchConfig()) == []  # off by default


def test_a_jab_the_fit_keeps_is_not_counted_twice() -> None:
    xyz = _jab(1.0)
    raw = _raw(xyz)
    assert len(_punches(xyz, xyz.copy(), raw)) == 1
    assert _failed(xyz, xyz.copy(), raw) == ["new"]


def test_a_spike_of_the_filtered_track_is_not_a_punch() -> None:
    # The fit's fist stays in guard; the filtered (and raw) wrist jumps 0.35 m towards the
    # opponent for two frames: fast, forward, extended, but out in one frame.
    fit = two_boxers(N, distance_m=1.0)
    filtered = fit.copy()
    filtered[50:52, 0, J["left_wrist"]] += np.array([0.35, 0.0, 0.05])
    raw = _raw(filtered)
    assert _punches(fit, filtered, raw) == []
    assert _failed(fit, filtered, raw) == ["whole"]


def test_a_filtered_excursion_no_two_views_measured_is_not_a_punch() -> None:
    # The filtered track draws a jab where the wrist was seen by one view only (frames
    # 25-45 have no raw estimate): the fit, which saw the same 2D, kept it still.
    fit, filtered = _jab(0.0), _jab(1.0)
    seen = np.ones(N, dtype=bool)
    seen[25:46] = False
    raw = _raw(filtered, seen)
    assert _punches(fit, filtered, raw) == []
    assert _failed(fit, filtered, raw) == ["measured"]
    # Measured but slow (a raw peak under the threshold): still not recovered.
    slow = dataclasses.replace(ON, flattened_min_raw_speed_mps=20.0)
    assert _punches(fit, filtered, _raw(filtered), slow) == []


def test_flattened_config_is_checked() -> None:
    with pytest.raises(ValueError, match="flattened_max_ratio"):
        PunchConfig(flattened_max_ratio=1.5)
    with pytest.raises(ValueError, match="flattened_min_out_s"):
        PunchConfig(flattened_min_out_s=0.0)


def test_the_filtered_joints_are_matched_by_name() -> None:
    # The same flattened jab with the filtered result's joints in reverse order (and one
    # joint the punch rules do not use left out): found the same.
    fit, filtered = _jab(0.15), _jab(1.0)
    kp = keypoints(filtered, "filtered")
    keep = [j for j in range(len(kp.joint_names)) if kp.joint_names[j] != "nose"][::-1]
    shuffled = dataclasses.replace(
        kp, joint_names=tuple(kp.joint_names[j] for j in keep), xyz_m=kp.xyz_m[:, :, keep],
        valid=kp.valid[:, :, keep], confidence=kp.confidence[:, :, keep], n_views=kp.n_views[:, :, keep],
        reproj_err_px=kp.reproj_err_px[:, :, keep], filled=kp.filled[:, :, keep] if kp.filled.size else kp.filled,
    )  # fmt: skip
    ev = run(
        AnalyzeInputs(keypoints(fit), raw=_raw(filtered), filtered=shuffled), AnalyzeConfig(punch=ON)
    ).events
    assert ev.punch_peak_frame[(ev.punch_person == 0) & (ev.punch_hand == "left")].tolist() == _punches(
        fit, filtered, _raw(filtered)
    )
    assert ev.n_punches == 1


def test_the_fits_verdict_on_a_punchs_form_stands() -> None:
    # The fit sees the fist swing up from the hip (rejected: not thrown from the guard); the
    # filtered track draws the same motion starting higher, where it would pass every rule.
    # The fit saw that motion and judged its form: the filtered track does not overrule it.
    fit = two_boxers(N, distance_m=1.0)
    throw(fit, 0, "left", profile(N, 0.6, 0.1), straight(np.array([0.05, 0.2, 1.0]), AT_HEAD))
    filtered = _jab(1.0)
    raw = _raw(filtered)
    assert _punches(fit, filtered, raw) == []
    assert _failed(fit, filtered, raw) == ["new"]
