"""SMPL / SMPL-X through the ``smplx`` package, with the user's own model files.

Nothing of SMPL is shipped (its licence forbids it). The files must be laid out as
``smplx.create`` expects::

    <body_model_path>/smpl/SMPL_NEUTRAL.pkl   (and/or SMPL_MALE.pkl, SMPL_FEMALE.pkl)
    <body_model_path>/smplx/SMPLX_NEUTRAL.npz (and/or SMPLX_MALE.npz, SMPLX_FEMALE.npz; .pkl also accepted)

Download them from https://smpl.is.tue.mpg.de and https://smpl-x.is.tue.mpg.de after
accepting their licences, and install the package with ``pip install smplx`` (extra
``cornerman[smpl]``). Pickles holding ``chumpy`` arrays (SMPL 1.0) need ``chumpy`` or a
conversion to plain numpy first.

Frames. SMPL is y-up and faces +z (the subject's left is +x); our world is z-up with the
subject facing -y (``CONVENTIONS.md``, as anny). The fixed rotation ``R_WORLD_SMPL`` (+90 deg
about x: y -> z, z -> -y, x -> x) maps one to the other. A ``BodyFit`` of SMPL stores:

* ``pose[..., 0, :]``: axis-angle of ``R_world_pelvis = R_WORLD_SMPL @ R(global_orient)``, the
  world orientation of SMPL's (canonical-axes) pelvis frame;
* ``pose[..., 1:, :]``: SMPL's ``body_pose`` unchanged (parent-local, SMPL axes). SMPL: 23
  joints (incl. the hands); SMPL-X: the 21 body joints (jaw, eyes and fingers stay at rest);
* ``root_translation_m``: world position of the pelvis joint;
* ``shape``: the betas.

Back to ``smplx``: ``global_orient = aa(R_WORLD_SMPL.T @ R_world_pelvis)``, ``transl =
R_WORLD_SMPL.T @ root_translation_m - J_pelvis(betas)``, and world vertices are
``R_WORLD_SMPL @ smplx_output.vertices`` (``smplx_params``/``posed_mesh`` do this).

Keypoints (``COCO17_FEET``) are matched by name to ``smplx``'s output joints
(``smplx.joint_names``): the shoulders, elbows, wrists, hips, knees and ankles are SMPL's
skeleton joints; nose, eyes, ears, big/small toes and heels are the mesh vertices that
``smplx``'s ``VertexJointSelector`` appends (SMPL: nose 332, eyes 2800/6260, ears 583/4071,
left toes 3216/3226, heel 3387, right toes 6617/6624, heel 6787). SMPL's hip joints sit
lower and more medial than a detector's "hip"; ``FitConfig.calibrate_landmarks`` absorbs it.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import io
import logging
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import roma
import torch

from pipeline.schema.joints import COCO17_FEET
from pipeline.schema.results import BodyFit

logger = logging.getLogger(__name__)

EXPECTED_FILES: dict[str, tuple[str, ...]] = {
    "smpl": ("smpl/SMPL_NEUTRAL.pkl", "smpl/SMPL_MALE.pkl", "smpl/SMPL_FEMALE.pkl"),
    "smplx": (
        "smplx/SMPLX_NEUTRAL.npz",
        "smplx/SMPLX_MALE.npz",
        "smplx/SMPLX_FEMALE.npz",
        "smplx/SMPLX_NEUTRAL.pkl",
        "smplx/SMPLX_MALE.pkl",
        "smplx/SMPLX_FEMALE.pkl",
    ),
}

R_WORLD_SMPL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
"""SMPL (y-up, facing +z) -> world (z-up, facing -y)."""

N_BETAS = 10
_SMPL_BODY_JOINTS = 22  # pelvis + 21 body joints, shared by SMPL, SMPL-H and SMPL-X


def find_model_files(body_model: str, body_model_path: str | Path) -> list[Path]:
    """The expected model files present under ``body_model_path`` (may be empty)."""
    if body_model not in EXPECTED_FILES:
        raise ValueError(f"unknown body model {body_model!r}; expected one of {sorted(EXPECTED_FILES)}")
    root = Path(body_model_path)
    return [root / rel for rel in EXPECTED_FILES[body_model] if (root / rel).is_file()]


def check_smpl_available(body_model: str, body_model_path: str | Path) -> list[Path]:
    """Raise ``ValueError`` saying exactly what is missing; return the model files found."""
    expected = ", ".join(EXPECTED_FILES.get(body_model, ()))
    if not str(body_model_path):
        raise ValueError(
            f"--body-model {body_model} needs --body-model-path: a folder with {expected} "
            "(your own licensed copy; nothing of SMPL is shipped)"
        )
    root = Path(body_model_path)
    if not root.is_dir():
        raise ValueError(f"body model path {root} is not a folder; it must contain {expected}")
    files = find_model_files(body_model, root)
    if not files:
        raise ValueError(
            f"no {body_model.upper()} model file under {root}: expected at least one of "
            f"{', '.join(str(root / r) for r in EXPECTED_FILES[body_model])} "
            "(download from https://smpl.is.tue.mpg.de / https://smpl-x.is.tue.mpg.de)"
        )
    if importlib.util.find_spec("smplx") is None:
        raise ValueError(
            f"found {files[0]} but the 'smplx' package is not installed: run `pip install smplx` to fit {body_model}"
        )
    return files


def model_file(body_model: str, body_model_path: str | Path, gender: str = "neutral") -> Path:
    """The model file of ``gender``; ``ValueError`` naming the missing path otherwise."""
    files = check_smpl_available(body_model, body_model_path)
    stem = f"{'SMPL' if body_model == 'smpl' else 'SMPLX'}_{gender.upper()}"
    for f in files:
        if f.stem == stem:
            return f
    want = Path(body_model_path) / body_model / f"{stem}.{'pkl' if body_model == 'smpl' else 'npz'}"
    raise ValueError(
        f"{want} not found (gender {gender!r}); the folder has {', '.join(str(f) for f in files)}"
    )


def _smplx_module(body_model: str, file: Path) -> Any:
    """An ``smplx.SMPL`` / ``smplx.SMPLX`` (float64, batch 1) read from ``file``."""
    import smplx

    gender = file.stem.split("_", 1)[1].lower()
    captured = io.StringIO()
    try:
        with contextlib.redirect_stdout(captured):  # smplx prints warnings
            if body_model == "smpl":
                model = smplx.SMPL(str(file), gender=gender, num_betas=N_BETAS, dtype=torch.float64)
            else:
                model = smplx.SMPLX(
                    str(file),
                    gender=gender,
                    num_betas=N_BETAS,
                    ext=file.suffix[1:],
                    use_pca=False,
                    flat_hand_mean=True,
                    dtype=torch.float64,
                )
    except ModuleNotFoundError as e:  # chumpy pickles (SMPL 1.0)
        raise ValueError(
            f"{file}: the model pickle needs the module {e.name!r}; install it or convert the file "
            "to plain numpy arrays"
        ) from e
    except (OSError, KeyError, AttributeError, pickle.UnpicklingError, EOFError, ValueError) as e:
        raise ValueError(f"{file}: not a readable {body_model.upper()} model file: {e}") from e
    if captured.getvalue().strip():
        logger.debug("smplx: %s", captured.getvalue().strip())
    return model


def output_joint_names(body_model: str) -> tuple[str, ...]:
    """Names of ``smplx``'s output joints up to its vertex joints (SMPL: 24 + 21, SMPL-X: 55 + 21)."""
    from smplx.joint_names import JOINT_NAMES

    if body_model == "smpl":
        return (
            tuple(JOINT_NAMES[:_SMPL_BODY_JOINTS]) + ("left_hand", "right_hand") + tuple(JOINT_NAMES[55:76])
        )
    return tuple(JOINT_NAMES[:76])


@dataclass(frozen=True)
class VertexSet:
    """A few mesh vertices, ready for sparse skinning (all float64, SMPL frame).

    v_template (m, 3); shapedirs (m, 3, betas); posedirs (9 * (joints - 1), m * 3);
    weights (m, joints) skinning weights folded onto the posed joints; top_joints /
    top_weights (m, k): the same weights restricted to the k joints that can be non-zero
    (k = the largest number of influences of one vertex, so this is exact).
    """

    ids: np.ndarray
    v_template: torch.Tensor
    shapedirs: torch.Tensor
    posedirs: torch.Tensor
    weights: torch.Tensor
    top_joints: torch.Tensor
    top_weights: torch.Tensor


@dataclass(frozen=True)
class SmplBody:
    """The parts of an SMPL/SMPL-X model the fit needs, as float64 tensors (SMPL frame).

    Posed joints: SMPL's 24, or SMPL-X's pelvis + 21 body joints (its jaw, eye and finger
    joints stay at rest, so their skinning weights are folded onto their body ancestors,
    exactly). ``kp_joint[k] >= 0``: ``COCO17_FEET[k]`` is that skeleton joint; otherwise
    ``kp_vertex[k]`` indexes ``keypoint_vertices``.
    """

    body_model: str
    gender: str
    file: Path
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]
    J_template: torch.Tensor  # (joints, 3)
    J_dirs: torch.Tensor  # (joints, 3, betas)
    kp_joint: np.ndarray  # (23,)
    kp_vertex: np.ndarray  # (23,)
    keypoint_vertices: VertexSet
    faces: np.ndarray
    v_template_all: np.ndarray  # (verts, 3)
    lbs_weights: torch.Tensor  # (verts, joints) skinning weights folded onto the posed joints
    module: Any  # the smplx module (meshes, reference forward)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def rig(self) -> str:
        return f"{self.body_model}-{self.gender}"

    def vertex_set(self, ids: np.ndarray) -> VertexSet:
        """Sparse-skinning data of the vertices ``ids``."""
        return _vertex_set(self.module, self.lbs_weights, ids)

    def rest_joints(self, betas: torch.Tensor) -> torch.Tensor:
        """(n, betas) -> (n, joints, 3) rest joint positions (SMPL frame)."""
        return self.J_template + torch.einsum("jdb,nb->njd", self.J_dirs, betas)


def _vertex_set(m: Any, lbs_folded: torch.Tensor, ids: np.ndarray) -> VertexSet:
    """Sparse-skinning data of the vertices ``ids`` of the smplx module ``m``, with its
    skinning weights folded onto the posed joints (``SmplBody.lbs_weights``)."""
    ids = np.asarray(ids, dtype=np.int64)
    nj = lbs_folded.shape[1]
    cols = (ids[:, None] * 3 + np.arange(3)).reshape(-1)
    folded = lbs_folded[ids]
    k = max(1, int((folded != 0).sum(dim=1).max()))
    top_w, top_j = folded.topk(k, dim=1)
    return VertexSet(
        ids=ids,
        v_template=m.v_template.detach().double()[ids],
        shapedirs=m.shapedirs.detach().double()[ids],
        posedirs=m.posedirs.detach().double()[: 9 * (nj - 1), cols],
        weights=folded,
        top_joints=top_j,
        top_weights=top_w,
    )


@functools.lru_cache(maxsize=4)
def _load(body_model: str, file: Path, mtime: float) -> SmplBody:
    del mtime  # cache key only: a replaced file is read again
    m = _smplx_module(body_model, file)
    nj = 24 if body_model == "smpl" else _SMPL_BODY_JOINTS
    names = output_joint_names(body_model)
    n_model_joints = int(m.J_regressor.shape[0])
    extra = m.vertex_joint_selector.extra_joints_idxs.numpy()
    kp_joint = np.full(len(COCO17_FEET), -1)
    kp_vertex = np.full(len(COCO17_FEET), -1)
    vert_ids: list[int] = []
    for k, name in enumerate(COCO17_FEET):
        i = names.index(name)
        if i < nj:
            kp_joint[k] = i
        else:
            kp_vertex[k] = len(vert_ids)
            vert_ids.append(int(extra[i - n_model_joints]))
    Jreg = m.J_regressor.detach().double()[:nj]
    v_t = m.v_template.detach().double()
    parents = m.parents.numpy()
    fold = np.arange(parents.size)  # nearest posed ancestor of every model joint
    for j in range(parents.size):
        while fold[j] >= nj:
            fold[j] = parents[fold[j]]
    lbs = torch.zeros(v_t.shape[0], nj, dtype=torch.float64)
    lbs.index_add_(1, torch.as_tensor(fold), m.lbs_weights.detach().double())
    body = SmplBody(
        body_model=body_model,
        gender=file.stem.split("_", 1)[1].lower(),
        file=file,
        joint_names=names[:nj],
        parents=tuple(int(p) for p in parents[:nj]),
        J_template=Jreg @ v_t,
        J_dirs=torch.einsum("jv,vdb->jdb", Jreg, m.shapedirs.detach().double()),
        kp_joint=kp_joint,
        kp_vertex=kp_vertex,
        keypoint_vertices=_vertex_set(m, lbs, np.array(vert_ids)),
        faces=np.asarray(m.faces, dtype=np.int64),
        v_template_all=v_t.numpy(),
        lbs_weights=lbs,
        module=m,
    )
    return body


def smpl_body(body_model: str, body_model_path: str | Path, gender: str = "neutral") -> SmplBody:
    """Load (cached) the user's SMPL/SMPL-X model of ``gender`` from ``body_model_path``.

    Raises ``ValueError`` naming the path when the folder, the file or ``smplx`` is missing,
    or when the file cannot be read."""
    file = model_file(body_model, body_model_path, gender).resolve()
    return _load(body_model, file, file.stat().st_mtime)


def forward(
    body: SmplBody,
    joints_rest: torch.Tensor,
    G_root: torch.Tensor,
    pose_aa: torch.Tensor,
    root_m: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """World forward kinematics.

    Args:
        joints_rest: (n, joints, 3) rest joints (``rest_joints``), SMPL frame.
        G_root: (n, 3, 3) world orientation of the pelvis frame (``R_WORLD_SMPL @ R(global_orient)``).
        pose_aa: (n, joints - 1, 3) parent-local axis-angle (SMPL's ``body_pose``).
        root_m: (n, 3) world position of the pelvis.
    Returns:
        G (n, joints, 3, 3) world rotations, x (n, joints, 3) world joint positions, and
        R_local (n, joints - 1, 3, 3) (for the pose blend shapes).
    """
    R_local = roma.rotvec_to_rotmat(pose_aa)
    G_cat, x_cat = G_root[:, None], root_m[:, None]
    for joints, parents, parent_pos in _levels(body.parents):  # one batched step per tree depth
        Gp = G_cat[:, parent_pos]
        G_new = Gp @ R_local[:, joints - 1]
        offs = joints_rest[:, joints] - joints_rest[:, parents]
        x_new = x_cat[:, parent_pos] + (Gp @ offs[..., None])[..., 0]
        G_cat, x_cat = torch.cat([G_cat, G_new], dim=1), torch.cat([x_cat, x_new], dim=1)
    inv = _levels_inverse(body.parents)
    return G_cat[:, inv], x_cat[:, inv], R_local


@functools.lru_cache(maxsize=8)
def _levels(parents: tuple[int, ...]) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]:
    """Per tree depth: joint ids, their parents, and the parents' positions in the
    concatenation order (root, depth 1, depth 2, ...)."""
    depth = [0] * len(parents)
    for j in range(1, len(parents)):
        depth[j] = depth[parents[j]] + 1
    pos = {0: 0}
    out = []
    for d in range(1, max(depth) + 1):
        joints = np.array([j for j in range(len(parents)) if depth[j] == d])
        par = np.array([parents[j] for j in joints])
        out.append((joints, par, np.array([pos[p] for p in par])))
        for j in joints:
            pos[int(j)] = len(pos)
    return tuple(out)


@functools.lru_cache(maxsize=8)
def _levels_inverse(parents: tuple[int, ...]) -> np.ndarray:
    order = np.concatenate([[0]] + [lv[0] for lv in _levels(parents)])
    inv = np.empty_like(order)
    inv[order] = np.arange(order.size)
    return inv


def skin(
    vs: VertexSet,
    betas: torch.Tensor,
    joints_rest: torch.Tensor,
    G: torch.Tensor,
    x: torch.Tensor,
    R_local: torch.Tensor,
) -> torch.Tensor:
    """(n, m, 3) world positions of the vertices of ``vs`` (shape and pose blend shapes, LBS);
    ``betas`` (n, betas) and the rest are per row as returned by ``forward``."""
    n = G.shape[0]
    v = vs.v_template + torch.einsum("mdb,nb->nmd", vs.shapedirs, betas)
    eye = torch.eye(3, dtype=G.dtype)
    feat = (R_local - eye).reshape(n, -1)
    v = v + (feat @ vs.posedirs).reshape(n, -1, 3)
    # LBS: sum_b w_b (G_b (v - J_b) + x_b) over the few joints that influence each vertex
    t = x - (G @ joints_rest[..., None])[..., 0]
    Gb = torch.einsum("mk,nmkab->nmab", vs.top_weights, G[:, vs.top_joints])
    tb = torch.einsum("mk,nmka->nma", vs.top_weights, t[:, vs.top_joints])
    return (Gb @ v[..., None])[..., 0] + tb


def keypoints(
    body: SmplBody,
    betas: torch.Tensor,
    joints_rest: torch.Tensor,
    G: torch.Tensor,
    x: torch.Tensor,
    R_local: torch.Tensor,
) -> torch.Tensor:
    """(n, 23, 3) world ``COCO17_FEET`` keypoints (skeleton joints and vertex landmarks)."""
    verts = skin(body.keypoint_vertices, betas, joints_rest, G, x, R_local)
    is_joint = torch.as_tensor(body.kp_joint >= 0)
    jx = x[:, np.maximum(body.kp_joint, 0)]
    vx = verts[:, np.maximum(body.kp_vertex, 0)]
    return torch.where(is_joint[None, :, None], jx, vx)


def smplx_params(
    body: SmplBody, betas: np.ndarray, pose_aa: np.ndarray, root_m: np.ndarray
) -> dict[str, np.ndarray]:
    """``smplx`` forward arguments (SMPL frame) from one person's ``BodyFit`` rows.

    betas (betas,), pose_aa (n, joints, 3), root_m (n, 3) -> global_orient (n, 3),
    body_pose (n, 3 * (joints - 1)), transl (n, 3), betas (1 or n, betas); for SMPL-X also
    zero jaw/eye/hand poses and expression (n, .)."""
    R = torch.as_tensor(R_WORLD_SMPL)
    G = roma.rotvec_to_rotmat(torch.as_tensor(pose_aa[:, 0], dtype=torch.float64))
    go = roma.rotmat_to_rotvec(R.T @ G).numpy()
    b = torch.as_tensor(betas, dtype=torch.float64)[None]
    j0 = body.rest_joints(b)[0, 0].numpy()
    transl = root_m @ R_WORLD_SMPL - j0  # rows: R^T @ root
    n = pose_aa.shape[0]
    out = {
        "global_orient": go,
        "body_pose": pose_aa[:, 1:].reshape(n, -1),
        "transl": transl,
        "betas": np.asarray(betas, dtype=np.float64)[None],
    }
    if body.body_model == "smplx":  # at rest; smplx does not broadcast these over the batch
        for k, d in (("jaw_pose", 3), ("leye_pose", 3), ("reye_pose", 3), ("left_hand_pose", 45)):
            out[k] = np.zeros((n, d))
        out["right_hand_pose"] = np.zeros((n, 45))
        out["expression"] = np.zeros((n, int(body.module.num_expression_coeffs)))
        out["betas"] = np.repeat(out["betas"], n, axis=0)
    return out


def posed_vertices(body: SmplBody, betas: np.ndarray, pose_aa: np.ndarray, root_m: np.ndarray) -> np.ndarray:
    """(n, verts, 3) world vertices through ``smplx``'s own forward (full mesh)."""
    p = {
        k: torch.as_tensor(v, dtype=torch.float64)
        for k, v in smplx_params(body, betas, pose_aa, root_m).items()
    }
    with torch.no_grad():
        out = body.module(return_verts=True, **p)
    return out.vertices.numpy() @ R_WORLD_SMPL.T


def posed_mesh(
    bodyfit: BodyFit, person_index: int, frames: np.ndarray, body_model_path: str | Path
) -> tuple[np.ndarray, np.ndarray]:
    """Posed meshes of one person of an SMPL/SMPL-X fit, for the viewer.

    ``frames``: row indices into ``bodyfit.frame_indices``. Needs the same model files as the
    fit (``FitConfig.body_model_path``; the gender is in ``bodyfit.rig``). Returns world
    vertices (n, verts, 3) float32 and faces (faces, 3) int64; ``ValueError`` otherwise."""
    if bodyfit.body_model not in ("smpl", "smplx"):
        raise ValueError(f"posed_mesh: not an SMPL/SMPL-X fit: body_model={bodyfit.body_model!r}")
    if not 0 <= person_index < bodyfit.person_ids.shape[0]:
        raise ValueError(
            f"posed_mesh: person_index {person_index} out of range {bodyfit.person_ids.shape[0]}"
        )
    gender = bodyfit.rig.split("-", 1)[1] if "-" in bodyfit.rig else "neutral"
    body = smpl_body(bodyfit.body_model, body_model_path, gender)
    if tuple(bodyfit.bone_names) != body.joint_names:
        raise ValueError(f"posed_mesh: fit joints {bodyfit.bone_names[:3]}... do not match {body.file}")
    frames = np.asarray(frames, dtype=np.int64).reshape(-1)
    verts = posed_vertices(
        body,
        bodyfit.shape[person_index],
        bodyfit.pose[frames, person_index].astype(np.float64),
        bodyfit.root_translation_m[frames, person_index].astype(np.float64),
    )
    return verts.astype(np.float32), body.faces.copy()
