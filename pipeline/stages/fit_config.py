"""Configuration of the kinematic body-model fit (stage ``fit``); defaults in one place."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

from pipeline.schema.config_types import check_field_types


@dataclass(frozen=True)
class FitConfig:
    """Body-model fit of every athlete over the whole sequence (paper section 3.3, eq. 3).

    Loss weights default to the paper's (w1..w6 = 0.001, 1.0, 0.01, 0.001, 1e-4, 1e-4); the
    terms we add (keypoint acceleration, joint limits, ground, landmark offsets) are documented
    per field. Their defaults were tuned with ``cornerman bench fit`` on the synthetic bout.
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
    """w4: squared pose change plus squared whole-mesh vertex displacement between
    consecutive frames (rad^2 + m^2 summed over all vertices; exact, via folded moments)."""

    reference_fps: float = 50.0
    """Frame rate (Hz, > 0) at which the per-frame temporal settings below (``w_smooth``,
    ``w_accel``, ``accel_scale_m``, ``w_jerk``, ``accel_adapt_*``) are stated. At another
    rate the stage converts them (``at_rate``) so that the same motion, in m/s² and m/s³,
    costs the same and the smoothing keeps its cut-off in Hz: a 25 fps bout is not
    smoothed 16 times harder than a 50 fps one."""

    w_accel: float = 300.0
    """Squared second difference of the fitted keypoints (m^2 per frame^2; ours, not in the
    paper): damps frame-to-frame jitter without slowing the motion down like ``w_smooth``.
    Was 500 before ``w_jerk``; see there."""

    accel_scale_m: float = 0.005
    """Scale of a pseudo-Huber penalty on those second differences (m per frame^2): below it
    the penalty is quadratic (jitter), above it linear (genuine fast accelerations such as
    punches are penalised less). 0 = plain squared penalty."""

    accel_whole_body: float = 0.3
    """Weight, relative to ``w_accel``, of the whole-body part of the acceleration penalty:
    above the feet, each keypoint's acceleration is split into the mean acceleration of
    those keypoints (footwork, weight shifts) and the keypoint's own relative to it, which
    keeps the full weight; ankles, heels and toes keep their plain penalty, so planted feet
    stay still (``fit_common.accel_term``). 1 is the plain penalty in its quadratic regime.
    Against the plain per-keypoint penalty on the synthetic bouts (4 cameras, seeds 0 / 1 / 2,
    300 frames), MPJPE 10.15 → 9.59, 10.91 → 10.18, 11.04 → 10.24 mm and acceleration error
    3.96 → 3.86, 3.92 → 3.80, 3.94 → 3.78 mm/f²; 2 cameras (seed 0) 23.5 → 22.9 mm; foot
    skating unchanged (150 frames, seeds 0-3: 1.64 → 1.63 mm/frame). 0.2 and 0.5 are within
    0.2 mm; splitting the feet too raised their skating by 20-40 %."""

    w_jerk: float = 150.0
    """Squared third difference of the fitted keypoints (m^2 per frame^6; ours), weighted per
    keypoint and frame by the re-weighted acceleration weights (``fit_common.jerk_term``), so
    it acts only in the iterations after ``accel_adapt_after``: a smoother of higher order
    that stops frame-to-frame noise more sharply and passes the slow motion. With it, the
    acceleration penalty went from ``w_accel`` 500, ``accel_adapt_gain`` 4, re-weighting after
    100 iterations to 300, 6, 90 (less smoothing before the re-weighting, as much after).
    ``cornerman bench fit``, 4 cameras, 300 frames, MPJPE / acceleration error (mm, mm/f²)
    against the filtered triangulation's: seed 0 9.51 / 3.16 → 9.16 / 3.01 (−27 → −30 %),
    seed 1 10.24 / 3.31 → 9.83 / 3.13 (−27 → −31 %), seed 2 10.61 / 3.52 → 10.35 / 3.35
    (−26 → −29 %); 2 cameras (seed 0) 24.16 / 4.53 → 23.41 / 4.43. Same iterations, same
    time. On seed 0, 100 alone (the rest as before): 9.68 / 3.07; applied in every
    iteration, unweighted: 30 → 9.87 / 3.10, 300 → 12.00 / 3.46."""

    accel_adapt_after: int = 90
    """Iterations of the full pass (``pose_iters``) after which the acceleration penalty is
    re-weighted per keypoint and frame from the motion fitted so far; the remaining
    iterations use those weights in place of the pseudo-Huber (``fit_common.
    adaptive_accel_weights``). Keypoints at rest are then smoothed harder and keypoints in a
    punch or a step less: a smoother whose acceleration variance changes over time. 0 (or
    >= ``pose_iters``): never. Against 0 (``cornerman bench fit``, 4 cameras, 300 frames),
    MPJPE / acceleration error: seed 0 9.59 / 3.86 → 9.19 / 3.59 mm, mm/f²; seed 1
    10.18 / 3.80 → 9.67 / 3.51; seed 2 10.24 / 3.78 → 9.55 / 3.47; 2 cameras (seed 0)
    22.90 / 4.92 → 23.08 / 4.75. Same number of iterations, so the same time. Re-weighting
    twice (after 70 and 110) was no better (9.70 / 3.65, seed 0). 100 before ``w_jerk``."""

    accel_adapt_scale_m: float = 0.002
    """s of the re-weighting (m per frame²): the weight is ``accel_adapt_gain · s² / (s² +
    m²)``, m the keypoint's RMS acceleration over ``accel_adapt_window`` frames either side.
    Seed 0: 0.0015 → 3.79, 0.0025 → 3.57 mm/f²."""

    accel_adapt_gain: float = 6.0
    """Weight, relative to ``w_accel``, of the re-weighted penalty at rest (m = 0). Seed 0:
    3 (re-weighting after 120) → 3.67, 6 with a pseudo-Huber kept → 3.77 mm/f². 4 before
    ``w_jerk`` (with ``w_accel`` 500: 2000 at rest, now 1800); with it (seeds 0 / 2, MPJPE /
    accel): 5 → 9.07 / 3.02, 10.24 / 3.37; 6 → 9.16 / 3.01, 10.35 / 3.35."""

    accel_adapt_window: int = 2
    """Frames either side over which m is averaged (0: that frame's acceleration alone, which
    a noisy fit over-reads: 3.85 mm/f² with weights from a whole first fit, against 3.57 for 2)."""

    calibrate_landmarks: bool = True
    """Estimate one constant offset per person and keypoint, rigid in the keypoint's bone
    frame: absorbs the difference between the detector's landmark definitions and anny's
    regressor (e.g. where a "hip" or "shoulder" keypoint sits). The fitted keypoints include
    it; the mesh does not."""

    refine_shape: bool = True
    """Refine the shape jointly with the poses in the pose passes (after its bone-length
    initialisation): lengths from noisy 3D are biased, the 2D views correct them."""

    landmark_step: float = 1.0
    """anny only: scale of the landmark offsets among the L-BFGS variables, relative to
    √frames (the number of frames they explain). They are optimised as ``landmark_step ·
    √frames`` times their value; L-BFGS starts from a scalar Hessian, so its steps along
    them grow as ``1 / landmark_step²``: below 1 the offsets follow the poses faster.
    ``cornerman bench fit`` (4 cameras, 300 frames), 0.1 against 1: MPJPE seed 0 9.49 →
    9.21 mm, seed 1 10.24 → 9.96 mm, 2 cameras 24.1 → 23.6 mm, acceleration error
    unchanged. Not the default: the physics stage did worse on that fit (``cornerman bench
    physics``, bouts 0-3, multi-person: skating 0.80 → 0.87 mm/frame, MPJPE 14.0 → 14.2 mm;
    the demo bout's physics MPJPE 14.6 → 17.1 mm). Applied to the shape refinement too it
    moved the shapes (seed 0: anny's gender 0.63 → 0.54, age 0.88 → 0.75) for 0.03 mm more
    and bout 3's physics skating 0.90 → 1.38 mm/frame. Seed 0 with 0.05 / 0.2 / 0.33 / 3
    (both): 9.42 / 9.31 / 9.36 / 11.12 mm."""

    w_landmarks: float = 10.0
    """Squared norm of those landmark offsets (m^2)."""

    w_prior: float = 1e-4
    """w5: statistical pose prior: sum over frames of the GMM's negative log-likelihood per
    frame (nats, shifted so the most likely mode costs ~0; a pose s standard deviations off
    along one axis costs ~s^2/2; anny). Unused when ``pose_prior_path`` is empty."""

    w_limits: float = 1.0
    """Soft anatomical joint limits: squared excess rotation beyond per-bone ranges (rad^2)."""

    w_ground: float = 1e4
    """Squared depth below the ground plane z = 0 of the foot keypoints and of 48 sole
    vertices of the mesh (m^2)."""

    w_overlap: float = 3000.0
    """Squared depth (m²) of the overlap between capsules of two different persons
    (``fit_contacts.ProxyOverlap``: an average adult's volumes, in boxing gloves), summed
    over the frames where both are present (ours, not in the paper; 0: off). In clinches
    and exchanges an arm hidden behind the other athlete has little 2D evidence, and
    without this term the fit let arms pass through each other and through the trunk.
    ``cornerman bench fit`` style runs (300 frames, 4 cameras), seeds 0 / 1 / 2, without
    -> with: deepest overlap 98.9 / 88.9 / 97.4 -> 4.7 / 5.8 / 4.4 mm, mean 5.9 / 6.2 /
    5.0 -> 0.1 mm, MPJPE 9.46 / 9.89 / 9.75 -> 9.49 / 9.88 / 9.79 mm, acceleration error
    unchanged (-25.8 / -25.7 / -26.7 -> -25.9 / -26.4 / -26.1 % against filtered
    triangulation), fit time +10 %; 2 cameras (seed 0, weight 1000): 110 -> 11 mm, MPJPE
    23.9 -> 23.6 mm."""

    gm_sigma_px: float = 25.0
    """Scale of the Geman-McClure function: residuals much larger than this barely count."""

    robust_2d: Literal["gm", "l2"] = "gm"
    """Reprojection penalty: Geman-McClure (paper) or plain squared error (for comparison)."""

    use_2d: bool = True
    """Include the reprojection term (the 3D term alone is much cheaper but less accurate)."""

    pose_prior_path: str = "builtin"
    """GMM pose prior: ``"builtin"`` = the shipped prior fitted to the DeepMimic clips
    (``pipeline/backends/data/anny_pose_gmm.npz``, zlib-licensed source motion; rebuild with
    ``anny_prior_build.build_pose_prior``), ``""`` = none (joint limits only), otherwise a
    user npz with ``means`` (K, D), ``precisions`` (K, D, D), ``weights`` (K,) and optionally
    ``bone_names`` (D/3 bones of ``rig``; default: every non-root bone) and ``rig``."""

    shape_iters: int = 60
    """L-BFGS iterations of the shape initialisation from bone lengths."""

    girth_prior: tuple[float, float] = (0.5, 0.5)
    """anny ``muscle`` and ``weight`` phenotypes the shape is held near (0.5 = anny's
    average adult). Keypoints give bone lengths, not girth: left free, these two moved
    to their bounds to shave millimetres off the limb lengths (synthetic bout: muscle
    0.00, weight 0.97-0.999, an obese body ~1.4x as wide as an average one, whose
    overlaps in clinches the physics stage then had to undo). Raise muscle for
    athletic builds when known."""

    girth_prior_weight: float = 1.0
    """Weight of ``(phenotype - girth_prior)²`` for muscle and weight in the shape
    initialisation (the limb-length term is in m²; the other phenotypes keep 1e-4)."""

    pose_iters_3d: int = 30
    """L-BFGS iterations of the first pose pass (3D term, priors and smoothness only)."""

    pose_iters: int = 180
    """L-BFGS iterations of the full pass (eq. 3). 150 before: the 30 more all run with the
    re-weighted acceleration and jerk terms (after ``accel_adapt_after`` 90). ``cornerman
    bench fit``, 4 cameras, 300 frames, MPJPE mm / acceleration error against the filtered
    triangulation's: seed 0 9.16 / −30.2 % → 9.02 / −31.6 %; seed 2 10.35 / −29.3 % →
    10.12 / −30.1 %. 200 iterations: seed 0 8.95 / −32.0 %, seed 1 9.83 / −31.0 % → 9.62 /
    −32.5 %, seed 2 10.00 / −30.5 % (re-weighting after 120 instead: 9.75 / −29.6 %, after
    150 of 250: 9.47 / −29.5 %); ~35 % more pose time for 200, ~20 % for 180. On seed 2 at
    150: ``w_jerk`` 80 / 250 −28.6 / −28.9 %, ``accel_adapt_gain`` 8 −28.8 %,
    ``accel_adapt_scale_m`` 0.0025 −28.5 %, ``accel_adapt_window`` 3 −27.4 %."""

    lbfgs_history: int = 100
    """L-BFGS history size (paper: 100)."""

    lbfgs_lr: float = 1.0
    """L-BFGS learning rate (paper: 1.0); the line search is strong Wolfe."""

    min_valid_joints: int = 4
    """A person counts as present in a frame with at least this many valid triangulated
    joints; other frames are filled by the smoothness term and marked invalid."""

    threads: int = 1
    """torch intra-op threads during the fit (restored afterwards; 0: torch's default). The
    tensors are small (frames x 36 bones), so extra threads gain little, and on a shared
    2-core machine an oversubscribed OpenMP pool made the fit ~10x slower (measured again:
    two fits at once with 2 threads each took 308 s, with 1 thread each 34 s)."""

    precision: Literal["float32", "float64"] = "float32"
    """anny only (SMPL fits stay float64): floating-point type of the fit's tensors. float32
    is ~20 % faster (``cornerman bench fit``, 2 x 300 frames, 4 cameras: pose pass 22.2 s
    against 27.4 s) with the same accuracy (synthetic bouts 0 and 1: MPJPE and acceleration
    error within 0.05 mm and 0.05 mm/frame²); float64 reproduces fits made before float32
    became the default."""

    vposer_path: str = ""
    """SMPL/SMPL-X only: the user's VPoser v2 weights (``human_body_prior`` ``.ckpt`` or a
    plain state dict; not shipped, SMPL licence). Adds the encoder-based prior
    ``w_prior * (0.5 |mu(pose)|^2 + |decode(mu) - pose|^2)`` on the 21 body joints (see
    ``pipeline.backends.vposer``). Empty: no VPoser."""

    smpl_gender: Literal["neutral", "male", "female"] = "neutral"
    """SMPL/SMPL-X only: which model file of ``body_model_path`` to fit (``SMPL_<GENDER>.pkl``)."""

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
        if min(self.shape_iters, self.pose_iters_3d, self.pose_iters) < 0 or self.lbfgs_history < 1:
            raise ValueError("FitConfig: iteration counts must be >= 0 and lbfgs_history >= 1")
