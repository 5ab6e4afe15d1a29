"""Settings of the MuJoCo physics: each defined once, here, and taken as objects by the
backends and nested in the stage's ``PhysicsConfig`` (no MuJoCo import: the stage
config and the server can build and check them without loading MuJoCo).

- ``HumanoidConfig``: the simulated bodies and the scene (servos, contacts, floor, step);
- ``ResidualConfig``: the residual root wrench, its limits and when it is used;
- ``ReferenceConfig``: the kinematic reference the optimiser tracks;
- ``ILQRConfig`` and ``CostWeights``, nested in ``SolverConfig``: the receding-horizon iLQR.

The rationale of the defaults, and what was measured for them, is in
``docs/design/physics-ilqr.md`` and ``docs/design/physics-contacts.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Literal

import numpy as np

from pipeline.schema.config_types import check_field_types

DENSITY_KG_M3 = 985.0


def _check(obj: Any, positive: tuple[str, ...] = (), non_negative: tuple[str, ...] = ()) -> None:
    """``ValueError`` naming ``Class.field`` for a value of the wrong type, or that is not
    > 0 / >= 0 (NaN refused)."""
    nested_from_dicts(obj)
    check_field_types(obj)
    for name in positive + non_negative:
        v = getattr(obj, name)
        ok = v > 0 if name in positive else v >= 0
        if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v) or not ok:
            raise ValueError(f"{type(obj).__name__}.{name} must be {'> 0' if name in positive else '>= 0'}, got {v!r}")


@dataclass(frozen=True)
class HumanoidConfig:
    """The simulated humanoids and the scene they share."""

    density_kg_m3: float = DENSITY_KG_M3
    """Body density of every geom's mass (kg/m³; the paper's 985)."""
    kp_per_kg: float = 12.0
    """Servo stiffness (N·m/rad per kg of body mass, times the joint's strength), > 0."""
    kv_ratio: float = 0.1
    """Servo damping kv = kv_ratio · kp (s), >= 0."""
    torque_per_kg: float = 6.0
    """Servo torque limit (N·m per kg of body mass, times the joint's strength), > 0."""
    torque_limits: Literal["servo", "human"] = "servo"
    """``servo``: each servo's limit is ``torque_per_kg`` × mass × strength; ``human``: also at
    most the joint group's human peak (``pipeline.evaluate.effort``) over √(hinges of the joint),
    so that no joint's torque norm can exceed a human's."""
    armature: float = 0.25
    """Joint armature (kg·m²) of the strongest joints of a 75 kg person, scaled by strength
    and mass: numerical stability at the video rate, at the price of inertia, >= 0."""
    target_slack_rad: float = 1.0
    """Servo targets may exceed the joint range by this much (rad; the torque stays limited)."""
    joint_damping: float = 1.0
    """Passive joint damping (N·m·s/rad), >= 0."""
    self_collision: Literal["adjacent_filtered", "none"] = "adjacent_filtered"
    """``adjacent_filtered``: a person's parts collide except parent/child, siblings and
    grandparent pairs; ``none``: only contacts with the floor and the other athletes."""
    floor_friction: float = 2.0
    """Sliding friction of the floor (every floor contact uses it), > 0: 2 against the soft
    contact's creep of planted soles."""
    body_friction: float = 1.0
    """Sliding friction between the athletes' body geoms, > 0."""
    mesh_foot_sole: Literal["hull", "box"] = "hull"
    """What a mesh foot (``PhysicsConfig.geometry`` ``mesh``) stands on: ``hull``: its convex
    hull alone (MuJoCo's plane-mesh collision keeps at most 3 vertices, the lowest one and two
    of its hull neighbours, so a level foot rests on a few cm of its forefoot); ``box``: also a
    massless flat box under the hull's sole outline, bottom at its lowest vertex (4 corner
    contacts, heel to toes)."""
    floor_margin_m: float = 0.008
    """Floor contacts act from this height (m, >= 0), so a landing foot stops before it sinks
    into the soft floor and a standing sole rests a few mm up, as planted keypoints do."""
    floor_solref: tuple[float, float] = (0.005, 1.0)
    """MuJoCo ``solref`` of floor contacts: (time constant s, damping ratio), or
    (−stiffness, −damping); the time constant must be >= 2 MuJoCo steps (see ``substeps``)."""
    floor_solimp: tuple[float, float, float] = (0.9, 0.95, 0.001)
    """MuJoCo ``solimp`` (d0, dwidth, width) of floor contacts; d0, dwidth in (0, 1)."""
    body_solref_s: float = 0.02
    """Contact time constant (s, > 0) of body geoms; larger: softer contacts between athletes."""
    substeps: int = 8
    """MuJoCo steps per video frame (>= 1): timestep = 1 / (fps · substeps)."""
    arm_contacts: Literal["reference", "simulate"] = "reference"
    """``reference``: arm-arm contacts between athletes are not simulated (the reference's
    separation and the cost keep arms apart); ``simulate``: they are."""
    foot_contacts: Literal["reference", "simulate"] = "reference"
    """As ``arm_contacts``, for the two athletes' feet against each other."""
    solver_iterations: int = 20
    """Constraint solver iterations per step (Newton), >= 1."""
    person_spacing_m: float = 2.0
    """Spacing of the default root positions in the MJCF (viewer only), m."""

    def __post_init__(self) -> None:
        _check(self, positive=("kp_per_kg", "torque_per_kg", "floor_friction", "body_friction", "body_solref_s"),
               non_negative=("kv_ratio", "armature", "joint_damping", "floor_margin_m"))  # fmt: skip
        if self.substeps < 1 or self.solver_iterations < 1:
            raise ValueError(f"HumanoidConfig: substeps and solver_iterations must be >= 1, got {self.substeps}, {self.solver_iterations}")
        sr, si = tuple(self.floor_solref), tuple(self.floor_solimp)
        if len(sr) != 2 or not all(np.isfinite(sr)):
            raise ValueError(f"HumanoidConfig.floor_solref must be 2 finite numbers, got {self.floor_solref!r}")
        if len(si) != 3 or not (0 < si[0] < 1 and 0 < si[1] < 1 and si[2] > 0):
            raise ValueError(f"HumanoidConfig.floor_solimp must be (d0, dwidth, width) with d0, dwidth in (0, 1) and width > 0, got {self.floor_solimp!r}")


@dataclass(frozen=True)
class ResidualConfig:
    """The residual root wrench (residual force control): a force and torque on each root,
    feed-forward from inverse dynamics plus a PD pull towards the reference root pose."""

    mode: Literal["always", "fallback", "off"] = "always"
    """``always``: in every window; ``fallback``: only in windows tracked worse than
    ``fallback_tol_m`` without it; ``off``: never (no root actuation at all). ``off`` and
    ``fallback`` flag the windows that could not be tracked without it
    (``PhysicsResult.untrackable``, stats ``untrackable_windows``)."""
    force_frac: float = 2.0
    """Hard limit of the residual root force on each world axis (x, y, z: the root servos'
    force range), as a fraction of body weight, > 0; its magnitude is at most √3 × this
    (0.05: 5 % per axis, 8.7 % in all; 0.0289 caps the magnitude at 5 %)."""
    torque_frac: float = 2.0
    """Limit of the residual root torque's feed-forward and proportional parts, as a fraction
    of body weight × 0.3 m, >= 0 (its damping part, the root joint's, is not limited)."""
    saturation_m: float = 0.1
    """Root position error (m, > 0) at which the force's PD part saturates."""
    rot_saturation_rad: float = 0.03
    """Root orientation error (rad, > 0) at which the torque's PD part saturates."""
    fallback_tol_m: float = 0.05
    """Mean keypoint-site error (m, > 0) of a window tracked without the residual above which
    it counts as untrackable (modes ``off`` and ``fallback``; ``fallback`` redoes it with
    the residual)."""

    def __post_init__(self) -> None:
        # force_frac 0 would be an empty force range, which MuJoCo refuses: no residual is mode "off".
        _check(self, positive=("force_frac", "saturation_m", "rot_saturation_rad", "fallback_tol_m"), non_negative=("torque_frac",))


@dataclass(frozen=True)
class ReferenceConfig:
    """The kinematic reference the optimiser tracks, made contact-consistent first."""

    separate: bool = True
    """Free each frame of the multi-person reference of inter-person overlap before tracking it."""
    separation_clearance_m: float = 0.003
    """Gap (m, >= 0) the separation leaves between the athletes' geoms."""
    flat_feet: bool = True
    """Stand planted feet flat on the floor (sole level, resting in the floor margin)."""
    calibrate_foot_sites: bool = True
    """With ``flat_feet``: move each foot's keypoint sites by the median of how far they miss
    the planted keypoints when the sole stands flat (the body model's foot landmarks are
    not the detector's)."""
    ik_posture_weight: float = 3e-4
    """Pull of the reference's inverse kinematics towards the rest joint angles (per rad²,
    against the sites' m²), >= 0: joints the keypoints leave free do not drift."""
    schedule: bool = True
    """Move the servo targets and the residual along the reference at every substep, with
    inverse-dynamics feed-forward whose ground reactions sit on the planted feet; False:
    targets held for a whole frame."""
    feedforward_friction: float = 0.3
    """Friction coefficient (>= 0) of the ground reactions the feed-forward plans; what the
    feet may not supply goes to the residual."""
    feedforward_smooth_frames: float = 1.0
    """Gaussian sigma (frames, >= 0) smoothing the reference's velocities and
    accelerations for the feed-forward (the target positions are not smoothed)."""

    balance: Literal["none", "zmp"] = "none"
    """``zmp``: move each athlete's body above the planted feet (the legs re-solved, the feet
    held) so that the zero-moment point of the centre of mass stays inside the planted
    feet's support (``balance.balance_reference``); ``none``: the reference as fitted."""
    balance_support: Literal["planted", "low"] = "planted"
    """With ``balance`` ``zmp``: the feet whose sole points make the support polygon (and are
    held): ``planted`` (the reference's planted feet) or ``low`` (also any foot whose lowest
    sole point is below 5 cm, pivoting or sliding)."""
    balance_margin_m: float = 0.02
    """With ``balance`` ``zmp``: how far inside the support polygon's edge (m, >= 0) the ZMP is kept."""
    balance_smooth_frames: float = 2.0
    """Gaussian sigma (frames, >= 0) of the centre-of-mass path whose acceleration gives the ZMP."""
    balance_w_vel: float = 1e-4
    """Weight of the offset's squared velocity (s², against the ZMP's m²), >= 0."""
    balance_w_acc: float = 1e-6
    """Weight of the offset's squared acceleration (s⁴, against the ZMP's m²), >= 0."""
    balance_w_size: float = 1e-2
    """Weight of the offset's squared size (against the ZMP's m²), >= 0."""
    balance_rounds: int = 2
    """Solve-and-move rounds (>= 1): the legs' mass makes the CoM move less than the body above them."""

    def __post_init__(self) -> None:
        _check(self, non_negative=("separation_clearance_m", "ik_posture_weight", "feedforward_friction", "feedforward_smooth_frames",
                                   "balance_margin_m", "balance_smooth_frames", "balance_w_vel", "balance_w_acc", "balance_w_size"))
        if isinstance(self.balance_rounds, bool) or not isinstance(self.balance_rounds, int) or self.balance_rounds < 1:
            raise ValueError(f"ReferenceConfig.balance_rounds must be an integer >= 1, got {self.balance_rounds!r}")


@dataclass(frozen=True)
class ILQRConfig:
    """The iLQR of one window."""

    max_iter: int = 8
    """Iterations per window (each: linearise, backward pass, line search), >= 1."""
    mu_init: float = 1e-3
    """Initial regularisation added to Q_uu, > 0."""
    mu_min: float = 1e-6
    """Lower bound of μ, > 0."""
    mu_max: float = 1e6
    """Stop when μ exceeds this (no descent direction found)."""
    mu_up: float = 10.0
    """Factor on μ after a failure, > 1."""
    mu_down: float = 0.3
    """Factor on μ after a success, in (0, 1)."""
    regularisation: Literal["success", "improvement_ratio"] = "success"
    """How μ follows an accepted step: ``success`` lowers it after every one;
    ``improvement_ratio`` compares the actual with the expected decrease (MuJoCo MPC's
    iLQG): lowered when the quadratic model predicted it well, raised when poorly."""
    n_alpha: int = 6
    """Line-search step sizes, log-spaced in [alpha_min, 1], >= 1."""
    alpha_min: float = 1e-2
    """Smallest line-search step, in (0, 1]."""
    fd_eps: float = 1e-6
    """Finite-difference step of ``mjd_transitionFD``, > 0."""
    fd_centered: bool = False
    """Centred finite differences (2× cost)."""
    fd_split_persons: bool = True
    """Forward differences of persons who do not touch share their steps (one DOF of each
    nudged at once, ``fd_split``): the same Jacobians from 1/persons of the steps; off runs
    ``mjd_transitionFD`` on the whole scene."""
    fd_interval_s: float = 0.02
    """Simulated time one substep's finite differences stand for (s, >= 0): every k-th MuJoCo
    substep of a control step is differentiated, k = this / timestep rounded (at least 1), and
    stands for itself and the k - 1 after it (chained as A^k, Σ A^i B); 0 = every substep."""
    backward_split_persons: bool = True
    """In a window where nothing couples the persons (no contact in the Jacobians, no
    collision term in the cost), one Riccati recursion per person instead of one over all:
    the same policy up to rounding, from a fraction of the matrix products."""
    deriv_every: int = 2
    """Dynamics Jacobians by finite differences every k frames, interpolated in between, >= 1."""
    jacobian_reuse: int = 2
    """Iterations that share one set of dynamics Jacobians (the line search still rolls out
    the true dynamics), >= 1."""
    max_backtracks: int = 6
    """Failed backward passes / line searches (μ raised each time) before an iteration gives up."""
    rel_tol: float = 1e-3
    """Stop when an iteration's relative cost decrease is below this, >= 0."""
    threads: int = 0
    """Worker threads of the finite differences and the line search (the result does not
    depend on it), >= 0; 0 = automatic: 2 (1 on a single CPU) for a thread-safe cost."""

    def __post_init__(self) -> None:
        check_field_types(self)
        if isinstance(self.threads, bool) or not isinstance(self.threads, int) or self.threads < 0:
            raise ValueError(f"ILQRConfig.threads must be an integer >= 0, got {self.threads!r}")
        for name in ("max_iter", "deriv_every", "jacobian_reuse", "n_alpha"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"ILQRConfig.{name} must be an integer >= 1, got {v!r}")
        _check(self, positive=("mu_init", "mu_min", "fd_eps", "alpha_min"), non_negative=("rel_tol", "fd_interval_s"))
        if not (self.mu_up > 1 and 0 < self.mu_down < 1 and self.alpha_min <= 1):
            raise ValueError(f"ILQRConfig: need mu_up > 1, 0 < mu_down < 1, alpha_min <= 1, got {self.mu_up}, {self.mu_down}, {self.alpha_min}")


@dataclass(frozen=True)
class CostWeights:
    """Weights of the tracking cost (the paper's eq. 5, with our additions)."""

    w_reg: float = 0.0003
    """w1: velocity and servo-target regularisation."""
    w_pos: float = 100.0
    """w2: joint positions (body and world frame) and root placement."""
    w_vel: float = 0.003
    """w3: generalised velocity tracking (small: reference velocities are noisy)."""
    w_collision: float = 1000.0
    """w4: squared inter-person penetration depth (m²), over every pair of the athletes' geoms."""
    world_frac: float = 0.5
    """Share of w2 given to world-frame joint positions (the rest: body frame), in [0, 1]."""
    w_residual: float = 10.0
    """Squared change (m²) of the residual root servos' targets from the reference's."""
    w_skate: float = 10.0
    """Squared horizontal velocity (m²/s²) of the foot points of feet planted in the reference."""
    collision_clearance_m: float = 0.012
    """Gap (m, >= 0) the collision term asks for: pairs closer than this pay (clearance − distance)²."""

    def __post_init__(self) -> None:
        _check(self, non_negative=("w_reg", "w_pos", "w_vel", "w_collision", "w_residual", "w_skate", "collision_clearance_m"))
        if not 0 <= self.world_frac <= 1:
            raise ValueError(f"CostWeights.world_frac must be in [0, 1], got {self.world_frac}")


@dataclass(frozen=True)
class SolverConfig:
    """Receding-horizon iLQR over the bout."""

    window: int = 24
    """iLQR horizon in frames per window, >= 1."""
    commit: int = 12
    """Frames kept from each window before re-planning, in [1, window]."""
    ilqr: ILQRConfig = field(default_factory=ILQRConfig)
    """The iLQR of each window."""
    exact_retry_tol_m: float = 0.0
    """Re-plan a window with every substep differentiated (``ilqr.fd_interval_s`` 0) when its
    simulated sites miss their targets by more than this on average (m, >= 0), keeping the
    lower-cost plan; 0: off. Only when ``ilqr.fd_interval_s`` > 0."""
    exact_retry_max_start_m: float = 0.1
    """... and only when the window starts with its simulated sites within this of their
    targets on average (m, > 0); a window that starts further off is not re-planned."""
    weights: CostWeights = field(default_factory=CostWeights)
    """The tracking cost's weights."""

    def __post_init__(self) -> None:
        nested_from_dicts(self)
        check_field_types(self)
        if not self.exact_retry_tol_m >= 0:  # also refuses NaN
            raise ValueError(f"SolverConfig.exact_retry_tol_m must be >= 0, got {self.exact_retry_tol_m}")
        if not self.exact_retry_max_start_m > 0:
            raise ValueError(f"SolverConfig.exact_retry_max_start_m must be > 0, got {self.exact_retry_max_start_m}")
        if not (1 <= self.commit <= self.window):
            raise ValueError(f"SolverConfig: need 1 <= commit <= window, got commit={self.commit}, window={self.window}")


def nested_from_dicts(obj: Any) -> None:
    """Replace dict values of ``obj``'s dataclass fields by the field's dataclass (for Python
    callers writing ``SolverConfig(ilqr={"max_iter": 4})``); ``session.json`` goes through
    ``pipeline.schema.config_types.build_config``, which does the same with type checks."""
    for f in fields(obj):
        v = getattr(obj, f.name)
        default = f.default_factory() if callable(f.default_factory) else None  # type: ignore[misc]
        if isinstance(v, dict) and default is not None and hasattr(default, "__dataclass_fields__"):
            cls = type(default)
            unknown = sorted(set(v) - {g.name for g in fields(cls)})
            if unknown:
                raise ValueError(
                    f"{type(obj).__name__}.{f.name}: unknown keys {unknown}; known: {sorted(g.name for g in fields(cls))}"
                )
            object.__setattr__(obj, f.name, cls(**v))
