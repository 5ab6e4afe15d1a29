"""The loss of the sequence fit, as small named terms (torch).

Each term is an object with the weight it takes from ``FitConfig`` and ``__call__(state)``:
``weight * value(state)``, a scalar tensor, from the ``FitState`` of one evaluation. The fit
selects its terms by name from ``LOSS_TERMS`` (``DEFAULT_TERMS`` unless told otherwise);
``build`` leaves out a term that is off (zero weight, or nothing to act on), ``applies``
one that a pass does not use (the reprojection term in the 3D-only pass, the jerk term before
the re-weighting). The loss is the sum of the terms in the order selected; its parts are
reported under the same names (``loss_<name>`` in the stage's metrics).

Rows are person-major (``row = person * frames + frame``). Paper: eq. 3 of section 3.3
(w1..w5 = ``w_2d``, ``w_3d``, ``w_reg``, ``w_smooth``, ``w_prior``); the other terms are ours.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from pipeline.backends.fitting.body_model import BodyModel, FitState, PriorFn
from pipeline.backends.fitting.common import joint_idx
from pipeline.backends.fitting.config import FitConfig
from pipeline.backends.fitting.contacts import ProxyOverlap
from pipeline.schema.joints import COCO17_FEET, FOOT_JOINTS

FOOT_KEYPOINTS: tuple[int, ...] = tuple(
    i for i, n in enumerate(COCO17_FEET) if n.endswith(("_ankle", "_heel", "_toe"))
)
"""Ankles, heels and toes (indices into COCO-17 + feet, whose first 17 are COCO-17)."""


@dataclass(frozen=True)
class Targets:
    """The observations of every row as tensors of the fit's dtype.

    kp3d_m: (rows, joints, 3) triangulated joints; w3d: (rows, joints) their weights, 0 where
    invalid; uv_px: (views, rows, joints, 2) undistorted 2D keypoints; w2d: (views, rows,
    joints) their weights; P_px: (views, 3, 4) projections to undistorted pixels; present:
    (persons, frames) bool, enough valid joints to count the person as there.
    """

    kp3d_m: torch.Tensor
    w3d: torch.Tensor
    uv_px: torch.Tensor
    w2d: torch.Tensor
    P_px: torch.Tensor
    present: torch.Tensor
    n_persons: int
    n_frames: int


@dataclass(frozen=True)
class TermContext:
    """What a term is built from: the settings, the bound body model and the targets."""

    cfg: FitConfig
    body: BodyModel
    targets: Targets


class LossTerm:
    """A named, weighted part of the loss: ``term(state) = weight * value(state)``."""

    name: ClassVar[str]
    """Key of the term in the loss parts and in ``LOSS_TERMS``."""

    def __init__(self, weight: float, ctx: TermContext) -> None:
        self.weight = weight
        self.ctx = ctx

    @classmethod
    def build(cls, ctx: TermContext) -> LossTerm | None:
        """The term for this fit, or None when it is off."""
        raise NotImplementedError

    def applies(self, state: FitState) -> bool:
        """Whether the term is part of the loss in this evaluation's pass."""
        del state
        return True

    def value(self, state: FitState) -> torch.Tensor:
        """The unweighted term (scalar)."""
        raise NotImplementedError

    def __call__(self, state: FitState) -> torch.Tensor:
        return self.weight * self.value(state)


def reprojection_term(
    kp: torch.Tensor, P_px: torch.Tensor, uv_px: torch.Tensor, w2d: torch.Tensor, cfg: FitConfig
) -> torch.Tensor:
    """Unweighted L2D of eq. 3: confidence-weighted robust reprojection error, summed (px²).

    kp: (n, joints, 3) world keypoints; P_px: (views, 3, 4) to undistorted pixels;
    uv_px: (views, n, joints, 2); w2d: (views, n, joints), 0 where unusable. The robust
    function is Geman-McClure with scale ``cfg.gm_sigma_px`` (or plain squares, ``robust_2d``).
    """
    h = torch.einsum("vij,nkj->vnki", P_px[:, :, :3], kp) + P_px[:, None, None, :, 3]
    proj = h[..., :2] / h[..., 2:].clamp(min=1e-3)
    r2 = (proj - uv_px).square().sum(-1)
    s2 = cfg.gm_sigma_px**2
    rho = s2 * r2 / (s2 + r2) if cfg.robust_2d == "gm" else r2
    return (w2d * rho).sum()


def accel_term(
    kp: torch.Tensor,
    scale_m: float,
    whole_body: float = 1.0,
    weights: torch.Tensor | None = None,
    relief: torch.Tensor | None = None,
) -> torch.Tensor:
    """Sum of (pseudo-Huber, scale ``scale_m``; 0: plain) squared second differences of
    keypoints ``kp`` (persons, frames, joints, 3) along frames (m^2 per frame^2).

    The keypoints above the feet have their acceleration a_j split into the person's
    whole-body acceleration ā (their mean) and the rest: |a_j|² → |a_j − ā|² +
    ``whole_body`` · |ā|². Below 1, the body (footwork, weight shifts) may accelerate more
    freely than one limb relative to it. The feet (``FOOT_KEYPOINTS``) keep their plain
    squared acceleration, so that a planted foot stays still while the body shifts its weight.

    ``weights`` (persons, frames - 2, joints), from ``adaptive_accel_weights``, replace the
    pseudo-Huber: each keypoint's squared term is multiplied by its weight at that frame.
    ``relief`` (persons, frames - 2, joints), from ``fast_view_relief``, multiplies each
    keypoint's term at that frame (after the pseudo-Huber or the weights)."""
    a = kp[:, 2:] - 2 * kp[:, 1:-1] + kp[:, :-2]
    nj = a.shape[2]
    feet = [i for i in FOOT_KEYPOINTS if i < nj]
    body = [i for i in range(nj) if i not in feet]
    if body:
        ab = a[:, :, body]
        mean = ab.mean(dim=2, keepdim=True)
        split = (ab - mean).square().sum(-1) + whole_body * mean.square().sum(-1)
        a2 = torch.cat([split, a[:, :, feet].square().sum(-1)], dim=2)
    else:
        a2 = a.square().sum(-1)
    if weights is not None:
        if weights.shape != a.shape[:3]:
            raise ValueError(
                f"accel_term: weights of shape {tuple(weights.shape)}, need {tuple(a.shape[:3])}"
            )
        a2 = a2 * weights[:, :, body + feet].to(a2.dtype)
    elif scale_m > 0:  # quadratic for jitter, linear for genuine fast motion (punches)
        d2 = scale_m**2
        a2 = 2 * d2 * (torch.sqrt(1 + a2 / d2) - 1)
    if relief is not None:
        a2 = a2 * relief[:, :, body + feet].to(a2.dtype)
    return a2.sum()


def jerk_term(kp: torch.Tensor, accel_weights: torch.Tensor, relief: torch.Tensor | None = None) -> torch.Tensor:
    """Sum of squared third differences of keypoints ``kp`` (persons, frames, joints, 3)
    along frames (m² per frame⁶), each weighted by the smaller of the two re-weighted
    acceleration weights (``adaptive_accel_weights``, (persons, frames - 2, joints)) it
    spans: strong where a keypoint is at rest, weak in a punch or a step.

    Against the acceleration penalty alone, a smoother of higher order passes the slow
    motion and stops the frame-to-frame noise more sharply. ``relief`` (as ``accel_term``'s)
    multiplies those weights."""
    if accel_weights.shape != (kp.shape[0], kp.shape[1] - 2, kp.shape[2]):
        raise ValueError(
            f"jerk_term: weights of shape {tuple(accel_weights.shape)} for keypoints of shape {tuple(kp.shape)}"
        )
    j = kp[:, 3:] - 3 * kp[:, 2:-1] + 3 * kp[:, 1:-2] - kp[:, :-3]
    if relief is not None:
        accel_weights = accel_weights * relief.to(accel_weights.dtype)
    w = torch.minimum(accel_weights[:, 1:], accel_weights[:, :-1]).to(j.dtype)
    return (j.square().sum(-1) * w).sum()


def ground_term(kp: torch.Tensor, foot: torch.Tensor, sole_z: torch.Tensor) -> torch.Tensor:
    """Unweighted ground term: squared depth below z = 0 (m²) of the foot keypoints
    ``kp[:, foot]`` and of the sole vertices' heights ``sole_z``."""
    return torch.relu(-kp[:, foot, 2]).square().sum() + torch.relu(-sole_z).square().sum()


WRISTS: tuple[int, ...] = (COCO17_FEET.index("left_wrist"), COCO17_FEET.index("right_wrist"))


def fast_view_relief(targets: Targets, cfg: FitConfig) -> torch.Tensor | None:
    """(persons, frames - 2, joints) factors of the temporal penalties: ``cfg.accel_fast_view_scale``
    at a wrist and frame where some view's 2D keypoint of it moves faster than
    ``cfg.accel_fast_view_px`` per frame (central difference, both neighbours seen), and at the
    frames either side; 1 elsewhere. None when ``accel_fast_view_px`` is 0 or there are fewer
    than 3 frames. Row r is frame r + 1, as in ``accel_term``."""
    if cfg.accel_fast_view_px <= 0 or targets.n_frames < 3:
        return None
    nv, P, F = targets.uv_px.shape[0], targets.n_persons, targets.n_frames
    uv = targets.uv_px.reshape(nv, P, F, -1, 2)
    seen = targets.w2d.reshape(nv, P, F, -1) > 0
    speed_px = (uv[:, :, 2:] - uv[:, :, :-2]).norm(dim=-1) / 2
    fast = ((speed_px > cfg.accel_fast_view_px) & seen[:, :, 2:] & seen[:, :, :-2]).any(dim=0)
    near = fast.clone()
    near[:, 1:] |= fast[:, :-1]
    near[:, :-1] |= fast[:, 1:]
    relief = torch.ones(near.shape, dtype=targets.kp3d_m.dtype)
    wrists = list(WRISTS)
    relief[:, :, wrists] = torch.where(near[:, :, wrists], cfg.accel_fast_view_scale, 1.0).to(relief.dtype)
    return relief


def _by_frame(t: torch.Tensor, ctx: TermContext) -> torch.Tensor:
    """(rows, ...) -> (persons, frames, ...)."""
    return t.reshape(ctx.targets.n_persons, ctx.targets.n_frames, *t.shape[1:])


class Triangulated(LossTerm):
    """w2 of eq. 3: confidence-weighted squared distance of the keypoints to the
    triangulated joints, summed over rows and joints (m²)."""

    name = "3d"

    @classmethod
    def build(cls, ctx: TermContext) -> LossTerm | None:
        return cls(ctx.cfg.w_3d, ctx)

    def value(self, state: FitState) -> torch.Tensor:
        t = self.ctx.targets
        return (t.w3d * (state.kp - t.kp3d_m).square().sum(-1)).sum()


class Reprojection(LossTerm):
    """w1 of eq. 3: robust reprojection error in every view (``reprojection_term``, px²);
    in the full pass only (``FitState.use_2d``)."""

    name = "2d"

    @classmethod
    def build(cls, ctx: TermContext) -> LossTerm | None:
        return cls(ctx.cfg.w_2d, ctx) if ctx.cfg.w_2d > 0 else None

    def applies(self, state: FitState) -> bool:
        return state.use_2d

    def value(self, state: FitState) -> torch.Tensor:
        t = self.ctx.targets
        return reprojection_term(state.kp, t.P_px, t.uv_px, t.w2d, self.ctx.cfg)


class Regularisation(LossTerm):
    """w3 of eq. 3 (Lreg): squared magnitude of the non-root bone rotations (rad²)."""

    name = "reg"

    @classmethod
    def build(cls, ctx: TermContext) -> LossTerm | None:
        return cls(ctx.cfg.w_reg, ctx)

    def value(self, state: FitState) -> torch.Tensor:
        return state.pose.square().sum()


class Smoothness(LossTerm):
    """w4 of eq. 3 (Lsmooth), between consecutive frames: squared change of the non-root
    rotations plus half the squared change of the root rotation matrix (rad²), plus the
    squared displacement of every mesh vertex (m², exact for linear blend skinning through
    the model's mesh moments; pose blend shapes ignored)."""

    name = "smooth"

    def __init__(self, weight: float, ctx: TermContext) -> None:
        super().__init__(weight, ctx)
        self.L = ctx.body.mesh_moment_factors()  # (persons, bones * 4, rank)

    @classmethod
    def build(cls, ctx: TermContext) -> LossTerm | None:
        return cls(ctx.cfg.w_smooth, ctx) if ctx.cfg.w_smooth > 0 and ctx.targets.n_frames > 1 else None

    def mesh_velocity(self, dA: torch.Tensor) -> torch.Tensor:
        """dA: (persons, steps, bones, 3, 4) bone transform differences -> the summed squared
        vertex displacement (m²): ``|Z L|²`` with Z stacking the rows of every ``dA_b``."""
        p, t, nb = dA.shape[:3]
        Z = dA.permute(0, 1, 3, 2, 4).reshape(p, t * 3, nb * 4)
        return (Z @ self.L).square().sum()

    def value(self, state: FitState) -> torch.Tensor:
        G, x = state.skeleton.G, state.skeleton.x
        nb = G.shape[-3]
        pz = _by_frame(state.pose, self.ctx)
        gz = _by_frame(state.G_root, self.ctx)
        sm = (pz[:, 1:] - pz[:, :-1]).square().sum() + 0.5 * (gz[:, 1:] - gz[:, :-1]).square().sum()
        t = x - (G @ state.rest.joints[..., None])[..., 0]
        A = torch.cat([G, t[..., None]], dim=-1).reshape(self.ctx.targets.n_persons, self.ctx.targets.n_frames, nb, 3, 4)
        return sm + self.mesh_velocity(A[:, 1:] - A[:, :-1])


class Acceleration(LossTerm):
    """Pseudo-Huber squared second differences of the keypoints (``accel_term``, m² per
    frame²); re-weighted per keypoint and frame once ``FitState.accel_weights`` are set."""

    name = "accel"

    def __init__(self, weight: float, ctx: TermContext) -> None:
        super().__init__(weight, ctx)
        self.relief = fast_view_relief(ctx.targets, ctx.cfg)

    @classmethod
    def build(cls, ctx: TermContext) -> LossTerm | None:
        return cls(ctx.cfg.w_accel, ctx) if ctx.cfg.w_accel > 0 and ctx.targets.n_frames > 2 else None

    def value(self, state: FitState) -> torch.Tensor:
        cfg = self.ctx.cfg
        kp = _by_frame(state.kp, self.ctx)
        return accel_term(kp, cfg.accel_scale_m, cfg.accel_whole_body, state.accel_weights, self.relief)


class Jerk(LossTerm):
    """Weighted squared third differences of the keypoints (``jerk_term``, m² per frame⁶);
    only once the acceleration penalty is re-weighted (it takes those weights)."""

    name = "jerk"

    def __init__(self, weight: float, ctx: TermContext) -> None:
        super().__init__(weight, ctx)
        self.relief = fast_view_relief(ctx.targets, ctx.cfg)

    @classmethod
    def build(cls, ctx: TermContext) -> LossTerm | None:
        return cls(ctx.cfg.w_jerk, ctx) if ctx.cfg.w_jerk > 0 and ctx.targets.n_frames > 3 else None

    def applies(self, state: FitState) -> bool:
        return state.accel_weights is not None

    def value(self, state: FitState) -> torch.Tensor:
        if state.accel_weights is None:
            raise ValueError("Jerk: needs the re-weighted acceleration weights (FitState.accel_weights)")
        return jerk_term(_by_frame(state.kp, self.ctx), state.accel_weights, self.relief)


class Landmarks(LossTerm):
    """Squared norm of the per-person landmark offsets (m²), with ``calibrate_landmarks``."""

    name = "landmarks"

    @classmethod
    def build(cls, ctx: TermContext) -> LossTerm | None:
        return cls(ctx.cfg.w_landmarks, ctx) if ctx.cfg.calibrate_landmarks else None

    def value(self, state: FitState) -> torch.Tensor:
        return state.offsets.square().sum()


class ShapeRegularisation(LossTerm):
    """A weak pull (weight 1e-4) of the refined shape towards the model's average: squared
    ``BodyModel.shape_deviation`` (unitless), with ``refine_shape``."""

    name = "shape"
    WEIGHT: ClassVar[float] = 1e-4

    @classmethod
    def build(cls, ctx: TermContext) -> LossTerm | None:
        return cls(cls.WEIGHT, ctx) if ctx.cfg.refine_shape else None

    def value(self, state: FitState) -> torch.Tensor:
        return self.ctx.body.shape_deviation(state.shape_u).square().sum()


class JointLimits(LossTerm):
    """Soft anatomical joint limits: squared rotation beyond the model's per-bone ranges
    (``BodyModel.joint_limit_penalty``, rad²)."""

    name = "limits"

    @classmethod
    def build(cls, ctx: TermContext) -> LossTerm | None:
        return cls(ctx.cfg.w_limits, ctx)

    def value(self, state: FitState) -> torch.Tensor:
        return self.ctx.body.joint_limit_penalty(state)


class PosePrior(LossTerm):
    """w5 of eq. 3: the model's GMM pose prior, negative log-likelihood summed over rows
    (nats); off without a prior file (``BodyModel.pose_priors``) or at ``w_prior = 0``."""

    name = "prior"

    def __init__(self, weight: float, ctx: TermContext, prior: PriorFn) -> None:
        super().__init__(weight, ctx)
        self.prior = prior

    @classmethod
    def build(cls, ctx: TermContext) -> LossTerm | None:
        prior = ctx.body.pose_priors().get(cls.name)
        return cls(ctx.cfg.w_prior, ctx, prior) if ctx.cfg.w_prior > 0 and prior is not None else None

    def value(self, state: FitState) -> torch.Tensor:
        return self.prior(state)


class VPoserPrior(PosePrior):
    """w5 of eq. 3 with the user's VPoser (SMPL/SMPL-X, ``smpl.vposer``): its encoder-based
    prior summed over rows (unitless)."""

    name = "vposer"


class Ground(LossTerm):
    """Squared depth below the floor z = 0 of the foot keypoints and the model's sole
    vertices (``ground_term``, m²)."""

    name = "ground"

    def __init__(self, weight: float, ctx: TermContext) -> None:
        super().__init__(weight, ctx)
        self.foot = torch.as_tensor(joint_idx(FOOT_JOINTS))

    @classmethod
    def build(cls, ctx: TermContext) -> LossTerm | None:
        return cls(ctx.cfg.w_ground, ctx) if ctx.cfg.w_ground > 0 else None

    def value(self, state: FitState) -> torch.Tensor:
        sole_z = self.ctx.body.sole_heights(state)
        return ground_term(state.kp, self.foot, sole_z)


class Overlap(LossTerm):
    """Squared depth of the overlap between two persons' capsule proxies, over the frames
    where both are present (``contacts.ProxyOverlap``, m²); with two persons or more."""

    name = "overlap"

    def __init__(self, weight: float, ctx: TermContext) -> None:
        super().__init__(weight, ctx)
        self.overlap = ProxyOverlap()

    @classmethod
    def build(cls, ctx: TermContext) -> LossTerm | None:
        return cls(ctx.cfg.w_overlap, ctx) if ctx.cfg.w_overlap > 0 and ctx.targets.n_persons > 1 else None

    def value(self, state: FitState) -> torch.Tensor:
        return self.overlap(_by_frame(state.kp, self.ctx), self.ctx.targets.present)


LOSS_TERMS: dict[str, type[LossTerm]] = {
    t.name: t
    for t in (
        Triangulated,
        Reprojection,
        Regularisation,
        Smoothness,
        Acceleration,
        Jerk,
        Landmarks,
        ShapeRegularisation,
        JointLimits,
        PosePrior,
        VPoserPrior,
        Ground,
        Overlap,
    )
}
"""Every loss term by name."""

DEFAULT_TERMS: tuple[str, ...] = tuple(LOSS_TERMS)
"""The terms of the fit, in the order their values are summed (each still off when
``build`` says so)."""


def build_terms(names: tuple[str, ...], ctx: TermContext) -> list[LossTerm]:
    """The terms ``names`` (keys of ``LOSS_TERMS``, summed in that order) that are on for
    this fit. ``ValueError`` for an unknown or repeated name."""
    unknown = [n for n in names if n not in LOSS_TERMS]
    if unknown or len(set(names)) != len(names):
        raise ValueError(f"fit loss terms {names}: unknown {unknown} or repeated; known: {tuple(LOSS_TERMS)}")
    return [t for t in (LOSS_TERMS[n].build(ctx) for n in names) if t is not None]


def evaluate_terms(terms: list[LossTerm], state: FitState) -> dict[str, torch.Tensor]:
    """The weighted value of every term that applies to ``state``, by name."""
    return {t.name: t(state) for t in terms if t.applies(state)}
