"""anny as a ``fitting.body_model.BodyModel``: what the sequence fit needs of it.

Shape: anny's 6 phenotypes in [0, 1] (free parameters: their logits), from the limb lengths
with the girth held near ``FitConfig.girth_prior`` (``fit_init.fit_shapes``). Keypoints: the
folded COCO(+feet) regressor (``fk.SparseKeypoints``), exact for any shape and pose; the sole
vertices are folded the same way. Joint limits in per-bone frames built from the rest
skeleton (``priors``); the shipped or a user GMM pose prior over the full pose.
"""

from __future__ import annotations

import numpy as np
import torch

from pipeline.backends.anny.fit_init import IK_DRIVERS, fit_shapes, forward_kinematics_rootmat
from pipeline.backends.anny.fit_terms import lever_arms, mesh_moment_factors, rest_tails, sole_vertices
from pipeline.backends.anny.fk import SparseKeypoints, keypoints_from_bones
from pipeline.backends.anny.model import DEFAULT_SHAPE, AnnyBody
from pipeline.backends.anny.priors import GMMPrior, joint_limit_penalty, joint_limit_tables, load_pose_prior
from pipeline.backends.fitting.body_model import FitState, PriorFn, Rest, Skeleton
from pipeline.backends.fitting.common import PersonObservations
from pipeline.backends.fitting.config import FitConfig
from pipeline.schema.joints import COCO17_FEET

__all__ = ["AnnyFitBody"]

_SHAPE_SCALE = 0.3
"""Scale of the phenotype logits among the L-BFGS variables, relative to √frames."""


class AnnyFitBody:
    """anny (``AnnyBody``, at the fit's precision) for ``fitting.sequence.fit_sequence``.

    One fit at a time: ``bind`` fixes the persons; with ``refine_shape``, ``rest(u)`` also
    moves the folded keypoints and soles to the shape ``u`` (they are state of this object).
    """

    name = "anny"

    def __init__(self, body: AnnyBody) -> None:
        self.body = body
        self.rig = body.rig
        self.bone_names = body.bone_names
        self.bone_parents = tuple(int(p) for p in body.bone_parent)
        self.neutral_shape = DEFAULT_SHAPE.copy()
        self.dtype = body.dtype
        self.ik_drivers = tuple((body.bone_names.index(b), COCO17_FEET.index(k)) for b, k in IK_DRIVERS)
        self.landmark_bones = body.kp_w.argmax(dim=1)  # each keypoint's dominant bone

    def init_shape(self, observations: list[PersonObservations], cfg: FitConfig) -> torch.Tensor:
        return fit_shapes(self.body, observations, cfg)

    def bind(self, shape: torch.Tensor, row_person: torch.Tensor, cfg: FitConfig) -> None:
        body, dt = self.body, self.body.dtype
        self._rows, self._refine = row_person, cfg.refine_shape
        self._coeffs = coeffs = body.shape_coeffs(shape)
        heads_p = body.rest_heads(coeffs)  # (P, B, 3)
        kpts_p = body.rest_kp_points(coeffs)  # (P, J, B, 3)
        self._heads_rows = heads_p[row_person]
        eye = torch.eye(3, dtype=dt).expand(shape.shape[0], body.n_bones, 3, 3)
        self._rest_kp = keypoints_from_bones(body, eye, heads_p - heads_p[:, :1], heads_p, kpts_p).double().numpy()
        self._heads_np = heads_p[0].double().numpy()
        rest_v = body.rest_vertices(coeffs[:1])[0].double().numpy()  # (verts, 3), first person
        tails = rest_tails(body, self._heads_np, rest_v)
        frames, lo, hi = (
            torch.as_tensor(a, dtype=dt) for a in joint_limit_tables(body.bone_names, self._heads_np, tails)
        )
        self._limits = (frames, torch.nan_to_num(lo, neginf=-1e6), torch.nan_to_num(hi, posinf=1e6))
        self._prior: GMMPrior | None = (
            load_pose_prior(cfg.pose_prior_path, body.bone_names, cfg.rig) if cfg.w_prior > 0 else None
        )
        self._sparse_kp = SparseKeypoints(body, heads_p, kpts_p)
        self._sole_idx = torch.as_tensor(sole_vertices(body, rest_v))
        self._sole_w = body.model.dense_vertex_bone_weights[self._sole_idx]
        self._soles = SparseKeypoints(body, heads_p, self._sole_points(coeffs), weights=self._sole_w)

    def _sole_points(self, c: torch.Tensor) -> torch.Tensor:
        """(persons, soles, bones, 3) the sole vertices at coefficients ``c``, folded per bone."""
        m = self.body.model
        v = m.template_vertices[self._sole_idx] + torch.einsum("cvd,pc->pvd", m.blendshapes[:, self._sole_idx], c)
        return self._sole_w[None, :, :, None] * v[:, :, None, :]

    def rest_keypoints(self) -> np.ndarray:
        return self._rest_kp

    def lever_arms(self) -> np.ndarray:
        return lever_arms(self.body, self._rest_kp[0] + self._heads_np[0], self._heads_np)

    def landmark_scale(self, cfg: FitConfig) -> float:
        return cfg.landmark_step

    def encode_shape(self, shape: torch.Tensor, s: float) -> torch.Tensor:
        return torch.logit(shape.clamp(1e-4, 1 - 1e-4)) * s * _SHAPE_SCALE

    def decode_shape(self, v: torch.Tensor, s: float) -> torch.Tensor:
        return v / (s * _SHAPE_SCALE)

    def shape_of(self, u: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(u)

    def shape_deviation(self, u: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(u) - 0.5

    def rest(self, u: torch.Tensor | None) -> Rest:
        if u is None or not self._refine:
            return Rest(self._heads_rows)
        body = self.body
        c = body.shape_coeffs(torch.sigmoid(u))
        hp = body.rest_heads(c)
        self._sparse_kp.set_shape(hp, body.rest_kp_points(c))
        self._soles.set_shape(hp, self._sole_points(c))
        return Rest(hp[self._rows])

    def forward(self, rest: Rest, G_root: torch.Tensor, pose: torch.Tensor, root: torch.Tensor) -> Skeleton:
        G, x = forward_kinematics_rootmat(self.body, G_root, pose, root, rest.joints)
        return Skeleton(G, x, self._sparse_kp(G, x, self._rows))

    def mesh_moment_factors(self) -> torch.Tensor:
        return mesh_moment_factors(self.body, self._coeffs)

    def sole_heights(self, state: FitState) -> torch.Tensor:
        return self._soles(state.skeleton.G, state.skeleton.x, self._rows)[..., 2]

    def joint_limit_penalty(self, state: FitState) -> torch.Tensor:
        return joint_limit_penalty(state.pose_full, *self._limits)

    def pose_priors(self) -> dict[str, PriorFn]:
        prior = self._prior
        if prior is None:
            return {}
        return {"prior": lambda state: prior.pose_nll(state.pose_full)}
