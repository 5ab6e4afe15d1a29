"""Ring zones on hand-made positions (with points exactly on the zone edges), the fatigue
slopes on made-up series, and both in the summary per athlete and per round."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from pipeline.schema.analytics import AthleteSeries, BoutEvents
from pipeline.stages.analyze import summarize
from pipeline.stages.analyze.fatigue import direction, slope_per_min, trends
from pipeline.stages.analyze.periods import bout_periods
from pipeline.stages.analyze.zones import (
    CENTRE_SCALE,
    CORNER_RADIUS_M,
    RING_ZONES,
    ROPES_BAND_M,
    centroid,
    ring_zones,
    zone_shares,
)

RING = np.array([[-3.0, -3.0], [3.0, -3.0], [3.0, 3.0], [-3.0, 3.0]])  # a 6 m ring, half-width 3 m


def _names(xy: list[tuple[float, float]], ring: np.ndarray = RING) -> list[str]:
    return [RING_ZONES[int(k)] for k in ring_zones(np.array(xy), ring)]


def test_zones_of_hand_made_positions_and_their_edges() -> None:
    assert (CENTRE_SCALE, ROPES_BAND_M, CORNER_RADIUS_M) == (0.5, 0.9, 1.5)  # the documented definition
    h = 3.0
    edge_centre = CENTRE_SCALE * h  # 1.5 m: the centre square's edge
    edge_ropes = h - ROPES_BAND_M  # 2.1 m from the middle = 0.9 m from the side
    assert _names([(0.0, 0.0), (1.0, -1.2)]) == ["centre", "centre"]
    assert _names([(edge_centre, 0.0), (edge_centre, -edge_centre)]) == [
        "centre",
        "centre",
    ]  # on the edge: in
    assert _names([(edge_centre + 0.01, 0.0), (2.0, 1.0), (-1.8, 0.3)]) == ["midring"] * 3
    assert _names([(edge_ropes, 0.0), (edge_ropes - 0.01, 0.0), (0.0, -2.9), (3.0, 0.5)]) == [
        "ropes", "midring", "ropes", "ropes",
    ]  # fmt: skip
    # corners: within 1.5 m of a post, exactly 1.5 m included; they win over the ropes
    d = CORNER_RADIUS_M / np.sqrt(2.0)
    assert _names([(3.0 - d, 3.0 - d), (3.0 - 1.5, 3.0), (-2.9, -2.9), (3.0 - 1.51, 3.0)]) == [
        "corners", "corners", "corners", "ropes",
    ]  # fmt: skip
    assert _names([(3.5, 0.0), (5.0, 0.0), (3.3, 3.3)]) == ["ropes", "outside", "corners"]
    # shapes carry through; a ring that is not a polygon is refused
    assert ring_zones(np.zeros((4, 2, 2)), RING).shape == (4, 2)
    assert centroid(RING + 10.0) == pytest.approx([10.0, 10.0])
    with pytest.raises(ValueError, match="ring_xy_m"):
        ring_zones(np.zeros((1, 2)), RING[:2])
    with pytest.raises(ValueError, match="no area"):
        ring_zones(np.zeros((1, 2)), np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]))


def test_a_ring_off_the_origin_and_small_rings() -> None:
    moved = RING * np.array([1.0, 0.5]) + np.array([10.0, -4.0])  # 6 x 3 m, centred at (10, -4)
    assert _names([(10.0, -4.0), (11.5, -4.0), (11.51, -4.0), (12.2, -4.0)], moved) == [
        "centre", "centre", "midring", "ropes",
    ]  # fmt: skip
    small = RING / 2.0  # half-width 1.5 m: the ropes band overlaps the centre square; ropes win
    assert _names([(0.0, 0.0), (0.7, 0.0), (1.0, 1.0)], small) == ["centre", "ropes", "corners"]


def test_zone_shares() -> None:
    zones = np.array([0, 0, 1, 2, 0, 4])
    valid = np.array([True, True, True, True, False, False])
    shares = zone_shares(zones, valid)
    assert shares == {"centre": 50.0, "ropes": 25.0, "corners": 25.0, "midring": 0.0, "outside": 0.0}
    assert zone_shares(zones, np.zeros(6, dtype=bool)) is None


def test_slopes_and_their_sign() -> None:
    t = np.array([1.5, 4.5, 7.5])  # three 3-minute rounds' middles
    assert slope_per_min(t, 8.0 - 0.2 * t) == pytest.approx(-0.2)
    assert slope_per_min(t, np.array([7.0, 7.6, 7.0])) == pytest.approx(0.0)
    noisy = np.array([6.9, 6.4, 6.1])
    assert slope_per_min(t, noisy) == pytest.approx(np.polyfit(t, noisy, 1)[0])
    assert slope_per_min(t[:1], noisy[:1]) is None and slope_per_min(np.ones(3), noisy) is None
    assert [direction(s) for s in (0.3, -0.01, 0.0004, -0.0004, None)] == [
        "rising", "falling", "flat", "flat", "unknown",
    ]  # fmt: skip
    per: list[dict[str, Any]] = [{"peak_speed_median_mps": 8.0, "guard_height_median_m": 0.05, "punches_per_min": 30.0},
           {"peak_speed_median_mps": None, "guard_height_median_m": 0.02, "punches_per_min": 20.0},
           {"peak_speed_median_mps": 7.0, "guard_height_median_m": -0.01, "punches_per_min": 20.0}]  # fmt: skip
    tr = trends([1.5, 4.5, 7.5], per)
    assert tr["peak_speed_median_mps"] == {"slope_per_min": pytest.approx(-1.0 / 6.0, abs=1e-3),
                                           "unit": "m/s per min", "trend": "falling", "periods": 2}  # fmt: skip
    assert (
        tr["guard_height_median_m"]["slope_per_min"] == pytest.approx(-0.01)
        and tr["punches_per_min"]["trend"] == "falling"
    )
    with pytest.raises(ValueError, match="period_s"):
        bout_periods(10.0, (), 0.0)


def _bout() -> tuple[BoutEvents, AthleteSeries]:
    """Two 30 s rounds with a 10 s break (70 s at 10 fps): athlete 0 at the ring's centre in
    round 1 and on the ropes in round 2, slower and with a lower guard in round 2; athlete 1
    in the corner throughout, position unknown for the last 10 s; one block by athlete 1."""
    fps, n = 10.0, 700
    t = np.arange(n) / fps
    pos = np.zeros((n, 2, 2))
    pos[t >= 40.0, 0] = [0.0, 2.5]
    pos[:, 1] = [2.8, 2.8]
    pos_ok = np.ones((n, 2), dtype=bool)
    pos_ok[t >= 60.0, 1] = False
    guard = np.zeros((n, 2, 2))
    guard[:, 0] = np.where(t[:, None] < 35.0, 0.04, -0.02)
    series = AthleteSeries(
        frame_indices=np.arange(n), fps=fps, person_ids=np.array([0, 1]), valid=np.ones((n, 2), bool),
        distance_m=np.full(n, 3.0), distance_valid=np.ones(n, bool), stance=np.ones((n, 2), np.int64),
        stance_width_m=np.full((n, 2), 0.5), guard_height_m=guard, punches_per_min=np.zeros((n, 2)),
        position_xy_m=pos, position_valid=pos_ok,
    )  # fmt: skip
    peaks = np.array([50, 100, 150, 450, 500])  # 3 punches in round 1, 2 in round 2
    speeds = np.array([8.0, 9.0, 7.0, 6.0, 6.4])
    k = peaks.size
    ev = BoutEvents.empty(fps, np.array([0, 1]))
    ev = BoutEvents(**{
        **ev.__dict__, "punch_person": np.zeros(k, np.int64), "punch_hand": np.full(k, "left"),
        "punch_type": np.full(k, "jab"), "punch_start_frame": peaks - 3, "punch_peak_frame": peaks,
        "punch_end_frame": peaks + 3, "punch_peak_speed_mps": speeds, "punch_extension": np.ones(k),
        "punch_target": np.full(k, "guard"), "punch_outcome": np.full(k, "blocked"), "punch_confidence": np.ones(k),
        "evade_person": np.array([1]), "evade_kind": np.array(["block"]), "evade_start_frame": np.array([449]),
        "evade_peak_frame": np.array([450]), "evade_end_frame": np.array([451]),
        "evade_displacement_m": np.array([0.01]), "evade_punch": np.array([3]),
    })  # fmt: skip
    return ev, series


def test_summary_ring_zones_blocks_and_fatigue_per_round() -> None:
    ev, series = _bout()
    s = summarize(
        ev, series, {0: "Red", 1: "Blue"}, ring_xy_m=RING.tolist(), rounds_s=((0.0, 30.0), (40.0, 70.0))
    )
    assert (
        s["ring_known"]
        and s["period_kind"] == "rounds"
        and [p["label"] for p in s["periods"]] == ["round 1", "round 2"]
    )
    red, blue = s["athletes"]
    assert red["ring_centre_pct"] == pytest.approx(400 / 7, abs=0.05) and red[
        "ring_ropes_pct"
    ] == pytest.approx(300 / 7, abs=0.05)
    assert (
        blue["ring_corners_pct"] == 100.0 and blue["ring_centre_pct"] == 0.0
    )  # over the 60 s he was located
    assert blue["blocks"] == 1 and blue["parries"] == 0 and red["blocks"] == 0
    r1, r2 = red["by_period"]
    assert (r1["ring_centre_pct"], r2["ring_ropes_pct"]) == (100.0, 100.0)
    assert (
        (r1["punches"], r2["punches"]) == (3, 2)
        and r1["peak_speed_median_mps"] == 8.0
        and r2["peak_speed_median_mps"] == 6.2
    )
    assert r1["punches_per_min"] == 6.0 and r2["punches_per_min"] == 4.0
    assert r1["guard_height_median_m"] == 0.04 and r2["guard_height_median_m"] == -0.02
    f = red["fatigue"]  # the rounds' middles are 0.25 and 0.917 min apart by 2/3 min
    assert f["peak_speed_median_mps"]["slope_per_min"] == pytest.approx(-1.8 / (2.0 / 3.0), abs=1e-3)
    assert (
        f["peak_speed_median_mps"]["trend"] == "falling" and f["guard_height_median_m"]["trend"] == "falling"
    )
    assert f["punches_per_min"]["slope_per_min"] == pytest.approx(-3.0, abs=1e-3)
    assert blue["by_period"][0]["blocks"] == 0 and blue["by_period"][1]["blocks"] == 1
    assert blue["fatigue"]["peak_speed_median_mps"]["trend"] == "unknown"  # he threw nothing
    # without the ring the zones are unknown; without rounds the periods are minutes
    bare = summarize(ev, series)
    assert not bare["ring_known"] and bare["athletes"][0]["ring_centre_pct"] is None
    assert bare["period_kind"] == "periods" and [p["label"] for p in bare["periods"]] == [
        "0:00–1:00",
        "1:00–1:10",
    ]
    assert sum(p["punches"] for p in bare["athletes"][0]["by_period"]) == 5
