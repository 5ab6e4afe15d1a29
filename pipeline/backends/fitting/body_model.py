"""What a parametric body model provides to the sequence fit (``fitting.sequence``).

anny (``anny.fit_body.AnnyFitBody``) and SMPL/SMPL-X (``smpl.fit.SmplFitBody``) implement
``BodyModel``; ``fit_sequence`` drives either with the same passes and the same loss terms
(``fitting.terms``). Rows are person-major throughout (``row = person * frames + frame``).

The variables of a fit: per person a shape (anny's 6 phenotypes, SMPL's 10 betas) and
landmark offsets; per row the root rotation (a correction ``delta`` of its initialisation
``R0``: ``G_root = R(delta) @ R0``), the root position (m) and the non-root bone rotations
(parent-local axis-angle, rad). The model maps them, through its rest skeleton, to world bone
frames and ``COCO17_FEET`` keypoints (``Skeleton``); the loss terms read the ``FitState``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch

from pipeline.backends.fitting.common import PersonObservations
from pipeline.backends.fitting.config import FitConfig


@dataclass(frozen=True)
class Rest:
    """The rest skeleton of every row at one shape.

    joints: (rows, bones, 3) rest joint positions (bone heads), model frame, m.
    shape: (rows, shape) per-row shape parameters, for a model whose skinning needs them
        (SMPL's shape blend shapes); None otherwise.
    """

    joints: torch.Tensor
    shape: torch.Tensor | None = None


@dataclass(frozen=True)
class Skeleton:
    """A model's forward kinematics of every row (world frame, z-up, m).

    G: (rows, bones, 3, 3) world bone rotations (rest -> posed); x: (rows, bones, 3) world
    joint positions; kp: (rows, joints, 3) ``COCO17_FEET`` keypoints without landmark
    offsets. A model may subclass it to carry what its own methods need again (SMPL: the
    local rotation matrices of its pose blend shapes).
    """

    G: torch.Tensor
    x: torch.Tensor
    kp: torch.Tensor


@dataclass(frozen=True)
class FitState:
    """One evaluation of the fit: the variables in physical units, the posed body, and what
    the pass asks for. What every loss term and the model's own terms read.

    pose: (rows, bones - 1, 3) non-root parent-local rotations (axis-angle, rad);
    G_root: (rows, 3, 3) world rotation of the root; pose_full: (rows, bones, 3) the root's
    world axis-angle followed by ``pose`` (what a ``BodyFit`` stores); root: (rows, 3) world
    position of the root joint (m); rest: the rest skeleton posed; skeleton: its forward
    kinematics; kp: (rows, joints, 3) keypoints with the landmark offsets (m); offsets:
    (persons, joints, 3) those offsets (m, rigid in ``landmark_bones``' frames); shape_u:
    (persons, shape) the model's free shape parameters; use_2d: whether the pass includes
    the reprojection term; accel_weights: (persons, frames - 2, joints) the re-weighted
    acceleration weights (``adaptive_accel_weights``), None before the re-weighting.
    """

    pose: torch.Tensor
    G_root: torch.Tensor
    pose_full: torch.Tensor
    root: torch.Tensor
    rest: Rest
    skeleton: Skeleton
    kp: torch.Tensor
    offsets: torch.Tensor
    shape_u: torch.Tensor
    use_2d: bool
    accel_weights: torch.Tensor | None


PriorFn = Callable[[FitState], torch.Tensor]
"""An unweighted pose prior: the state -> the negative log-likelihood summed over rows (nats)."""


class BodyModel(Protocol):
    """A body model as the sequence fit sees it. An adapter serves one fit at a time:
    ``bind`` fixes the persons (their initial shape and rows); the methods after it refer to
    them. Tensors are in ``dtype``; numpy results are float64.

    Shape variables. The L-BFGS variable of the shape is ``encode_shape(shape, s)`` (s =
    √frames, so that a per-person constant has the curvature of a per-frame variable);
    ``decode_shape`` undoes the scaling into the model's free parameters ``u``, which
    ``shape_of`` maps to the shape itself (anny: phenotypes = sigmoid(u); SMPL: betas = u).
    """

    name: str
    """Label in logs: ``"anny"``, ``"smpl-neutral"``."""
    rig: str
    """The rig name a ``BodyFit`` records."""
    bone_names: tuple[str, ...]
    """(bones,) the posed bones/joints, root first, parents before children."""
    bone_parents: tuple[int, ...]
    """(bones,) parent index of each bone, -1 for the root."""
    neutral_shape: np.ndarray
    """(shape,) the model's average shape (a ``BodyFit`` row of a person not fitted)."""
    dtype: torch.dtype
    """Floating-point type of the fit's tensors."""
    ik_drivers: tuple[tuple[int, int], ...]
    """(bone, keypoint) pairs of the swing initialisation, in FK order: the bone is rotated
    so that the keypoint points at its observation."""
    landmark_bones: torch.Tensor
    """(joints,) long: the bone in whose frame each keypoint's landmark offset is rigid."""

    def init_shape(self, observations: list[PersonObservations], cfg: FitConfig) -> torch.Tensor:
        """(persons, shape) shapes whose limb lengths fit the observed ones (``SHAPE_LIMBS``;
        L-BFGS, ``cfg.shape_iters`` iterations)."""
        ...

    def bind(self, shape: torch.Tensor, row_person: torch.Tensor, cfg: FitConfig) -> None:
        """Fix the persons of the fit: their initial shape (persons, shape) and the person of
        every row (rows,); builds what the methods below need (rest skeleton, joint limits,
        pose priors, mesh moments). ``ValueError`` for unreadable prior files."""
        ...

    def rest_keypoints(self) -> np.ndarray:
        """(persons, joints, 3) zero-pose keypoints at the initial shape, root joint at the
        origin, in the axes ``G_root`` rotates to the world (anny: the world's; SMPL: its
        own y-up frame); the root initialisation's Kabsch source."""
        ...

    def lever_arms(self) -> np.ndarray:
        """(bones,) RMS distance (m, >= 5 cm) from each bone to the keypoints its rotation
        moves, of the first person at rest: the scale of the bone's rotation variable."""
        ...

    def landmark_scale(self, cfg: FitConfig) -> float:
        """Scale of the landmark offsets among the L-BFGS variables, relative to √frames."""
        ...

    def encode_shape(self, shape: torch.Tensor, s: float) -> torch.Tensor:
        """(persons, shape) -> the scaled L-BFGS variable (see the class docstring)."""
        ...

    def decode_shape(self, v: torch.Tensor, s: float) -> torch.Tensor:
        """The scaled variable -> the model's free shape parameters ``u``."""
        ...

    def shape_of(self, u: torch.Tensor) -> torch.Tensor:
        """Free parameters ``u`` -> (persons, shape) shape (phenotypes, betas)."""
        ...

    def shape_deviation(self, u: torch.Tensor) -> torch.Tensor:
        """(persons, shape) deviation of the shape from the model's average, unitless: the
        shape regulariser's residual."""
        ...

    def rest(self, u: torch.Tensor | None) -> Rest:
        """The rows' rest skeleton at free shape ``u`` (None: the initial shape). A model
        that refines no shape (``FitConfig.refine_shape`` off) may ignore ``u``."""
        ...

    def forward(self, rest: Rest, G_root: torch.Tensor, pose: torch.Tensor, root: torch.Tensor) -> Skeleton:
        """Forward kinematics to the world bone frames and the ``COCO17_FEET`` keypoints
        (without landmark offsets): G_root (rows, 3, 3) world root rotation, pose (rows,
        bones - 1, 3) parent-local axis-angle (rad), root (rows, 3) world root joint (m)."""
        ...

    def mesh_moment_factors(self) -> torch.Tensor:
        """(persons, bones * 4, rank) factors ``L`` of the mesh's skinning moments at the
        initial shape (``common.lbs_moment_factors``): the summed squared vertex
        displacement of bone transform changes ``dA`` is ``|Z L|²`` (m²)."""
        ...

    def sole_heights(self, state: FitState) -> torch.Tensor:
        """(rows, soles) world heights (m) of the sole vertices (~24 per foot)."""
        ...

    def joint_limit_penalty(self, state: FitState) -> torch.Tensor:
        """Unweighted soft joint limits: summed squared rotation beyond the model's per-bone
        ranges (rad²)."""
        ...

    def pose_priors(self) -> dict[str, PriorFn]:
        """The pose priors the bound fit uses, by loss-term name (``"prior"``: a GMM;
        ``"vposer"``: VPoser); empty when none."""
        ...
