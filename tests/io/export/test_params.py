"""``--format params``: the body-model parameters NPZ round-trips and equals the BodyFit of the
selected athletes and frames (anny); for SMPL, ``smplx`` fed the exported arrays puts the pelvis
where the fit did."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from pipeline.artifacts import ArtifactStore  # noqa: E402
from pipeline.artifacts.store import Manifest  # noqa: E402
from pipeline.io.export import ExportSelection, export_files  # noqa: E402
from pipeline.schema.results import BodyFit  # noqa: E402
from tests.io.export.fitted_session import ATHLETES, write_fitted_session  # noqa: E402


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, BodyFit]:
    s = tmp_path_factory.mktemp("params") / "bout"
    return s, write_fitted_session(s)


def _load(files: dict[str, bytes]) -> dict[str, np.ndarray]:
    assert list(files) == ["body_params.npz"]
    with np.load(io.BytesIO(files["body_params.npz"]), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def test_anny_params_equal_the_fit_for_the_selected_athlete_and_frames(session: tuple[Path, BodyFit]) -> None:
    from pipeline.backends.anny.model import PHENOTYPE_LABELS, anny_body

    s, fit = session
    z = _load(
        export_files(
            ExportSelection(s, athletes=(1,), frames=(12, 16), names=dict(enumerate(ATHLETES))), "params"
        )
    )
    rows = np.flatnonzero((fit.frame_indices >= 12) & (fit.frame_indices < 16))
    assert rows.tolist() == [2, 3, 4, 5]
    assert str(z["format"]) == "cornerman.bodyparams/v1" and str(z["body_model"]) == "anny"
    assert str(z["rig"]) == fit.rig and float(z["fps"]) == fit.fps
    assert z["person_ids"].tolist() == [1] and z["person_names"].tolist() == ["Blue"]
    np.testing.assert_array_equal(z["frame_indices"], fit.frame_indices[rows])
    np.testing.assert_array_equal(z["valid"], fit.valid[rows][:, [1]])
    assert not z["valid"][:2].any() and z["valid"][2:].all()  # rows 2, 3 of Blue are not fitted
    assert tuple(z["phenotype_names"].tolist()) == PHENOTYPE_LABELS
    np.testing.assert_array_equal(z["phenotypes"], fit.shape[[1]])
    assert tuple(z["bone_names"].tolist()) == fit.bone_names
    np.testing.assert_array_equal(z["bone_parents"], anny_body(fit.rig).bone_parent)
    assert z["pose_aa"].shape == (4, 1, len(fit.bone_names), 3)
    np.testing.assert_array_equal(z["pose_aa"], fit.pose[rows][:, [1]])
    np.testing.assert_array_equal(z["root_translation_m"], fit.root_translation_m[rows][:, [1]])
    assert "radians" in str(z["units"]) and "z-up" in str(z["axes"])
    assert np.abs(z["pose_aa"]).max() > 0.05  # a real pose, not zeros


def test_all_athletes_by_default_and_only_the_fit_as_source(session: tuple[Path, BodyFit]) -> None:
    s, fit = session
    z = _load(export_files(ExportSelection(s), "params"))
    assert z["person_names"].tolist() == ["person0", "person1"]
    np.testing.assert_array_equal(z["pose_aa"], fit.pose)
    np.testing.assert_array_equal(z["phenotypes"], fit.shape)
    np.testing.assert_array_equal(z["valid"], fit.valid)
    with pytest.raises(ValueError, match="--source physics"):
        export_files(ExportSelection(s, source="physics"), "params")


def _smpl_session(root: Path) -> tuple[Path, BodyFit, Path]:
    from pipeline.backends.smpl import body as sb
    from tests.backends.test_smpl_fit import write_synthetic_smpl

    models = root / "models"
    write_synthetic_smpl(models)
    body = sb.smpl_body("smpl", models)
    rng = np.random.default_rng(2)
    nf, npers, nj = 5, 2, body.n_joints
    fit = BodyFit(
        body_model="smpl",
        rig=body.rig,
        bone_names=body.joint_names,
        person_ids=np.array([0, 1]),
        frame_indices=np.arange(nf) + 100,
        fps=30.0,
        shape=rng.normal(0, 1, (npers, 10)),
        pose=rng.normal(0, 0.3, (nf, npers, nj, 3)),
        root_translation_m=rng.normal(0, 1, (nf, npers, 3)) + [0, 0, 1.0],
        valid=np.ones((nf, npers), dtype=bool),
        loss_final=np.zeros(npers),
    )
    s = root / "bout"
    s.mkdir()
    cfg = {"body_model": "smpl", "body_model_path": str(models)}
    ArtifactStore(s).write(
        Manifest(stage="fit", code_version="t", config=cfg, config_hash="0", inputs={}), {"bodyfit": fit}
    )
    return s, fit, models


def test_smpl_params_follow_smplx_conventions(tmp_path: Path) -> None:
    import roma
    import torch

    from pipeline.backends.smpl import body as sb

    s, fit, models = _smpl_session(tmp_path)
    z = _load(export_files(ExportSelection(s, athletes=(1,), frames=(101, 104)), "params"))
    assert str(z["body_model"]) == "smpl" and tuple(z["joint_names"].tolist()) == fit.bone_names
    np.testing.assert_array_equal(z["betas"], fit.shape[[1]])
    np.testing.assert_allclose(z["body_pose"][:, 0], fit.pose[1:4, 1, 1:].reshape(3, -1))
    assert z["global_orient"].shape == z["transl"].shape == (3, 1, 3) and z["body_pose"].shape == (3, 1, 69)
    # smplx fed the exported arrays: its pelvis lands on the fit's root, oriented as the fit's root
    module = sb.smpl_body("smpl", models).module
    with torch.no_grad():
        out = module(
            betas=torch.as_tensor(z["betas"]),
            global_orient=torch.as_tensor(z["global_orient"][:, 0]),
            body_pose=torch.as_tensor(z["body_pose"][:, 0]),
            transl=torch.as_tensor(z["transl"][:, 0]),
        )
    R = z["R_world_smpl"]
    pelvis_world = out.joints[:, 0].numpy() @ R.T
    np.testing.assert_allclose(pelvis_world, fit.root_translation_m[1:4, 1], atol=1e-9)
    G = R @ roma.rotvec_to_rotmat(torch.as_tensor(z["global_orient"][:, 0])).numpy()
    np.testing.assert_allclose(
        G, roma.rotvec_to_rotmat(torch.as_tensor(fit.pose[1:4, 1, 0])).numpy(), atol=1e-9
    )
    with pytest.raises(ValueError, match="bvh"):
        export_files(ExportSelection(s), "bvh")


def test_smpl_params_without_the_model_files_name_the_problem(tmp_path: Path) -> None:
    s, _, models = _smpl_session(tmp_path)
    for f in (models / "smpl").iterdir():
        f.unlink()
    with pytest.raises(ValueError, match="SMPL_NEUTRAL"):
        export_files(ExportSelection(s), "params")
