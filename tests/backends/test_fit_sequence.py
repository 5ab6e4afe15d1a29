"""One fit driver for every body model: ``fitting.sequence.fit_sequence`` with loss terms
selected by name (``fitting.terms``); anny and SMPL enter it through their adapters."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from pipeline.stages.fit import FitConfig

torch = pytest.importorskip("torch")

from pipeline.backends.fitting import terms as ft  # noqa: E402
from pipeline.backends.fitting.sequence import FitOutput, fit_sequence  # noqa: E402
from pipeline.schema.joints import COCO17_FEET  # noqa: E402

NJ = len(COCO17_FEET)


class _StubBody:
    """Just what building the terms asks of a body model."""

    name = "stub"

    def mesh_moment_factors(self) -> torch.Tensor:
        return torch.zeros(2, 8, 1, dtype=torch.float64)

    def pose_priors(self) -> dict[str, Any]:
        return {"prior": lambda state: state.pose.sum(), "vposer": lambda state: state.pose.sum()}


def _targets(npers: int = 2, nf: int = 6) -> ft.Targets:
    n = npers * nf
    z = torch.zeros
    return ft.Targets(
        z(n, NJ, 3), z(n, NJ), z(1, n, NJ, 2), z(1, n, NJ), z(1, 3, 4), torch.ones(npers, nf, dtype=torch.bool), npers, nf
    )


def test_the_default_terms_are_todays_with_the_config_weights() -> None:
    cfg = FitConfig()
    built = ft.build_terms(ft.DEFAULT_TERMS, ft.TermContext(cfg, _StubBody(), _targets()))  # type: ignore[arg-type]
    assert [(t.name, t.weight) for t in built] == [
        ("3d", cfg.w_3d),
        ("2d", cfg.w_2d),
        ("reg", cfg.w_reg),
        ("smooth", cfg.w_smooth),
        ("accel", cfg.w_accel),
        ("jerk", cfg.w_jerk),
        ("landmarks", cfg.w_landmarks),
        ("shape", 1e-4),
        ("limits", cfg.w_limits),
        ("prior", cfg.w_prior),
        ("vposer", cfg.w_prior),
        ("ground", cfg.w_ground),
        ("overlap", cfg.w_overlap),
    ]
    # Terms that are off are left out; the overlap needs two persons.
    off = FitConfig(w_2d=0.0, w_smooth=0.0, calibrate_landmarks=False, refine_shape=False, w_prior=0.0, w_ground=0.0)
    names = [t.name for t in ft.build_terms(ft.DEFAULT_TERMS, ft.TermContext(off, _StubBody(), _targets(1)))]  # type: ignore[arg-type]
    assert names == ["3d", "reg", "accel", "jerk", "limits"]
    with pytest.raises(ValueError, match="unknown"):
        ft.build_terms(("3d", "elbow"), ft.TermContext(cfg, _StubBody(), _targets()))  # type: ignore[arg-type]


def test_anny_and_smpl_go_through_the_same_fit_sequence(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Both adapters reach the same loss term objects: a term patched once is called by the
    anny fit and by the SMPL fit, and both report the same terms."""
    pytest.importorskip("smplx")
    pytest.importorskip("anny")
    from pipeline.backends.anny.fit import fit_anny
    from pipeline.backends.smpl import body as sb
    from pipeline.backends.smpl.fit import fit_smpl, smpl_fit_model
    from tests.backends.test_smpl_fit import _motion, _observations, _rig, write_synthetic_smpl

    write_synthetic_smpl(tmp_path)
    body = sb.smpl_body("smpl", tmp_path)
    rig = _rig(3)
    xyz = _motion(body, 6, seed=0)[3]
    obs = [_observations(rig, xyz), _observations(rig, xyz + [1.0, 0.0, 0.0])]
    calls: list[str] = []
    real = ft.Ground.value

    def spy(self: ft.Ground, state: Any) -> torch.Tensor:
        calls.append(self.ctx.body.name)
        return real(self, state)

    monkeypatch.setattr(ft.Ground, "value", spy)
    cfg = FitConfig(shape_iters=3, pose_iters_3d=2, pose_iters=3, pose_prior_path="")
    res = {"anny": fit_anny(obs, rig.P, cfg), "smpl": fit_smpl(obs, rig.P, cfg, body)}
    assert {"anny", "smpl-neutral"} <= set(calls)
    assert all(isinstance(r, FitOutput) for r in res.values())
    every = {"3d", "2d", "reg", "smooth", "accel", "landmarks", "shape", "limits", "ground", "overlap"}
    assert set(res["anny"].loss_terms) == set(res["smpl"].loss_terms) == every
    assert res["smpl"].joint_names == body.joint_names  # type: ignore[attr-defined]
    # The fit's loss is the terms selected by name.
    only = fit_sequence(smpl_fit_model(cfg, body), obs, rig.P, cfg, terms=("3d", "reg"))
    assert set(only.loss_terms) == {"3d", "reg"}
