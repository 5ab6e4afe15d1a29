"""``cornerman bench fit`` on a short bout: rows, timings and the printed table."""

from __future__ import annotations

import math

import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from pipeline.bench.fit import print_table, run_bench  # noqa: E402


def test_fit_bench_rows_time_the_fit_without_the_model_load(capsys: pytest.CaptureFixture[str]) -> None:
    rows = run_bench(n_frames=20, cameras=3, seed=1, shape_iters=5, pose_iters_3d=3, pose_iters=5)
    assert [r["method"] for r in rows] == ["triangulation (raw)", "triangulation (filtered)", "fit (anny)"]
    fit = rows[-1]
    assert fit["load_s"] >= 0.0 and math.isfinite(fit["load_s"])
    # the fit's own wall time covers its shape and pose passes, and frames/s/person derives from it
    assert fit["time_s"] >= fit["shape_s"] + fit["pose_s"] > 0.0
    assert fit["fps_per_person"] == pytest.approx(20 / (fit["time_s"] / 2), rel=1e-6)
    assert math.isfinite(fit["mpjpe_mm"]) and math.isfinite(fit["accel_vs_tri_pct"])
    print_table(rows)
    out = capsys.readouterr().out
    assert "model load s" in out and "fit (anny)" in out
