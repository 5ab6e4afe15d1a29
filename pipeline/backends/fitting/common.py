"""Body-model-independent pieces of the kinematic fit (anny and SMPL/SMPL-X share them).

The observations of one person, the L-BFGS driver and its pose passes with the re-weighting
of the acceleration penalty, limb lengths for the shape initialisation, the root
initialisation by Kabsch on the torso, the swing rotation of the limb initialisation, and the
mesh-moment factors of the smoothness term. The loss terms are in ``terms``, the driver of a
whole fit in ``sequence``. Everything works on ``COCO17_FEET`` keypoints; nothing here knows
the body model.
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
