"""Body-model-independent pieces of the kinematic fit (anny and SMPL/SMPL-X share them).

The observations of one person, the L-BFGS driver, limb lengths for the shape
initialisation, the root initialisation by Kabsch on the torso, the swing rotation of the
limb initialisation, and the robust reprojection and keypoint-acceleration terms of the loss.
Everything works on ``COCO17_FEET`` keypoints; nothing here knows the body model.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass

import numpy as np
import roma
import torch

from pipeline.backends.fitting.config import FitConfig
from pipeline.schema.joints import BODY_LIMBS, COCO17_FEET

# Limbs whose length is (nearly) pose independent, used for the shape initialisation.
SHAPE_LIMBS: tuple[tuple[str, str], ...] = BODY_LIMBS + (
    ("left_ankle", "left_heel"),
    ("right_ankle", "right_heel"),
    ("left_heel", "left_big_toe"),
    ("right_heel", "right_big_toe"),
)
_EVALS_PER_ITER = 1.25
TORSO: tuple[str, ...] = ("left_shoulder", "right_shoulder", "left_hip", "right_hip")


@dataclass(frozen=True)
class PersonObservations:
    """One person's inputs, in ``COCO17_FEET`` order.

    Fields:
        kp3d_m: (frames, joints, 3) triangulated joints (anything where ``w3d == 0``).
        w3d: (frames, joints) confidence weights, 0 where invalid.
        uv_px: (views, frames, joints, 2) *undistorted* 2D keypoints.
        w2d: (views, frames, joints) confidence weights, 0 where invalid or below threshold.
    """

    kp3d_m: np.ndarray
    w3d: np.ndarray
    uv_px: np.ndarray
    w2d: np.ndarray


def joint_idx(names: tuple[str, ...]) -> list[int]:
    return [COCO17_FEET.index(n) for n in names]


ProgressFn = Callable[[float, "float | None", str], None]
"""``progress(done, total, message)``, the runner's ``StageContext.progress``."""


@dataclass
class _IterationCounter:
    report: ProgressFn
    total: int
    done: int = 0


_PROGRESS: ContextVar[_IterationCounter | None] = ContextVar("lbfgs_progress", default=None)


def lbfgs_budget(cfg: FitConfig) -> int:
    """L-BFGS iterations a fit runs at most: the shape pass, then the pose passes
    (``run_pose_passes``); the progress total."""
    return cfg.shape_iters + cfg.pose_iters_3d + (cfg.pose_iters if cfg.use_2d else 0)


@contextmanager
def report_lbfgs_progress(progress: ProgressFn | None, cfg: FitConfig) -> Iterator[None]:
    """While active, every ``run_lbfgs`` iteration calls ``progress(done, total, message)``
    with the iterations done over the whole fit (``lbfgs_budget``); a pass that converges
    early counts as its full budget. ``progress`` may raise to stop the fit."""
    if progress is None:
        yield
        return
    token = _PROGRESS.set(_IterationCounter(progress, max(1, lbfgs_budget(cfg))))
    try:
        yield
    finally:
        _PROGRESS.reset(token)


def run_lbfgs(
    params: list[torch.Tensor], closure: Callable[[], torch.Tensor], iters: int, cfg: FitConfig
) -> None:
    """Minimise ``closure()`` over ``params`` in place: L-BFGS with ``cfg``'s history and
    learning rate, strong Wolfe line search, at most ``iters`` iterations. Reports each
    iteration inside ``report_lbfgs_progress``."""
    if iters <= 0:
        return
    counter = _PROGRESS.get()
    start = counter.done if counter is not None else 0
    started = 0
    opt = torch.optim.LBFGS(
        params,
        lr=cfg.lbfgs_lr,
        max_iter=iters,
        max_eval=int(iters * _EVALS_PER_ITER) + 5,
        history_size=cfg.lbfgs_history,
        line_search_fn="strong_wolfe",
        tolerance_grad=1e-10,
        tolerance_change=1e-14,
    )

    def _closure() -> torch.Tensor:
        nonlocal started
        if counter is not None:  # torch counts an iteration before its line search evaluates
            k = int(opt.state[params[0]].get("n_iter", 0))
            if k > started:
                started = k
                done = min(start + k - 1, counter.total)
                counter.report(done, counter.total, f"L-BFGS iteration {done + 1}/{counter.total}")
        opt.zero_grad()
        loss = closure()
        loss.backward()
        return loss

    opt.step(_closure)
    if counter is not None:
        counter.done = min(start + iters, counter.total)
        counter.report(counter.done, counter.total, f"L-BFGS iteration {counter.done}/{counter.total}")


Evaluate = Callable[[bool, "torch.Tensor | None"], tuple[torch.Tensor, dict[str, torch.Tensor], torch.Tensor]]
"""``evaluate(use_2d, accel_weights) -> (loss, terms, keypoints (persons * frames, joints, 3))``."""


def run_pose_passes(
    params: list[torch.Tensor], evaluate: Evaluate, cfg: FitConfig, npers: int, nf: int
) -> torch.Tensor | None:
    """The pose optimisation both body models share: ``cfg.pose_iters_3d`` L-BFGS iterations
    without the reprojection term, then (``cfg.use_2d``) ``cfg.pose_iters`` of the full loss.

    After ``cfg.accel_adapt_after`` iterations of the full loss, the acceleration penalty is
    re-weighted per keypoint and frame from the motion fitted so far
    (``adaptive_accel_weights``), and the remaining iterations run with those weights (the
    L-BFGS history restarts, as the loss changed). Returns the weights, or None when the
    penalty was not re-weighted; the caller evaluates its final loss with them."""
    run_lbfgs(params, lambda: evaluate(False, None)[0], cfg.pose_iters_3d, cfg)
    if not cfg.use_2d:
        return None
    adapt = 0 < cfg.accel_adapt_after < cfg.pose_iters and cfg.w_accel > 0 and nf > 2
    n1 = cfg.accel_adapt_after if adapt else cfg.pose_iters
    run_lbfgs(params, lambda: evaluate(True, None)[0], n1, cfg)
    if not adapt:
        return None
    with torch.no_grad():
        kp = evaluate(True, None)[2]
    w = adaptive_accel_weights(
        kp.reshape(npers, nf, kp.shape[-2], 3),
        cfg.accel_adapt_scale_m,
        cfg.accel_adapt_window,
        cfg.accel_adapt_gain,
    )
    run_lbfgs(params, lambda: evaluate(True, w)[0], cfg.pose_iters - n1, cfg)
    return w


def observed_lengths(obs: PersonObservations) -> tuple[np.ndarray, np.ndarray]:
    """Median length (m) and a weight per ``SHAPE_LIMBS`` limb (0 when never observed)."""
    lengths, weights = [], []
    for a, b in SHAPE_LIMBS:
        ia, ib = COCO17_FEET.index(a), COCO17_FEET.index(b)
        ok = (obs.w3d[:, ia] > 0) & (obs.w3d[:, ib] > 0)
        if ok.sum() < 3:
            lengths.append(0.0)
            weights.append(0.0)
            continue
        d = np.linalg.norm(obs.kp3d_m[ok, ia] - obs.kp3d_m[ok, ib], axis=-1)
        lengths.append(float(np.median(d)))
        weights.append(float(np.sqrt(obs.w3d[ok, ia] * obs.w3d[ok, ib]).mean()))
    return np.array(lengths), np.array(weights)


def kabsch(X: np.ndarray, Y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising sum w |R X + t - Y|^2 (X, Y: (n, 3))."""
    wn = w / w.sum()
    mx, my = wn @ X, wn @ Y
    H = ((X - mx) * wn[:, None]).T @ (Y - my)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, my - R @ mx


def init_roots(rest_kp: np.ndarray, obs: PersonObservations) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-frame root rotation (frames, 3, 3) and position (frames, 3) from the torso; and the
    frames where the torso (3+ of shoulders/hips) was seen. ``rest_kp``: zero-pose keypoints
    with the root head at the origin."""
    nf = obs.kp3d_m.shape[0]
    t_idx = joint_idx(TORSO) + joint_idx(("nose", "left_ear", "right_ear"))
    R = np.tile(np.eye(3), (nf, 1, 1))
    t = np.zeros((nf, 3))
    ok = np.zeros(nf, dtype=bool)
    for f in range(nf):
        w = obs.w3d[f, t_idx].copy()
        w[4:] *= 0.3
        if (w[:4] > 0).sum() >= 3:
            R[f], t[f] = kabsch(rest_kp[t_idx], obs.kp3d_m[f, t_idx], w)
            ok[f] = True
    if not ok.any():
        return R, t, ok
    good = np.flatnonzero(ok)
    for f in np.flatnonzero(~ok).tolist():  # nearest seen frame
        g = int(good[np.argmin(np.abs(good - f))])
        R[f], t[f] = R[g], t[g]
    return R, t, ok


def min_rotation(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(n, 3, 3) smallest rotations taking directions ``a`` to ``b`` (n, 3)."""
    a = a / a.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    b = b / b.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    axis = torch.linalg.cross(a, b)
    s = axis.norm(dim=-1, keepdim=True)
    c = (a * b).sum(-1, keepdim=True)
    angle = torch.atan2(s, c)
    return roma.rotvec_to_rotmat(axis / s.clamp(min=1e-9) * angle)


def reprojection_term(
    kp: torch.Tensor, P_px: torch.Tensor, uv_px: torch.Tensor, w2d: torch.Tensor, cfg: FitConfig
) -> torch.Tensor:
    """Unweighted L2D of eq. 3: confidence-weighted robust reprojection error, summed.

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


FOOT_KEYPOINTS: tuple[int, ...] = tuple(
    i for i, n in enumerate(COCO17_FEET) if n.endswith(("_ankle", "_heel", "_toe"))
)
"""Ankles, heels and toes (indices into COCO-17 + feet, whose first 17 are COCO-17)."""


def accel_term(
    kp: torch.Tensor, scale_m: float, whole_body: float = 1.0, weights: torch.Tensor | None = None
) -> torch.Tensor:
    """Sum of (pseudo-Huber, scale ``scale_m``; 0: plain) squared second differences of
    keypoints ``kp`` (persons, frames, joints, 3) along frames (m^2 per frame^2).

    The keypoints above the feet have their acceleration a_j split into the person's
    whole-body acceleration ā (their mean) and the rest: |a_j|² → |a_j − ā|² +
    ``whole_body`` · |ā|². Below 1, the body (footwork, weight shifts) may accelerate more
    freely than one limb relative to it. The feet (``FOOT_KEYPOINTS``) keep their plain
    squared acceleration, so that a planted foot stays still while the body shifts its weight.

    ``weights`` (persons, frames - 2, joints), from ``adaptive_accel_weights``, replace the
    pseudo-Huber: each keypoint's squared term is multiplied by its weight at that frame."""
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
        return (a2 * weights[:, :, body + feet].to(a2.dtype)).sum()
    if scale_m > 0:  # quadratic for jitter, linear for genuine fast motion (punches)
        d2 = scale_m**2
        a2 = 2 * d2 * (torch.sqrt(1 + a2 / d2) - 1)
    return a2.sum()


def jerk_term(kp: torch.Tensor, accel_weights: torch.Tensor) -> torch.Tensor:
    """Sum of squared third differences of keypoints ``kp`` (persons, frames, joints, 3)
    along frames (m² per frame⁶), each weighted by the smaller of the two re-weighted
    acceleration weights (``adaptive_accel_weights``, (persons, frames - 2, joints)) it
    spans: strong where a keypoint is at rest, weak in a punch or a step.

    Against the acceleration penalty alone, a smoother of higher order passes the slow
    motion and stops the frame-to-frame noise more sharply."""
    if accel_weights.shape != (kp.shape[0], kp.shape[1] - 2, kp.shape[2]):
        raise ValueError(
            f"jerk_term: weights of shape {tuple(accel_weights.shape)} for keypoints of shape {tuple(kp.shape)}"
        )
    j = kp[:, 3:] - 3 * kp[:, 2:-1] + 3 * kp[:, 1:-2] - kp[:, :-3]
    w = torch.minimum(accel_weights[:, 1:], accel_weights[:, :-1]).to(j.dtype)
    return (j.square().sum(-1) * w).sum()


def adaptive_accel_weights(kp: torch.Tensor, scale_m: float, window: int, gain: float) -> torch.Tensor:
    """Per keypoint and frame weights of the acceleration penalty, from a motion fitted so
    far: ``kp`` (persons, frames, joints, 3) → (persons, frames - 2, joints).

    m is the root mean square of the keypoint's acceleration |a| over the ``window`` frames
    either side; the weight is ``gain · s² / (s² + m²)`` with s = ``scale_m``. A keypoint at
    rest is smoothed ``gain`` times harder than the plain penalty, one in a punch or a step
    (m ≫ s) much less: the penalty acts as the smoother of a motion whose acceleration
    variance changes over time, with the variance estimated from the fit itself."""
    with torch.no_grad():
        a2 = (kp[:, 2:] - 2 * kp[:, 1:-1] + kp[:, :-2]).square().sum(-1)
        if window > 0:
            k = 2 * window + 1
            padded = torch.nn.functional.pad(a2.permute(0, 2, 1), (window, window), mode="replicate")
            a2 = torch.nn.functional.avg_pool1d(padded, k, stride=1).permute(0, 2, 1)
        return gain * scale_m**2 / (scale_m**2 + a2)


def sequence_terms(
    cfg: FitConfig,
    kp: torch.Tensor,
    kp3d: torch.Tensor,
    w3d: torch.Tensor,
    P_px: torch.Tensor,
    uv_px: torch.Tensor,
    w2d: torch.Tensor,
    use_2d: bool,
    pose: torch.Tensor,
    G_root: torch.Tensor,
    G: torch.Tensor,
    x: torch.Tensor,
    rest_heads: torch.Tensor,
    npers: int,
    nf: int,
    mesh_velocity: Callable[[torch.Tensor], torch.Tensor] | None,
    accel_weights: torch.Tensor | None = None,
) -> dict[str, torch.Tensor]:
    """The weighted loss terms both body models share, in this order: ``3d``, ``2d``
    (when ``use_2d``), ``reg``, ``smooth``, ``accel``, ``jerk`` (with ``accel_weights``).

    Rows are person-major (``npers * nf``): kp, kp3d (rows, joints, 3); w3d (rows, joints);
    pose (rows, bones - 1, 3) local rotation vectors; G_root (rows, 3, 3); G (rows, bones,
    3, 3) and x (rows, bones, 3) world bone frames, ``rest_heads`` (rows, bones, 3) their
    rest positions. ``mesh_velocity`` maps the frame-to-frame change of the bones' affine
    transforms (persons, frames - 1, bones, 3, 4) to the summed squared mesh-vertex velocity;
    None leaves out ``smooth``. ``accel_weights``: see ``accel_term``; the ``jerk`` term
    (``jerk_term``) needs them, so it acts only in the re-weighted iterations.
    """
    out: dict[str, torch.Tensor] = {}
    out["3d"] = cfg.w_3d * (w3d * (kp - kp3d).square().sum(-1)).sum()
    if use_2d and cfg.w_2d > 0:
        out["2d"] = cfg.w_2d * reprojection_term(kp, P_px, uv_px, w2d, cfg)
    out["reg"] = cfg.w_reg * pose.square().sum()
    nb = G.shape[-3]
    if mesh_velocity is not None and nf > 1:
        pz = pose.reshape(npers, nf, nb - 1, 3)
        gz = G_root.reshape(npers, nf, 3, 3)
        sm = (pz[:, 1:] - pz[:, :-1]).square().sum() + 0.5 * (gz[:, 1:] - gz[:, :-1]).square().sum()
        t = x - (G @ rest_heads[..., None])[..., 0]
        A = torch.cat([G, t[..., None]], dim=-1).reshape(npers, nf, nb, 3, 4)
        out["smooth"] = cfg.w_smooth * (sm + mesh_velocity(A[:, 1:] - A[:, :-1]))
    if cfg.w_accel > 0 and nf > 2:  # pseudo-Huber: quadratic for jitter, linear for punches
        out["accel"] = cfg.w_accel * accel_term(
            kp.reshape(npers, nf, kp.shape[-2], 3), cfg.accel_scale_m, cfg.accel_whole_body, accel_weights
        )
    if cfg.w_jerk > 0 and accel_weights is not None and nf > 3:
        out["jerk"] = cfg.w_jerk * jerk_term(kp.reshape(npers, nf, kp.shape[-2], 3), accel_weights)
    return out


def ground_term(kp: torch.Tensor, foot: torch.Tensor, sole_z: torch.Tensor) -> torch.Tensor:
    """Unweighted ground term: squared depth below z = 0 of the foot keypoints ``kp[:, foot]``
    and of the sole vertices' heights ``sole_z``."""
    return torch.relu(-kp[:, foot, 2]).square().sum() + torch.relu(-sole_z).square().sum()


def lbs_moment_factors(rest_vertices: list[torch.Tensor], weights: torch.Tensor) -> torch.Tensor:
    """Factors ``L`` (persons, bones * 4, rank) with ``sum_v |dv'|^2 = |Z L|^2`` for linear
    blend skinning with per-bone transform differences ``dA_b`` (rows of every ``dA_b``
    stacked in ``Z``): ``S = sum_v (w_v (x) [v; 1])(w_v (x) [v; 1])^T = L L^T`` by
    eigen-decomposition, one per person's rest vertices (V, 3); ``weights`` (V, bones)."""
    factors = []
    for v in rest_vertices:
        vt = torch.cat([v, torch.ones_like(v[:, :1])], dim=1)
        X = (weights[:, :, None] * vt[:, None, :]).reshape(v.shape[0], -1)
        lam, U = torch.linalg.eigh(X.T @ X)
        keep = lam > lam.max() * 1e-12
        factors.append(U[:, keep] * lam[keep].sqrt())
    rank = max(f.shape[1] for f in factors)
    return torch.stack([torch.nn.functional.pad(f, (0, rank - f.shape[1])) for f in factors])
