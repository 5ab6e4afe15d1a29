"""The anny body model, built once per process and folded into small per-bone tensors.

Building anny's model data the first time takes ~1 min and ~1.75 GB of RAM and fills a
cache of ~0.8 GB (``$ANNY_CACHE_DIR``; we default it to ``$CORNERMAN_CACHE_DIR/anny``,
``CORNERMAN_CACHE_DIR`` itself defaulting to ``~/.cache/cornerman``). Later builds load the
cache in well under a second. :func:`anny_body` keeps one built model per (rig, topology)
per process.

Folding. anny skins with linear blend skinning, ``v' = sum_b w_vb T_b v``, and its COCO
regressor is linear in the skinned vertices, ``k = sum_v r_kv v'``. Hence
``k = sum_b T_b (sum_v r_kv w_vb [v; 1])``: each keypoint is a fixed weighted point per bone.
Those points are linear in the phenotype blendshape coefficients, so the folded tensors
(``kp_pts0``, ``kp_pts_bs``, ``kp_w``) reproduce the mesh keypoints exactly (up to float
round-off) for any shape and pose, at a fraction of the cost of skinning the mesh.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import os
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
import torch

from pipeline.backends.anny.cache import anny_cache_dir
from pipeline.schema.joints import COCO17_FEET

logger = logging.getLogger(__name__)

DEFAULT_RIG = "anny-nohands-notoes-noeyes"
"""anny's default rig minus fingers, toes and eyes (see ``/work/notes/anny_api.md``)."""

DEFAULT_TOPOLOGY = "anny"
"""anny's full triangulated body mesh (display); fitting never skins it."""

PHENOTYPE_LABELS: tuple[str, ...] = ("gender", "age", "muscle", "weight", "height", "proportions")
"""Order of the 6 shape values (anny's default phenotype set), each in [0, 1]."""

DEFAULT_SHAPE = np.full(6, 0.5)
"""anny's average adult (all phenotypes at 0.5)."""

_SAFE_TOPOLOGIES = (
    "anny",
    "makehuman",
    "notoes",
    "notoes_collapse3pc",
    "notoes_collapse5pc",
    "notoes_collapse10pc",
)


def _import_anny():  # noqa: ANN202 (module type)
    cache = anny_cache_dir()
    os.environ.setdefault("ANNY_CACHE_DIR", str(cache))
    import anny
    import anny.paths

    # anny reads the variable at import time; someone may have imported it before us.
    anny.paths.set_anny_cache_path(cache)
    return anny


@dataclass(frozen=True)
class AnnyBody:
    """A built anny model plus the folded tensors used for fast fitting (float64, CPU).

    Fields:
        model: the ``anny.Anny`` module (skinning ``"lbs"``) for whole-mesh passes.
        rig, topology: the names it was built with.
        bone_names: (bones,) anny bone labels.
        bone_parent: (bones,) parent index, -1 for the root (index 0); parents precede children.
        levels: bone indices grouped by depth (root first), for level-by-level FK.
        heads0: (bones, 3) rest bone heads of the template; heads_bs: (coeffs, bones, 3).
        kp_w: (joints, bones) weight of each bone in each keypoint (rows sum to 1).
        kp_pts0: (joints, bones, 3) folded weighted rest points of the template;
            kp_pts_bs: (coeffs, joints, bones, 3) their blendshape offsets.
        joint_names: ``COCO17_FEET`` (the folded keypoints' order).
        faces: (faces, 3) int64 triangles.
        vertex_bone: (verts,) dominant skinning bone per vertex.
    """

    model: Any  # anny.Anny (typed loosely: its buffers are dynamic attributes)
    rig: str
    topology: str
    bone_names: tuple[str, ...]
    bone_parent: np.ndarray
    levels: tuple[torch.Tensor, ...]
    heads0: torch.Tensor
    heads_bs: torch.Tensor
    kp_w: torch.Tensor
    kp_pts0: torch.Tensor
    kp_pts_bs: torch.Tensor
    joint_names: tuple[str, ...]
    faces: np.ndarray
    vertex_bone: np.ndarray

    @property
    def n_bones(self) -> int:
        return len(self.bone_names)

    @property
    def dtype(self) -> torch.dtype:
        """Floating-point type of the model's tensors (``anny_body`` builds float64)."""
        return self.heads0.dtype

    def to(self, dtype: torch.dtype) -> AnnyBody:
        """This body computing in ``dtype`` (a copy, the anny module included; ``self`` when
        it already does)."""
        if dtype == self.dtype:
            return self
        return dataclasses.replace(
            self,
            model=copy.deepcopy(self.model).to(dtype),
            heads0=self.heads0.to(dtype),
            heads_bs=self.heads_bs.to(dtype),
            kp_w=self.kp_w.to(dtype),
            kp_pts0=self.kp_pts0.to(dtype),
            kp_pts_bs=self.kp_pts_bs.to(dtype),
        )

    def shape_coeffs(self, shape: torch.Tensor) -> torch.Tensor:
        """(n, 6) phenotype values in [0, 1] -> (n, coeffs) blendshape coefficients (differentiable)."""
        m = self.model
        n = shape.shape[0]
        empty_lc = shape.new_zeros((n, len(m.local_change_labels)))
        empty_fa = shape.new_zeros((n, len(m.facial_action_labels)))
        return m._get_phenotype_blendshape_coefficients(shape, empty_lc, empty_fa)

    def rest_heads(self, coeffs: torch.Tensor) -> torch.Tensor:
        """(n, coeffs) -> (n, bones, 3) rest bone heads."""
        return self.heads0[None] + torch.einsum("cbd,nc->nbd", self.heads_bs, coeffs)

    def rest_kp_points(self, coeffs: torch.Tensor) -> torch.Tensor:
        """(n, coeffs) -> (n, joints, bones, 3) folded weighted rest points."""
        return self.kp_pts0[None] + torch.einsum("ckbd,nc->nkbd", self.kp_pts_bs, coeffs)

    def rest_vertices(self, coeffs: torch.Tensor) -> torch.Tensor:
        """(n, coeffs) -> (n, verts, 3) rest mesh vertices (whole mesh: slower)."""
        return self.model.get_rest_vertices(coeffs)


def _levels(parent: np.ndarray) -> tuple[torch.Tensor, ...]:
    depth = np.zeros(len(parent), dtype=np.int64)
    for b in range(1, len(parent)):
        if parent[b] >= b:
            raise ValueError(f"anny rig: bone {b} has parent {parent[b]} that does not precede it")
        depth[b] = depth[parent[b]] + 1
    return tuple(torch.as_tensor(np.flatnonzero(depth == d)) for d in range(int(depth.max()) + 1))


@lru_cache(maxsize=4)
def anny_body(rig: str = DEFAULT_RIG, topology: str = DEFAULT_TOPOLOGY) -> AnnyBody:
    """Build (or load from the cache) anny and fold its COCO(+feet) regressor per bone.

    Only topologies that ship with anny are accepted: ``smpl``/``smplx`` would download
    non-commercial data. Raises ``ValueError`` for those and for unknown rigs.
    """
    if topology.split("-")[0] not in _SAFE_TOPOLOGIES:
        raise ValueError(
            f"anny topology {topology!r} is not allowed (allowed: {_SAFE_TOPOLOGIES}); "
            "the smpl/smplx topologies download non-commercial data"
        )
    anny = _import_anny()
    from anny.paths import get_anny_root_dir

    torch.set_default_dtype(torch.float32)
    logger.info("building anny rig=%s topology=%s (cache %s)", rig, topology, anny_cache_dir())
    model = anny.Anny(rig=rig, topology=topology, skinning_method="lbs").to(torch.float64)
    model.eval()
    for p in model.parameters():
        p.requires_grad_(False)

    parent = np.asarray(model.bone_parents, dtype=np.int64)
    parent[0] = -1
    weights = model.dense_vertex_bone_weights  # (verts, bones)

    kp = torch.load(
        get_anny_root_dir() / "data" / "keypoints" / "coco.pth", weights_only=True, map_location="cpu"
    )
    missing = [n for n in COCO17_FEET if n not in kp]
    if missing:
        raise ValueError(f"anny coco.pth lacks keypoints {missing} (has {list(kp)})")
    base_idx = model.base_mesh_vertex_indices.cpu()
    reg = torch.stack([kp[n][base_idx].to(torch.float64) for n in COCO17_FEET])  # (joints, verts)
    reg = reg / reg.sum(dim=1, keepdim=True)

    kp_w = reg @ weights  # (joints, bones)
    kp_pts0 = torch.einsum("kv,vb,vd->kbd", reg, weights, model.template_vertices)
    kp_pts_bs = torch.einsum("kv,vb,cvd->ckbd", reg, weights, model.blendshapes)
    tri = model.faces if model.faces.shape[-1] == 3 else model.get_triangular_faces()

    return AnnyBody(
        model=model,
        rig=rig,
        topology=topology,
        bone_names=tuple(model.bone_labels),
        bone_parent=parent,
        levels=_levels(parent),
        heads0=model.template_bone_heads.clone(),
        heads_bs=model.bone_heads_blendshapes.clone(),
        kp_w=kp_w,
        kp_pts0=kp_pts0,
        kp_pts_bs=kp_pts_bs,
        joint_names=COCO17_FEET,
        faces=np.asarray(tri.cpu().numpy(), dtype=np.int64),
        vertex_bone=np.asarray(weights.argmax(dim=1).cpu().numpy(), dtype=np.int64),
    )


FIT_DTYPES: dict[str, torch.dtype] = {"float32": torch.float32, "float64": torch.float64}
"""``FitConfig.precision`` names."""


@lru_cache(maxsize=4)
def anny_fit_body(rig: str = DEFAULT_RIG, precision: str = "float32") -> AnnyBody:
    """``anny_body(rig)`` computing in the fit's precision (cached; the float32 copy of the
    anny module takes ~27 MB next to the float64 one's 53 MB)."""
    if precision not in FIT_DTYPES:
        raise ValueError(f"fit precision must be one of {sorted(FIT_DTYPES)}, got {precision!r}")
    return anny_body(rig, DEFAULT_TOPOLOGY).to(FIT_DTYPES[precision])
