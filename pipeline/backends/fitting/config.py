"""Configuration of the kinematic body-model fit (stage ``fit``); defaults in one place.

Light (no torch): the fit backends take it, and ``pipeline.stages.fit_config`` re-exports it
for the stage, the CLI and the server.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

from pipeline.schema.config_types import check_field_types


@dataclass(frozen=True)
class FitConfig:
    """Body-model fit of every athlete over the whole sequence (paper section 3.3, eq. 3).

    Loss weights default to the paper's (w1..w6 = 0.001, 1.0, 0.01, 0.001, 1e-4, 1e-4) where
    the paper has them; the terms we add are documented per field. Why each default is what
    it is, and what was measured for it: ``docs/design/fit.md``.
    """

    body_model: Literal["anny", "smpl", "smplx"] = "anny"
    """Parametric body model. anny ships with the package; SMPL/SMPL-X need the user's model
    files (``body_model_path``) and the ``smplx`` package."""

    body_model_path: str = ""
    """SMPL/SMPL-X only: folder holding ``smpl/SMPL_{NEUTRAL,MALE,FEMALE}.pkl`` or
    ``smplx/SMPLX_{NEUTRAL,MALE,FEMALE}.npz`` (the layout of ``smplx.create``)."""

    rig: str = "anny-nohands-notoes-noeyes"
    """anny rig: the default rig without fingers, toes and eyes (36 bones)."""

    min_conf_2d: float = 0.7
    """2D keypoints with confidence at or below this are ignored (paper: 0.7)."""

    outlier_view_frac: float = 0.05
    """A detection whose confident keypoints lie, in the median, farther than this fraction
    of its box height from its person's triangulated joints is left out of the 2D term (a
    failed 2D pose or a wrong person: the other views disagree with it as a whole), in
    [0, 1); 0 keeps every detection."""

    w_2d: float = 1e-3
    """w1: confidence-weighted Geman-McClure reprojection error over every view (pixels^2)."""

    w_3d: float = 1.0
    """w2: confidence-weighted squared distance to the triangulated joints (m^2)."""

    w_reg: float = 0.01
    """w3: squared magnitude of the non-root bone rotations (rad^2)."""

    w_smooth: float = 1e-3
    """w4: squared pose change plus squared whole-mesh vertex displacement between consecutive
    frames (rad² + m² summed over the vertices), >= 0; per frame at ``reference_fps``."""

    reference_fps: float = 50.0
    """Frame rate (Hz, > 0) at which the per-frame temporal settings below (``w_smooth``,
    ``w_accel``, ``accel_scale_m``, ``w_jerk``, ``accel_adapt_*``) are stated. At another
    rate the stage converts them (``at_rate``) so that the same motion, in m/s² and m/s³,
    costs the same and the smoothing keeps its cut-off in Hz: a 25 fps bout is not
    smoothed 16 times harder than a 50 fps one."""

    w_accel: float = 300.0
    """Squared second difference of the fitted keypoints (m² per frame², at ``reference_fps``; ours):
    damps jitter without slowing the motion like ``w_smooth``, >= 0."""

    accel_scale_m: float = 0.005
    """Scale (m per frame², >= 0) of the pseudo-Huber on those second differences: quadratic below
    (jitter), linear above (punches); 0 = plain squared penalty."""

    accel_whole_body: float = 0.3
    """Weight (>= 0), relative to ``w_accel``, of the whole-body part of the acceleration penalty
    above the feet (the mean acceleration of those keypoints); each keypoint's own part and
    the feet keep the full weight, so planted feet stay still."""

    w_jerk: float = 150.0
    """Squared third difference of the fitted keypoints (m² per frame⁶; ours), weighted by the
    re-weighted acceleration weights, so it acts after ``accel_adapt_after`` only, >= 0."""

    accel_adapt_after: int = 90
    """L-BFGS iterations of the full pass after which the acceleration penalty is re-weighted per
    keypoint and frame from the motion fitted so far (resting keypoints smoothed harder,
    punches less); 0 or >= ``pose_iters``: never."""

    accel_adapt_scale_m: float = 0.002
    """s of the re-weighting (m per frame², > 0): weight ``accel_adapt_gain · s² / (s² + m²)``,
    m the keypoint's RMS acceleration over ``accel_adapt_window`` frames either side."""

    accel_adapt_gain: float = 6.0
    """Weight (> 0), relative to ``w_accel``, of the re-weighted penalty at rest (m = 0)."""

    accel_adapt_window: int = 2
    """Frames (>= 0) either side over which m of the re-weighting is averaged."""

    accel_fast_view_px: float = 0.0
    """Speed (px per frame at ``reference_fps``, >= 0) of a wrist's 2D keypoint in any view above
    which that wrist's acceleration and jerk penalties are multiplied by
    ``accel_fast_view_scale`` at that frame and the frames either side: a fist one view sees
    fly is not held back by the penalty where the 3D evidence is weak; 0: off."""

    accel_fast_view_scale: float = 0.2
    """Factor (in (0, 1]) of those penalties at such frames (``accel_fast_view_px``)."""

    calibrate_landmarks: bool = True
    """Estimate one constant offset per person and keypoint, rigid in the keypoint's bone frame:
    the difference between the detector's landmarks and the body model's (where a "hip"
    sits). The fitted keypoints include it; the mesh does not."""

    refine_shape: bool = True
    """Refine the shape jointly with the poses (after its bone-length initialisation): lengths
    from noisy 3D are biased, the 2D views correct them."""

    landmark_step: float = 1.0
    """anny only: scale (> 0) of the landmark offsets among the L-BFGS variables, relative to
    √frames; below 1 the offsets follow the poses faster."""

    w_landmarks: float = 10.0
    """Squared norm of the landmark offsets (m²), >= 0."""

    w_prior: float = 1e-4
    """w5: the pose prior's negative log-likelihood per frame (nats, ~0 at the most likely mode),
    >= 0; unused when ``pose_prior_path`` is empty."""

    w_limits: float = 1.0
    """Soft anatomical joint limits: squared excess rotation beyond per-bone ranges (rad²), >= 0."""

    w_ground: float = 1e4
    """Squared depth below the floor z = 0 of the foot keypoints and 48 sole vertices (m²), >= 0."""

    w_overlap: float = 3000.0
    """Squared depth (m²) of the overlap between capsules of two persons (an average adult's
    volumes, in boxing gloves), >= 0: arms hidden behind the other athlete do not pass
    through him; 0: off."""

    gm_sigma_px: float = 25.0
    """Scale (px, > 0) of the Geman-McClure function: residuals much larger barely count."""

    robust_2d: Literal["gm", "l2"] = "gm"
    """Reprojection penalty: Geman-McClure (paper) or plain squared error (for comparison)."""

    use_2d: bool = True
    """Include the reprojection term (the 3D term alone is much cheaper but less accurate)."""

    pose_prior_path: str = "builtin"
    """GMM pose prior: ``"builtin"`` (shipped, fitted to the DeepMimic clips; rebuild with
    ``cornerman priors build``), ``""`` = none, or a user npz with ``means``, ``precisions``,
    ``weights`` (and optionally ``bone_names``, ``rig``)."""

    shape_iters: int = 60
    """L-BFGS iterations of the shape initialisation from bone lengths."""

    girth_prior: tuple[float, float] = (0.5, 0.5)
    """anny ``muscle`` and ``weight`` phenotypes (in [0, 1]) the shape is held near (0.5 = average
    adult): keypoints give bone lengths, not girth."""

    girth_prior_weight: float = 1.0
    """Weight (>= 0) of ``(phenotype - girth_prior)²`` for muscle and weight in the shape
    initialisation (the limb-length term is in m²)."""

    pose_iters_3d: int = 30
    """L-BFGS iterations of the first pose pass (3D term, priors and smoothness only)."""

    pose_iters: int = 180
    """L-BFGS iterations (>= 0) of the full pass (eq. 3)."""

    lbfgs_history: int = 100
    """L-BFGS history size (paper: 100)."""

    lbfgs_lr: float = 1.0
    """L-BFGS learning rate (paper: 1.0); the line search is strong Wolfe."""

    min_valid_joints: int = 4
    """A person counts as present in a frame with at least this many valid triangulated
    joints; other frames are filled by the smoothness term and marked invalid."""

    threads: int = 1
    """torch intra-op threads during the fit (0: torch's default); 1 is fastest on a shared
    2-core machine (the tensors are small)."""

    precision: Literal["float32", "float64"] = "float32"
    """anny only (SMPL stays float64): float32 (~20 % faster, same accuracy) or float64."""

    vposer_path: str = ""
    """SMPL/SMPL-X only: the user's VPoser v2 weights (``human_body_prior`` ``.ckpt`` or a
    plain state dict; not shipped, SMPL licence). Adds the encoder-based prior
    ``w_prior * (0.5 |mu(pose)|^2 + |decode(mu) - pose|^2)`` on the 21 body joints (see
    ``pipeline.backends.smpl.vposer``). Empty: no VPoser."""

    smpl_gender: Literal["neutral", "male", "female"] = "neutral"
    """SMPL/SMPL-X only: which model file of ``body_model_path`` to fit (``SMPL_<GENDER>.pkl``)."""

    incremental: bool = True
    """Re-use the previous fit (same config and code, frames and persons): re-optimise only
    the frames whose inputs changed, ``incremental_margin_frames`` around them, and keep the
    rest, the shapes and the landmark offsets (``pipeline.stages.fit_incremental``); False:
    always fit in full."""

    incremental_margin_frames: int = 0
    """Frames re-optimised on each side of a changed one in an incremental re-fit (>= 0); 0:
    only the changed ones, next to kept frames that stay in the loss as fixed context."""

    def at_rate(self, fps: float) -> FitConfig:
        """This config with its temporal settings converted from ``reference_fps`` to ``fps``
        (a k-th difference of the same motion scales as ``fps^-k``); unchanged at the reference."""
        if not fps > 0:
            raise ValueError(f"FitConfig.at_rate: fps must be positive, got {fps!r}")
        r = fps / self.reference_fps
        if r == 1.0:
            return self
        return replace(
            self,
            reference_fps=fps,
            w_smooth=self.w_smooth * r**2,
            w_accel=self.w_accel * r**4,
            accel_scale_m=self.accel_scale_m / r**2,
            accel_adapt_scale_m=self.accel_adapt_scale_m / r**2,
            accel_adapt_window=max(1, round(self.accel_adapt_window * r)) if self.accel_adapt_window else 0,
            w_jerk=self.w_jerk * r**6,
            accel_fast_view_px=self.accel_fast_view_px / r,
        )

    def __post_init__(self) -> None:
        check_field_types(self)  # values from Python callers; session.json goes through build_config
        for name in (
            "w_2d",
            "w_3d",
            "w_reg",
            "w_smooth",
            "w_accel",
            "w_jerk",
            "accel_whole_body",
            "w_landmarks",
            "w_prior",
            "w_limits",
            "w_ground",
            "w_overlap",
        ):
            if not getattr(self, name) >= 0:  # also refuses NaN
                raise ValueError(f"FitConfig.{name} must be >= 0, got {getattr(self, name)}")
        if self.accel_scale_m < 0:
            raise ValueError(f"FitConfig.accel_scale_m must be >= 0, got {self.accel_scale_m}")
        for name in ("accel_adapt_after", "accel_adapt_window"):
            if getattr(self, name) < 0:
                raise ValueError(f"FitConfig.{name} must be >= 0, got {getattr(self, name)}")
        for name in ("accel_adapt_scale_m", "accel_adapt_gain", "landmark_step", "reference_fps"):
            if not getattr(self, name) > 0:  # also refuses NaN
                raise ValueError(f"FitConfig.{name} must be positive, got {getattr(self, name)}")
        if not self.accel_fast_view_px >= 0:  # also refuses NaN
            raise ValueError(f"FitConfig.accel_fast_view_px must be >= 0, got {self.accel_fast_view_px}")
        if not 0 < self.accel_fast_view_scale <= 1:
            raise ValueError(f"FitConfig.accel_fast_view_scale must be in (0, 1], got {self.accel_fast_view_scale}")
        if self.gm_sigma_px <= 0:
            raise ValueError(f"FitConfig.gm_sigma_px must be positive, got {self.gm_sigma_px}")
        if len(self.girth_prior) != 2 or not all(0.0 <= v <= 1.0 for v in self.girth_prior):
            raise ValueError(f"FitConfig.girth_prior must be (muscle, weight) in [0, 1], got {self.girth_prior}")
        if not self.girth_prior_weight >= 0:  # also refuses NaN
            raise ValueError(f"FitConfig.girth_prior_weight must be >= 0, got {self.girth_prior_weight}")
        if not 0 <= self.outlier_view_frac < 1:
            raise ValueError(f"FitConfig.outlier_view_frac must be in [0, 1), got {self.outlier_view_frac}")
        if not 0 <= self.min_conf_2d < 1:
            raise ValueError(f"FitConfig.min_conf_2d must be in [0, 1), got {self.min_conf_2d}")
        if self.precision not in ("float32", "float64"):
            raise ValueError(f"FitConfig.precision must be 'float32' or 'float64', got {self.precision!r}")
        if self.incremental_margin_frames < 0:
            raise ValueError(f"FitConfig.incremental_margin_frames must be >= 0, got {self.incremental_margin_frames}")
        if min(self.shape_iters, self.pose_iters_3d, self.pose_iters) < 0 or self.lbfgs_history < 1:
            raise ValueError("FitConfig: iteration counts must be >= 0 and lbfgs_history >= 1")
