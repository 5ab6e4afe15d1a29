"""The fit reports its L-BFGS iterations, and says so before the slow first build of anny."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.runner.steps.fit import _loading_message
from pipeline.stages.fit_config import FitConfig
from tests.conftest import fit_stage_inputs, make_rig


class Stop(Exception):
    pass


def test_first_fit_announces_the_anny_cache_build(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ANNY_CACHE_DIR", str(tmp_path / "anny"))
    assert "building the anny model cache" in _loading_message(FitConfig())
    assert str(tmp_path / "anny") in _loading_message(FitConfig())
    (tmp_path / "anny" / "v14").mkdir(parents=True)
    (tmp_path / "anny" / "v14" / "load_data_0123.safetensors").write_bytes(b"x")
    assert _loading_message(FitConfig()) == "loading the anny body model"


def test_the_fit_step_and_the_cache_check_do_not_import_torch() -> None:
    code = (
        "import sys, pipeline.runner.steps.fit, pipeline.backends.anny.cache as c\n"
        "c.anny_cache_built()\n"
        "print('torch' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.strip() == "False"


def _small_fit_inputs():  # noqa: ANN202
    pytest.importorskip("torch")
    pytest.importorskip("anny")
    from pipeline.synthetic.anny_motion import make_anny_motion

    rig = make_rig(3, fps=50.0, phase_rad=0.4)
    motion = make_anny_motion(6, fps=50.0, seed=3)
    xyz = motion.keypoints_m[:, None]  # (F, 1, J, 3)
    return rig, fit_stage_inputs(rig, xyz, 50.0)


def test_progress_advances_by_lbfgs_iteration() -> None:
    from pipeline.stages.fit import run

    rig, (kp3d, tracks, assoc) = _small_fit_inputs()
    cfg = FitConfig(shape_iters=3, pose_iters_3d=4, pose_iters=5)
    calls: list[tuple[float, float | None, str]] = []
    res = run(kp3d, tracks, assoc, rig, cfg, progress=lambda d, t, m: calls.append((d, t, m)))
    assert res.bodyfit.valid.any()
    total = cfg.shape_iters + cfg.pose_iters_3d + cfg.pose_iters
    assert {t for _, t, _ in calls} == {total}
    done = [d for d, _, _ in calls]
    assert done == sorted(done) and done[-1] == total
    assert len(set(done)) >= 6  # many steps, not just 0 % and 100 %
    assert all(m.startswith("L-BFGS iteration") for _, _, m in calls)
    # reporting reads the optimiser's counter only: the result is the same without it
    assert np.array_equal(run(kp3d, tracks, assoc, rig, cfg).bodyfit.pose, res.bodyfit.pose)


def test_progress_may_stop_the_fit() -> None:
    from pipeline.stages.fit import run

    rig, (kp3d, tracks, assoc) = _small_fit_inputs()
    seen: list[float] = []

    def stop_after_two(done: float, total: float | None, message: str) -> None:
        seen.append(done)
        if len(seen) > 2:
            raise Stop

    with pytest.raises(Stop):
        run(kp3d, tracks, assoc, rig, FitConfig(shape_iters=3, pose_iters_3d=4, pose_iters=5), progress=stop_after_two)
    assert len(seen) == 3 and np.all(np.diff(seen) >= 0)
