"""Body-model parameters of the fit as one NPZ (``--format params``): ``body_params.npz``.

Plain arrays (``np.load(path)``, no pickle); ``persons`` are the selected athletes, ``frames``
the selected fitted frames. Every file holds:

* ``format`` (): ``"cornerman.bodyparams/v1"``; ``body_model`` (): ``"anny"``, ``"smpl"`` or
  ``"smplx"``; ``rig`` (): the body model's rig (anny rig name, or ``"smpl-<gender>"``).
* ``person_ids`` (persons,) int64; ``person_names`` (persons,) str (``person<id>`` when unnamed).
* ``frame_indices`` (frames,) int64 video frame numbers; ``fps`` () float, frames per second.
* ``valid`` (frames, persons) bool: False where the athlete was not fitted (their parameters
  there are zeros and mean nothing).
* ``units`` (), ``axes`` (): strings stating the units and frames below.

anny fits (``body_model == "anny"``), cornerman's convention (``backends/anny/fk.py``):

* ``phenotype_names`` (6,) str and ``phenotypes`` (persons, 6) float64 in [0, 1]: anny's
  phenotype values (one body shape per athlete for the whole bout).
* ``bone_names`` (bones,) str and ``bone_parents`` (bones,) int64 (-1 for the root).
* ``pose_aa`` (frames, persons, bones, 3) float64: each bone's rotation relative to its parent
  as axis-angle in radians, expressed in the world-aligned axes of anny's rest (A-)pose (the
  root's: relative to the world). Zero everywhere is the rest pose.
* ``root_translation_m`` (frames, persons, 3) float64: world position of the root bone's
  head (pelvis centre), metres, world z-up.

SMPL / SMPL-X fits, ``smplx``'s own conventions (feed a row to ``smplx.create(...)(...)``):

* ``joint_names`` (joints,) str: the fit's joints (pelvis first).
* ``betas`` (persons, betas) float64.
* ``global_orient`` (frames, persons, 3) float64: pelvis axis-angle (radians) in SMPL's y-up frame.
* ``body_pose`` (frames, persons, 3 * (joints - 1)) float64: parent-local axis-angle,
  radians (SMPL: 69 values, SMPL-X: 63; SMPL-X's jaw, eyes and hands stay at rest).
* ``transl`` (frames, persons, 3) float64: ``smplx``'s translation, metres, SMPL frame.
* ``R_world_smpl`` (3, 3) float64: cornerman's world point is ``R_world_smpl @ p`` for an
  ``smplx`` output point ``p`` (SMPL is y-up facing +z; the world is z-up facing -y).

``transl`` depends on the pelvis' rest position for the betas, so SMPL exports read the
user's model files named by the fit's ``body_model_path`` (``ValueError`` when missing).
"""

from __future__ import annotations

import io
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from pipeline.io.export.selection import ExportSelection
    from pipeline.schema.results import BodyFit

PARAMS_FORMAT_ID = "cornerman.bodyparams/v1"

FIT_SOURCES = ("best", "latest", "fit")
"""``--source`` values that body-model formats accept: all mean the fit stage's ``BodyFit``."""

ANNY_UNITS = "pose_aa: radians (axis-angle); root_translation_m: metres; phenotypes: [0, 1]"
ANNY_AXES = (
    "world z-up, right-handed (floor world, calibrate/world.json); pose_aa parent-relative in the world-aligned "
    "axes of anny's rest A-pose (facing -y, subject's left +x)"
)
SMPL_UNITS = "global_orient, body_pose: radians (axis-angle); transl: metres"
SMPL_AXES = "smplx's SMPL frame (y-up, facing +z); world point = R_world_smpl @ smplx point (world z-up)"


def fit_for_export(sel: ExportSelection, fmt: str) -> BodyFit:
    """The selection's ``BodyFit`` for a body-model format ``fmt``.

    ``ValueError`` when ``sel.source`` asks for something other than the fit (physics, raw or
    filtered keypoints); ``LookupError`` when the fit stage has not run."""
    if sel.source not in FIT_SOURCES:
        raise ValueError(
            f"--format {fmt} is written from the body fit (stage 'fit'), not from --source {sel.source}; "
            f"use --source {' / '.join(FIT_SOURCES)} (all mean the fit)"
        )
    return sel.bodyfit()


def _anny_arrays(fit: BodyFit) -> dict[str, np.ndarray]:
    from pipeline.backends.anny.model import PHENOTYPE_LABELS, anny_body

    body = anny_body(fit.rig)
    if tuple(fit.bone_names) != body.bone_names:
        raise ValueError(
            f"--format params: the fit's bones {fit.bone_names[:3]}... are not anny rig {fit.rig!r}'s"
        )
    if fit.shape.shape[1] != len(PHENOTYPE_LABELS):
        raise ValueError(
            f"--format params: anny fit shape has {fit.shape.shape[1]} values, expected 6 phenotypes"
        )
    return {
        "phenotype_names": np.array(PHENOTYPE_LABELS, dtype=np.str_),
        "phenotypes": fit.shape.astype(np.float64),
        "bone_names": np.array(fit.bone_names, dtype=np.str_),
        "bone_parents": body.bone_parent.astype(np.int64),
        "pose_aa": fit.pose.astype(np.float64),
        "root_translation_m": fit.root_translation_m.astype(np.float64),
        "units": np.array(ANNY_UNITS),
        "axes": np.array(ANNY_AXES),
    }


def _smpl_arrays(fit: BodyFit, body_model_path: str) -> dict[str, np.ndarray]:
    from pipeline.backends.smpl.body import R_WORLD_SMPL, smpl_body, smplx_params

    gender = fit.rig.split("-", 1)[1] if "-" in fit.rig else "neutral"
    if not body_model_path:
        raise ValueError(
            f"--format params: the {fit.body_model} fit's manifest names no body_model_path; "
            "smplx's transl needs the model files the fit used"
        )
    body = smpl_body(fit.body_model, body_model_path, gender)
    if tuple(fit.bone_names) != body.joint_names:
        raise ValueError(
            f"--format params: the fit's joints {fit.bone_names[:3]}... do not match {body.file}"
        )
    nf, npers = fit.valid.shape
    go = np.zeros((nf, npers, 3))
    bp = np.zeros((nf, npers, 3 * (body.n_joints - 1)))
    tr = np.zeros((nf, npers, 3))
    for p in range(npers):
        d = smplx_params(body, fit.shape[p], fit.pose[:, p].astype(np.float64), fit.root_translation_m[:, p])
        go[:, p], bp[:, p], tr[:, p] = d["global_orient"], d["body_pose"], d["transl"]
    return {
        "joint_names": np.array(fit.bone_names, dtype=np.str_),
        "betas": fit.shape.astype(np.float64),
        "global_orient": go,
        "body_pose": bp,
        "transl": tr,
        "R_world_smpl": np.asarray(R_WORLD_SMPL, dtype=np.float64),
        "units": np.array(SMPL_UNITS),
        "axes": np.array(SMPL_AXES),
    }


def params_arrays(fit: BodyFit, names: list[str], body_model_path: str = "") -> dict[str, np.ndarray]:
    """The NPZ's arrays (module docstring) for ``fit`` (already restricted to the selection);
    ``names`` (persons,) athlete names; ``body_model_path`` only for SMPL/SMPL-X."""
    common: dict[str, np.ndarray] = {
        "format": np.array(PARAMS_FORMAT_ID),
        "body_model": np.array(fit.body_model),
        "rig": np.array(fit.rig),
        "person_ids": fit.person_ids.astype(np.int64),
        "person_names": np.array(names, dtype=np.str_),
        "frame_indices": fit.frame_indices.astype(np.int64),
        "fps": np.array(float(fit.fps)),
        "valid": fit.valid.astype(bool),
    }
    specific = _anny_arrays(fit) if fit.body_model == "anny" else _smpl_arrays(fit, body_model_path)
    return {**common, **specific}


def build_params(sel: ExportSelection) -> dict[str, bytes]:
    """The registry's ``params`` format: ``body_params.npz`` (module docstring)."""
    from pipeline.artifacts import ArtifactStore

    fit = fit_for_export(sel, "params")
    path = ""
    if fit.body_model != "anny":
        manifest = ArtifactStore(sel.session_dir).manifest("fit")
        cfg: dict[str, Any] = manifest.config if manifest is not None else {}
        path = str(cfg.get("body_model_path", ""))
    arrays = params_arrays(fit, [sel.name_of(p) for p in fit.person_ids.tolist()], path)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)  # type: ignore[arg-type]  # numpy stub, see schema.base
    return {"body_params.npz": buf.getvalue()}
