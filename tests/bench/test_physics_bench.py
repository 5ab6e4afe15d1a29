"""``cornerman bench physics`` table helpers: target deltas and the mean over seeds."""

from __future__ import annotations

import math

import pytest

from pipeline.bench.physics import mean_over_seeds, run_bench, with_deltas


def _row(method: str, seed: int, pen: float, skate: float, mpjpe: float) -> dict:
    return {
        "method": method,
        "seed": seed,
        "inter_penetration_max_mm": pen,
        "foot_skate_mm_per_frame": skate,
        "mpjpe_mm": mpjpe,
        "residual_windows": "3/3",
    }


def test_deltas_are_against_the_kinematic_row_of_the_same_seed() -> None:
    rows = with_deltas(
        [
            _row("kinematic (fit)", 0, 100.0, 2.0, 10.0),
            _row("physics (multi, bodyfit mesh)", 0, 20.0, 0.5, 11.0),
            _row("kinematic (fit)", 1, 50.0, 0.0, 20.0),
            _row("physics (multi, bodyfit mesh)", 1, 60.0, 1.0, 10.0),
        ]
    )
    assert "d_pen_max_pct" not in rows[0]
    assert rows[1]["d_pen_max_pct"] == pytest.approx(-80.0)
    assert rows[1]["d_skate_pct"] == pytest.approx(-75.0)
    assert rows[1]["d_mpjpe_pct"] == pytest.approx(10.0)
    assert rows[3]["d_pen_max_pct"] == pytest.approx(20.0)
    assert rows[3]["d_mpjpe_pct"] == pytest.approx(-50.0)
    assert math.isnan(rows[3]["d_skate_pct"])  # no skating in the input: no ratio
    assert "d_body_pen_max_pct" not in rows[1]  # no body penetration in these rows


def test_body_penetration_delta_when_both_rows_have_it() -> None:
    kin = {**_row("kinematic (fit)", 0, 100.0, 2.0, 10.0), "body_pen_max_mm": 90.0}
    phys = {**_row("physics (multi, bodyfit mesh)", 0, 50.0, 1.0, 12.0), "body_pen_max_mm": 30.0}
    rows = with_deltas([kin, phys])
    assert rows[1]["d_body_pen_max_pct"] == pytest.approx(-100.0 * 2 / 3)
    assert rows[1]["d_pen_max_pct"] == pytest.approx(-50.0)


def test_mean_over_seeds_averages_numbers_per_method() -> None:
    rows = [
        _row("kinematic (fit)", 0, 100.0, 2.0, 10.0),
        _row("physics (multi)", 0, 20.0, 1.0, 40.0),
        _row("kinematic (fit)", 1, 50.0, 4.0, 20.0),
        _row("physics (multi)", 1, 60.0, 3.0, 50.0),
    ]
    mean = mean_over_seeds(rows)
    assert [m["method"] for m in mean] == ["kinematic (fit)", "physics (multi)"]
    assert mean[1]["inter_penetration_max_mm"] == pytest.approx(40.0)
    assert mean[1]["mpjpe_mm"] == pytest.approx(45.0)
    assert mean[0]["seed"] == "mean of 2"
    assert "residual_windows" not in mean[0]  # text columns are not averaged


@pytest.mark.parametrize("seeds", ["abc", [], [0.5], [True]])
def test_bad_seeds_are_refused_before_any_work(seeds: object) -> None:
    with pytest.raises(ValueError, match="seeds must be a non-empty list of integers"):
        run_bench(seeds=seeds)  # type: ignore[arg-type]
