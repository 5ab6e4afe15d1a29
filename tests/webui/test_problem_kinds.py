"""The viewer's problem flags of every kind (``FLAG_KINDS``), the physics residual plot, and
problems.npz files written before the physics kinds existed."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import viser

from pipeline.artifacts import ArtifactStore, Manifest
from pipeline.stages.evaluate import FLAG_KINDS, LEGACY_FLAG_KINDS, ProblemFlags
from tests.webui.fixtures import build_session
from webui.analysis import compute_problems, compute_series
from webui.app import ViewerApp
from webui.panels.plots import RESIDUAL_TITLE
from webui.panels.timeline import ANY_PROBLEM, kind_options
from webui.scene.session_data import load_session_data

N = 12


def _write_problems(sdir: Path, arrays: dict[str, np.ndarray], metrics: dict | None = None) -> None:
    outputs: dict = {"problems": arrays}
    if metrics is not None:
        outputs["metrics.json"] = json.dumps(metrics)
    ArtifactStore(sdir).write(
        Manifest(stage="evaluate", code_version="t", config={}, config_hash="0", inputs={}), outputs
    )


def _effort_flags() -> ProblemFlags:
    """Residual over the cap at frames 7-8 (one problem), a joint over its limit at frame 2."""
    res = np.zeros(N)
    res[[7, 8]] = [0.09, 0.12]
    tau = np.full(N, 0.5)
    tau[2] = 1.4
    keys = [k.key for k in FLAG_KINDS]
    flags = np.zeros((N, len(FLAG_KINDS)), bool)
    flags[:, keys.index("residual_high")] = res > 0.05
    flags[:, keys.index("torque_high")] = tau > 1.0
    z = np.zeros(N)
    return ProblemFlags(np.arange(N), np.ones(N), z, z, z, flags, np.array(keys), res, tau)


def _legacy_arrays() -> dict[str, np.ndarray]:
    """A problems.npz of the three original kinds, without the kinds' names or the effort."""
    flags = np.zeros((N, len(LEGACY_FLAG_KINDS)), bool)
    flags[4, 0] = True  # identity low at frame 4
    z = np.zeros(N)
    return {"frame_indices": np.arange(N), "identity_conf_min": np.ones(N), "reproj_err_px": z,
            "penetration_mm": z, "reproj_rel": z, "flags": flags}  # fmt: skip


def test_frame_problems_list_the_physics_kinds(tmp_path: Path) -> None:
    sdir = build_session(tmp_path, n_frames=N, physics=True)
    _write_problems(sdir, _effort_flags().to_arrays(), {"physics_residual_high_frac_bw": 0.07})
    d = load_session_data(sdir)
    p = compute_problems(d)
    assert np.flatnonzero(p.of("residual_high")).tolist() == [7, 8]
    assert np.flatnonzero(p.of("torque_high")).tolist() == [2]
    assert p.kinds_at(8) == ["residual root force high"] and p.kinds_at(2) == [
        "joint torque over human limit"
    ]
    assert p.next_after(0) == 2 and p.next_after(2) == 7
    assert p.next_after(0, "residual_high") == 7 and p.next_after(7, "residual_high") == 7  # one run, wraps
    assert p.next_after(0, "identity_low") is None
    with pytest.raises(ValueError, match="unknown problem kind 'tired'"):
        p.of("tired")
    opts = kind_options(p)
    assert opts[0] == ANY_PROBLEM and len(opts) == 1 + len(FLAG_KINDS)
    assert "residual root force high (2)" in opts and "joint torque over human limit (1)" in opts
    s = compute_series(d, "filtered")
    assert s is not None and s.residual_frac_bw is not None
    np.testing.assert_allclose(s.residual_frac_bw, _effort_flags().residual_frac_bw)
    assert s.residual_cap_frac_bw == 0.07  # the evaluate stage's threshold, from metrics.json


def test_old_three_column_problems_load(tmp_path: Path) -> None:
    sdir = build_session(tmp_path, n_frames=N, physics=True)
    _write_problems(sdir, _legacy_arrays())
    d = load_session_data(sdir)
    assert d.problems is not None and d.problems.flags.shape == (N, 3)
    p = compute_problems(d)
    assert np.flatnonzero(p.of("identity_low")).tolist() == [4]
    assert not p.of("residual_high").any() and not p.of("torque_high").any()
    s = compute_series(d, "filtered")
    assert s is not None and s.residual_frac_bw is None  # nothing to plot: no effort in the file


def test_viewer_next_problem_by_kind_and_the_residual_plot(tmp_path: Path, server: viser.ViserServer) -> None:
    sdir = build_session(tmp_path, n_frames=N, physics=True)
    _write_problems(sdir, _effort_flags().to_arrays())
    app = ViewerApp(server, sdir, role="coach", max_image_width=160)
    try:
        tl = app.timeline
        assert app.plots.residual.visible and app.plots.residual.title == RESIDUAL_TITLE
        np.testing.assert_allclose(app.plots.residual.data[1], _effort_flags().residual_frac_bw)
        np.testing.assert_allclose(app.plots.residual.data[2], 0.05)  # default threshold line
        tl.problem_kind.value = "residual root force high (2)"
        assert tl.kind == "residual_high"
        tl.next_problem.value = True
        assert app.frame == 7
        app.render(7)
        assert "residual root force high" in tl.info.content
        tl.problem_kind.value = ANY_PROBLEM
        tl.next_problem.value = True
        assert app.frame == 2  # the torque problem, wrapping around
        # An older evaluate artifact: the viewer reloads without the physics kinds and hides the plot.
        tl.problem_kind.value = "joint torque over human limit (1)"
        _write_problems(sdir, _legacy_arrays())
        app.reload()
        assert tl.problem_kind.value == "joint torque over human limit (0)"  # same kind, new count
        assert not app.plots.residual.visible
        tl.next_problem.value = True
        assert app.frame == 2  # nothing of that kind: stays
        tl.problem_kind.value = ANY_PROBLEM
        tl.next_problem.value = True
        assert app.frame == 4
    finally:
        app.close()
