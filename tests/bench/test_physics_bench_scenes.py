"""``cornerman bench physics`` with ``scenes``: a DeepMimic scene runs through the same
rows and metrics as the synthetic bout; deltas and seed means stay within a scene.

The bench call uses the triangulation input (~15 s for 30 frames; the fit would double
it) and needs pybullet (the dev extra) for the DeepMimic clips."""

from __future__ import annotations

import importlib.util
import math

import pytest

from pipeline.bench.physics import mean_over_seeds, run_bench, with_deltas


@pytest.mark.skipif(
    importlib.util.find_spec("pybullet_data") is None, reason="pybullet (DeepMimic clips) not installed"
)
def test_a_deepmimic_scene_gives_every_row_with_finite_errors() -> None:
    rows = run_bench(
        n_frames=30, kinematic="triangulation", modes=("multi",), scenes=("deepmimic:punch+walk",)
    )
    assert [r["method"].split(" (")[0] for r in rows] == ["ground truth", "kinematic", "physics"]
    assert all(r["scene"] == "deepmimic:punch+walk" for r in rows)
    assert rows[0]["mpjpe_mm"] == 0.0
    for r in rows[1:]:
        assert math.isfinite(r["mpjpe_mm"]) and 0.0 < r["mpjpe_mm"] < 300.0, r["method"]
    phys = rows[2]
    for key in (
        "foot_skate_mm_per_frame",
        "ground_penetration_max_mm",
        "residual_mean_frac_bw",
        "realtime_factor",
    ):
        assert math.isfinite(phys[key]), key
    assert math.isfinite(phys["d_mpjpe_pct"])  # against the kinematic row of the same scene


@pytest.mark.parametrize("scenes", [["synthetic", "dance"], ["deepmimic:punch+moonwalk"], [], [3]])
def test_bad_scenes_are_refused_before_any_work(scenes: object) -> None:
    with pytest.raises(ValueError, match="scene"):
        run_bench(scenes=scenes)  # type: ignore[arg-type]


def _row(scene: str, method: str, seed: int, mpjpe: float) -> dict:
    return {"scene": scene, "method": method, "seed": seed, "mpjpe_mm": mpjpe}


def test_deltas_and_means_stay_within_a_scene() -> None:
    rows = with_deltas(
        [
            _row("synthetic", "kinematic (fit)", 0, 10.0),
            _row("synthetic", "physics (multi)", 0, 12.0),
            _row("deepmimic:kick+spin", "kinematic (fit)", 0, 20.0),
            _row("deepmimic:kick+spin", "physics (multi)", 0, 10.0),
            _row("synthetic", "kinematic (fit)", 1, 30.0),
            _row("synthetic", "physics (multi)", 1, 30.0),
            _row("deepmimic:kick+spin", "kinematic (fit)", 1, 40.0),
            _row("deepmimic:kick+spin", "physics (multi)", 1, 60.0),
        ]
    )
    assert rows[1]["d_mpjpe_pct"] == pytest.approx(20.0)
    assert rows[3]["d_mpjpe_pct"] == pytest.approx(-50.0)
    assert rows[7]["d_mpjpe_pct"] == pytest.approx(50.0)
    mean = mean_over_seeds(rows)
    assert [(m["scene"], m["method"]) for m in mean] == [
        ("synthetic", "kinematic (fit)"),
        ("synthetic", "physics (multi)"),
        ("deepmimic:kick+spin", "kinematic (fit)"),
        ("deepmimic:kick+spin", "physics (multi)"),
    ]
    assert mean[1]["mpjpe_mm"] == pytest.approx(21.0)
    assert mean[3]["mpjpe_mm"] == pytest.approx(35.0)
    assert mean[3]["d_mpjpe_pct"] == pytest.approx(0.0)
    assert mean[0]["seed"] == "mean of 2"
