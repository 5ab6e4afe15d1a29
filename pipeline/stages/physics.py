"""Physics stage (paper §3.4): per-athlete MuJoCo humanoids + multi-person iLQR.

``run(inputs, cfg)`` builds one humanoid per person — from the fitted anny body
(``cfg.skeleton == "bodyfit"``: anny's main skeleton, convex-hull or capsule geoms cut
from the body mesh, see ``pipeline.backends.anny_humanoid``) or sized from the fitted
3D joints (``"keypoints"``: capsules from median bone lengths) — puts all
persons on one ground plane, computes a kinematic reference by inverse kinematics
and optimises servo targets with receding-horizon iLQR so that the simulated
motion tracks the joints while contacts (ground, other athlete) stay physical.

The reference is made contact-consistent before tracking: planted feet are held
still and flat on the floor, overlapping athletes are separated in order, frame by
frame (arms and spine move first; arm-arm overlap is only removed here, the
simulation leaves arm-arm contacts out: ``arm_contacts``), and the hands are boxing
gloves. Between video frames the servo targets move along the reference at every
substep, with inverse-dynamics feed-forward whose ground reactions sit on the planted
feet (``schedule``). The initial controls of every window are that schedule; the
iLQR optimises the servo targets and the residual root servos' targets. The residual
root wrench (feed-forward + PD, ≤ ``residual_force_frac`` body weights) lets the
kinematic, not dynamically consistent motion be followed; its use is reported.

mujoco is only imported inside ``run`` via ``pipeline.backends``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from pipeline.schema.config_types import check_field_types
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit, PhysicsResult

if TYPE_CHECKING:
    from pipeline.backends.humanoid_skeleton import Skeleton
    from pipeline.backends.mujoco_humanoid import HumanoidConfig
    from pipeline.backends.mujoco_reference import Scene

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PhysicsConfig:
    """Settings of the physics stage (defaults keep a 300-frame, 2-boxer bout at a few minutes on 2 cores)."""

    mode: Literal["multi", "single"] = "multi"
    """``multi``: all persons in one simulation (inter-person contacts); ``single``:
    each person optimised alone (the paper's ablation)."""
    skeleton: Literal["bodyfit", "keypoints"] = "bodyfit"
    """``bodyfit``: humanoids built from the anny ``BodyFit`` (19 bodies, 44 hinges; when
    given, anny, and covering every person; otherwise falls back to ``keypoints`` with a
    log message); ``keypoints``: 13 bodies, 26 hinges sized from the fitted joints' bone
    lengths (capsules only; ~3x faster)."""
    geometry: Literal["capsule", "mesh"] = "mesh"
    """Collision geometry of the ``bodyfit`` humanoid: ``mesh`` (convex hulls of the body
    mesh segmented by skinning weights) or ``capsule`` (one capsule per part fitted to the
    same vertices). On the synthetic bench (150 frames, multi) hulls give the least
    penetration (mean 9.1 mm vs 12.2 capsules, 13.9 keypoint capsules) at the same MPJPE."""
    glove_radius_m: float = 0.065
    """Boxing gloves on the ``bodyfit`` humanoids: each hand is a ball of this radius
    around the fist (centre one radius past the wrist), not anny's open, flat hand that
    reaches 12-20 cm past the wrist. 0: anny's hand mesh."""
    substeps: int = 8
    """MuJoCo steps per video frame (stability of strong servos; see ``HumanoidConfig``).
    More steps allow a stiffer floor contact (``floor_solref``; MuJoCo's time constant must
    be ≥ 2 steps) and let a planted foot roll less on its sole. With ``deriv_every`` equal
    to ``substeps`` the finite-difference cost per second of motion stays that of 4 and 4.
    ``cornerman bench physics`` bouts 0-3 (multi, one fixed fit), skating mm/frame / MPJPE
    mm, against 4 substeps (floor (0.01, 1), ``deriv_every`` 4): 0.79 / 13.59; 6 (6): 0.67
    / 13.44; 8 (8): 0.67 / 13.51; 8 (8) with the floor at (0.005, 1): 0.61 / 13.64 (the
    default); 8 (4): 0.64 / 13.55 at twice the finite differences; 16 (16): 0.64 / 13.79
    with deeper capsule overlap (49 against 35-39 mm)."""
    schedule: bool = True
    """Move the servo targets and the residual root wrench along the reference between
    video frames, at every substep, with inverse-dynamics feed-forward whose ground
    reactions sit on the planted feet (``mujoco_schedule``). False: targets held for a
    whole frame, feed-forward from 3-frame smoothed accelerations (the scheme before)."""
    flat_feet: bool = True
    """Stand the reference's planted feet flat on the floor (sole level, resting where the
    floor contact settles: 1 mm inside ``floor_margin_m``). From the keypoints alone a
    planted foot is tilted by ~5° (up to 10°) and hovers ~7 mm up; the simulated foot,
    flat on the floor, then rocks on its sole and slides."""
    calibrate_foot_sites: bool = True
    """With ``flat_feet``: move each foot's keypoint sites (ankle, heel, toes) by the median
    of how far they miss the planted keypoints when the sole stands flat
    (``mujoco_foot_sites``): the body model's landmark convention for the feet is not the
    keypoints' (anny's toe sites sit ~15 mm lower than its heel's on a level sole; the
    observed planted heel and toes are level). The collision geometry is unchanged."""
    max_frames: int = 0
    """Process only the first N frames (0 = all)."""
    window: int = 24
    """iLQR horizon in frames per receding-horizon window."""
    commit: int = 12
    """Frames kept from each window before re-planning (≤ window). Bouts 0-3 of ``cornerman
    bench physics`` (multi-person, one fixed fit, the other defaults), MPJPE mm / skating
    mm/frame / capsule penetration max, mean / body overlap max, mean mm / seconds per bout:
    16 -> 11.92 / 0.59 / 22.7, 0.54 / 20.9, 0.64 / 44; 12 (the default) -> 11.87 / 0.56 /
    16.9, 0.45 / 19.9, 0.53 / 53; 8 -> 11.93 / 0.59 / 23.1, 0.51 / 20.7, 0.59 / 73; window 18
    with 12 -> 12.08 / 0.59 / 19.2, 0.50 / 22.3, 0.64 / 45; window 32 with 16 -> 12.34 / 0.56
    / 40.7, 1.07 / 27.1, 1.05."""
    max_iter: int = 8
    """iLQR iterations per window (with ``jacobian_reuse`` 2: four sets of finite-difference
    Jacobians, as 4 and 1 before)."""
    deriv_every: int = 8
    """Finite-difference dynamics Jacobians every k video frames, interpolated in between.
    Each costs ``substeps`` MuJoCo steps per perturbed coordinate, so 8 with 8 substeps
    costs what 4 with 4 did."""
    n_alpha: int = 6
    """Line-search candidates, log-spaced in [alpha_min, 1]."""
    alpha_min: float = 1e-2
    """Smallest line-search step."""
    fd_centered: bool = False
    """Centred finite differences (2× slower)."""
    jacobian_reuse: int = 2
    """iLQR iterations that share one set of finite-difference dynamics Jacobians
    (``ILQRConfig.jacobian_reuse``; 1 = fresh Jacobians at every iteration). Bouts 0-3 of
    ``cornerman bench physics`` (multi-person, one fixed fit, ``w_pos`` 100, commit 16), MPJPE mm /
    skating mm/frame / capsule penetration max, mean / body overlap max, mean mm / seconds
    per bout: ``max_iter`` 4, reuse 1 -> 12.42 / 0.59 / 31.6, 0.87 / 24.2, 0.77 / 30; 6, 1
    -> 12.24 / 0.58 / 30.8, 0.80 / 25.5, 0.72 / 41; 8, 1 -> 12.13 / 0.57 / 23.3, 0.65 /
    21.8, 0.64 / 51; 8, 2 (the default) -> 11.92 / 0.59 / 22.7, 0.54 / 20.9, 0.64 / 44; 12,
    3 -> 12.19 / 0.60 / 24.7, 0.51 / 22.0, 0.61 / 42. (At ``w_pos`` 10, on an earlier
    simulation, more iterations had not paid: twelve on bout 0 gave MPJPE 13.19 against
    13.08 mm with four.)"""
    rollout_threads: int = 1
    """Threads that roll the line-search candidates out together (same result either
    way). Measured on the 150-frame bench: no gain (rollouts 9.8 s on 1 thread, 10.3 s
    on 2): MuJoCo releases the GIL while stepping (1.5x on bare steps), but our cost
    and feedback are evaluated in Python at every step and hold it."""
    residual_root: Literal["fallback", "always", "off"] = "always"
    """Residual root wrench (residual force control): the root wrench the reference
    needs beyond what the feet can supply (inverse dynamics) plus a PD pull of the
    root towards the reference root pose, limited by ``residual_force_frac``; in
    every window (default), only for windows whose tracking error exceeds
    ``fallback_tol_m``, or never. Its use is reported (``residual_root_force``,
    stats). Without it the synthetic boxers (kinematic, not dynamically consistent
    motion) drift and fall within a second."""
    servo_kp_per_kg: float = 12.0
    """Servo stiffness (N·m/rad per kg of body mass, times the joint's strength). Stiffer
    servos track better but collide and slide more: ``cornerman bench physics``, 4 bouts,
    multi-person, 24 against 12: MPJPE 33.8 vs 38.6 mm, penetration mean 9.8 vs 13.3 mm
    but max 74.2 vs 64.1 mm, ground max 9.1 vs 6.8 mm, skating 2.2 vs 1.9 mm/frame,
    body-mesh penetration mean 3.1 vs 2.5 mm, RTF 25.6 vs 23.0."""
    armature: float = 0.25
    """Joint armature (kg·m²) of the strongest joints of a 75 kg person (scaled by
    strength and mass): numerical stability at the video rate, at the price of
    extra inertia that slows fast limbs (see ``HumanoidConfig.armature``)."""
    body_friction: float = 1.0
    """Sliding friction between the athletes' body geoms (soles and floor: ``floor_friction``)."""
    floor_friction: float = 2.0
    """Sliding friction of the floor (``HumanoidConfig.friction``; every floor contact uses
    it, the floor's priority is higher). MuJoCo's friction is a soft constraint: a planted
    sole creeps while its contact force is well inside the cone (median ratio 0.3 of 1.0),
    and a larger coefficient stiffens the pyramidal cone's tangential response. The
    planned ground reactions stay within ``feedforward_friction`` (0.3) whatever this is,
    so the iLQR is not taught to lean on the floor's grip. Bouts 0-3 (multi, one fixed
    fit), skating mm/frame / MPJPE mm / capsule penetration max, mean mm: 1.0 (until
    2026-11-26) → 0.42 / 11.94 / 21.5, 0.40; 1.5 → 0.38 / 11.88 / 21.5, 0.44; 2.0 → 0.34 /
    11.84 / 19.1, 0.35; 3.0 → 0.33 / 12.01 / 21.2, 0.43. Rubber soles on canvas grip at
    about 1-1.5 in reality: 2 is chosen against the soft contact's creep, not measured."""
    servo_torque_per_kg: float = 6.0
    """Servo torque limit (N·m per kg of body mass, times the joint's strength)."""
    separate_reference: bool = True
    """Free each frame of the multi-person reference of inter-person overlap before
    tracking it (``mujoco_separation.separate_reference``)."""
    ik_posture_weight: float = 3e-4
    """Pull of the reference's inverse kinematics towards the rest joint angles
    (``mujoco_reference.inverse_kinematics(posture_weight)``, per rad² against the sites'
    m²). Without it the joints the keypoints leave free drifted from frame to frame:
    on bout 1 both shoulder girdles sat at their ±0.6 rad yaw limit in 62 of 150 frames,
    turned against the trunk's twist, while the fitted body's clavicles turn < 0.13 rad.
    ``cornerman bench physics`` bouts 0-3 (multi, fit input, BLAS on one thread), skating
    mm/frame / MPJPE mm / capsule penetration max, mean mm: 0 -> 0.344 / 11.84 / 19.1,
    0.35; 1e-4 -> 0.335 / 11.46 / 35.5, 0.61; 3e-4 -> 0.293 / 11.39 / 14.6, 0.33; 1e-3
    -> 0.280 / 11.81 / 14.9, 0.39 (with the wider clavicle, spine and hip ranges of
    ``anny_humanoid._joints``: 3e-4 -> 0.298 / 11.29 / 11.4, 0.30; 1e-3 -> 0.285 /
    11.87 / 14.5, 0.39). Pulling only the girdles and the trunk's twist, 1e-2: 0.397 /
    12.40: the trunk does twist."""
    separation_clearance_m: float = 0.003
    """Gap the separation leaves between the athletes' geoms. Synthetic bench, bouts 0-7,
    150 frames, multi: 3 mm against 10 mm: MPJPE 15.8 vs 16.5 mm, penetration mean 8.0
    vs 8.5 mm (max 96.0 vs 95.5), skating 0.96 vs 0.98 mm/frame. 0 and 6 mm were worse on
    bouts 0 and 2 (one run at 6 mm lost bout 2's arms: 35 mm)."""
    floor_solref: tuple[float, float] = (0.005, 1.0)
    """MuJoCo ``solref`` of floor contacts (see ``HumanoidConfig.floor_solref``). (0.005, 1)
    needs ≥ 7 substeps at 60 fps (time constant ≥ 2 steps; with fewer the stage warns and
    MuJoCo uses two steps, ``floor_timeconst_warning``): see ``substeps``. The soft floor
    is why feet sank: at (0.02, 1) the sole hull itself rests 11–12 mm into it. On
    ``cornerman bench physics`` (4 bouts, multi-person, each bout run alone), (0.01, 1) with
    4 substeps and ``deriv_every = 4`` against (0.02, 1) with 2 and 2: ground penetration
    max 8.0 vs 17.3 mm, foot skating 3.1 vs 4.3 mm/frame, MPJPE 45.9 vs 47.9 mm, keypoint
    penetration mean 4.3 vs 5.8 mm (max 49.8 vs 60.2, a noisy number), body-mesh
    penetration mean 2.4 vs 3.7 mm, at a real-time factor of 22–30 vs 21–25."""
    floor_solimp: tuple[float, float, float] = (0.9, 0.95, 0.001)
    """MuJoCo ``solimp`` of floor contacts (see ``HumanoidConfig.floor_solimp``)."""
    arm_contacts: Literal["reference", "simulate"] = "reference"
    """How the athletes' arms are kept out of each other. ``reference``: the separation
    of the reference removes arm-arm overlap (``separate_reference``), and the
    simulation leaves arm-arm contacts out (arm-trunk, arm-head and all other contacts
    are simulated). ``simulate``: arm-arm contacts are simulated too. Gloves travel
    13-17 cm per video frame in a punch; simulated arm-arm contacts at that speed
    interlock: on the synthetic bench (bouts 0 and 1, 150 frames) the arms left the
    reference by 30-80 mm for the rest of the bout (MPJPE 22-36 mm against 15-16 mm with
    ``reference``). Overlap that remains is still reported (``contacts_and_sites`` uses
    every pair)."""
    foot_contacts: Literal["reference", "simulate"] = "reference"
    """How the athletes' feet are kept out of each other: as ``arm_contacts``, for the
    feet of the two athletes against each other (foot against shin or any other part is
    always simulated). Fitted feet in a clinch can overlap by a centimetre; simulated,
    the two left feet of bout 3 of the synthetic bench collided for five frames and kicked
    each other 20-30 mm across the floor in a frame. ``reference`` on bouts 0-3
    (multi-person): skating 0.89 -> 0.79 mm/frame, MPJPE 13.9 -> 13.6 mm (bout 3: 1.27 ->
    0.88, 14.8 -> 13.7; bouts 0 and 1 had no foot-foot contact and are unchanged)."""
    feedforward_friction: float = 0.3
    """Friction coefficient of the ground reactions the inverse-dynamics feed-forward
    plans (``mujoco_schedule.servo_schedule``; the floor's is 1.0): a planned force near
    the floor's cone makes the foot slip whenever the simulated load differs; what the
    feet may not supply goes to the residual root wrench."""
    feedforward_smooth_frames: float = 1.0
    """Gaussian sigma (frames) of the smoothing of the reference's velocities and
    accelerations that the inverse-dynamics feed-forward uses (its target positions are
    not smoothed). Unsmoothed, the per-frame noise of the inverse kinematics, twice
    differentiated, shook the whole body: a person standing still (rest-pose keypoints
    with 1 mm of noise) kept its joints moving at 0.56 rad/s RMS and its planted feet
    sliding 0.7 mm/frame; with 1 frame, 0.18 rad/s and 0.12-0.15 mm/frame. Bouts 0 and 2
    (multi): skating 0.94 / 1.44 -> 0.77 / 1.20 mm/frame, MPJPE 16.4 / 18.3 -> 16.4 / 18.0
    mm."""
    floor_margin_m: float = 0.008
    """Floor contact margin (see ``HumanoidConfig.floor_margin_m``): floor contacts act from
    8 mm above the floor, so a foot landing at ~1 m/s (the simulated feet land harder than
    the reference's) is stopped before its hull sinks 10-12 mm into the soft floor; a
    standing foot rests a few mm above the floor, as the reference's planted feet do
    (3-9 mm). On ``cornerman bench physics`` (4 bouts, multi-person, run alone), with the
    foot hulls enclosing the foot keypoints, 8 mm / 6 mm / 0 (session 12, hulls without the
    keypoints): ground penetration max 0.3 / 1.9 / 6.8 mm (per bout 0.0, 0.0, 0.0, 1.0 at
    8 mm; 1.8, 0.0, 0.0, 5.7 at 6 mm), MPJPE 37.9 / 38.0 / 38.6 mm, skating 1.6 / 1.8 /
    1.9 mm/frame, foot height error 6.3 / 7.5 mm (8 / 6 mm), keypoint-capsule penetration
    max 62.9 / 69.6 / 64.1 mm (mean 11.2 / 13.7 / 13.3), body-mesh penetration max 39.9 /
    31.6 / 36.7 mm (mean 2.8 / 2.6 / 2.5), RTF 21.2 / 22.1 / 23.0. A harder floor
    (``floor_solimp`` 0.99-0.995, bout 0) did not help: 11.1 mm."""
    body_solref_s: float = 0.02
    """Contact time constant of body geoms (soles: 0.02 s); larger = softer
    inter-person contacts."""
    residual_saturation_m: float = 0.1
    """Root position error at which the residual root force's PD part saturates (its
    stiffness is ``residual_force_frac`` body weights per this distance). A soft pull:
    the feed-forward supplies what the motion needs, the PD only what drifts. Bouts 0-7
    (multi), 2 body weights at 2 / 10 / 50 / 100 / 200 mm: MPJPE 16.4 / 15.8 / 15.9 /
    15.8 / 16.3 mm, mean residual 1.94 / 1.27 / 0.85 / 0.75 / 0.69 body weights,
    penetration mean 8.7 / 8.0 / 8.0 / 7.7 / 8.3 mm; 1 body weight at 50 mm: 17.8 mm,
    3 at 150 mm: 16.3 mm."""
    residual_force_frac: float = 2.0
    """Limit of the residual root force per axis (fraction of body weight) and of the
    residual root torque (fraction of body weight × 0.3 m). The synthetic boxers'
    choreographed footwork and punches are not dynamically consistent (their pelvis
    accelerates horizontally at 0.9 g on average, 2 g at the 90th percentile, beyond what
    friction allows), so following them takes a strong residual. Single-person mode,
    bout 0 (150 frames), with the servo schedule, MPJPE for a limit of 2 body weights and
    a saturation of 5 / 10 / 20 mm: 14.3 / 14.4 / 14.5 mm; 1 body weight at 5 mm: 18.8 mm;
    the previous defaults (1 body weight, 20 mm, no schedule): 24.1 mm. See
    ``residual_saturation_m``. Its use is reported (``residual_force_mean_frac_bw``)."""
    fallback_tol_m: float = 0.05
    """Mean joint error (m) above which a window is re-optimised with the residual."""
    self_collision: Literal["adjacent_filtered", "none"] = "adjacent_filtered"
    """Self-contacts within a person (adjacent parts always filtered)."""
    w_reg: float = 0.0003
    """w1 of eq. 5 (‖v‖² + servo target deviation). Below the paper's 0.001 since
    ``w_pos`` is 100: bouts 0-3 of ``cornerman bench physics`` (multi-person, one fixed fit,
    the other defaults), MPJPE mm / skating mm/frame / capsule penetration mean / body
    overlap mean mm: 0.001 -> 11.87 / 0.56 / 0.45 / 0.53; 0.0003 -> 11.90 / 0.51 / 0.40 /
    0.53; 0.0001 -> 11.90 / 0.54 / 0.55 / 0.60; 0.01 -> 13.66 / 0.65 / 1.43 / 1.06. (Also
    ``w_residual`` 3 / 100 -> 11.79 / 0.52 and 12.04 / 0.56; with 0.0003, 11.98 / 0.55.)"""
    w_pos: float = 100.0
    """w2 of eq. 5 (joint positions in the body frame + root placement). The paper's 10
    tracked loosely at our 8 substeps: bouts 0-3 of ``cornerman bench physics``
    (multi-person, one fixed fit), MPJPE / skating mm/frame / capsule penetration mean
    / body overlap mean mm: 10 -> 13.64 / 0.61 / 1.22 / 0.61; 30 -> 13.02 / 0.60 / 1.25
    / 0.76; 50 -> 12.98 / 0.60 / 1.27 / 0.77; 100 -> 12.66 / 0.59 / 1.39 / 1.00; 300
    (``w_collision`` 600) -> 12.67 / 0.65 / 1.75 / 1.22. Raising ``w_collision`` with
    it did not take the overlap back (100 with 200: 1.69 / 0.94 mm); making the trunk
    and the root dear in the reference's separation did (``mujoco_separation``)."""
    w_vel: float = 0.003
    """w3 of eq. 5 (velocity tracking). Small: reference velocities of triangulated
    joints are noisy, and at the paper's 0.1 this term outweighs positions ~10×."""
    w_collision: float = 1000.0
    """w4 of eq. 5 (squared inter-person penetration depth, m², over every pair of geoms of
    different athletes, also those the simulation does not collide). The paper's 20 sits
    beside its ``w_pos`` 10; beside our 100 it let a swinging foot sink 27 mm into the
    other athlete's planted foot (bout 3). ``cornerman bench physics`` bouts 0-3 (multi,
    fit input), body overlap max / mean mm, capsule max / mean mm, skating mm/frame, MPJPE
    mm: 20 -> 23.6 / 0.60, 11.4 / 0.30, 0.298, 11.29; 200 (the paper's ratio to
    ``w_pos``) -> 14.0 / 0.42, 11.7 / 0.28, 0.310, 11.39; 1000 -> 9.7 / 0.24, 11.7 /
    0.29, 0.316, 11.42; 3000 -> 10.1 / 0.24, 12.7 / 0.29, 0.304, 11.41. (At ``w_pos`` 10
    and 4 substeps, 20 / 200 / 1000 had made no difference: capsule max 35.4 / 38.5 /
    40.1 mm, body max 21.9 / 19.9 / 20.0 mm.)"""
    collision_clearance_m: float = 0.012
    """Gap the collision term of the iLQR asks for between geoms of different athletes:
    it penalises (clearance − distance)², so near-misses cost a little too and a limb
    heading into the other athlete is turned before it touches. ``cornerman bench
    physics`` bouts 0-3 (multi, ``w_collision`` 1000), per bout deepest body overlap mm,
    then the means of skating mm/frame and MPJPE mm. On fits of 150 iterations: 0 ->
    10.8 / 0.2 / 11.6 / 16.1, 0.316, 11.42; 5 mm -> 3.3 / 0.0 / 11.6 / 18.6, 0.312, 11.45;
    8 mm -> 0 / 0 / 18.4 / 13.0, 0.319, 11.39; 10 mm -> 0 / 0 / 10.3 / 3.6, 0.314, 11.51.
    On the fits of 180 (``FitConfig.pose_iters``; kinematic 29.1 / 24.3 / 43.8 / 48.0,
    1.19, 10.35): 10 mm -> 10.6 / 0 / 5.7 / 15.3, 0.325, 11.33; 12 mm -> 0 / 0 / 4.0 /
    5.1, 0.335, 11.30; 15 mm -> 2.4 / 0 / 0.5 / 4.2, 0.350, 11.38; 20 mm -> 0 / 0 / 5.3 /
    12.9, 0.360, 11.48 (and a capsule overlap of 41 mm on bout 3). The deepest overlap is
    one frame's and moves by several mm with small changes of the input; what is left is
    mostly foot in foot."""
    w_residual: float = 10.0
    """Squared change (m²) of the residual root servos' targets that the iLQR makes
    (``CostWeights.w_residual``): 1 cm costs 0.001, a 4 cm overlap 0.03 at ``w_collision``.
    Bouts 0 / 2 (multi), MPJPE and mean residual: 1 -> 16.0 / 18.1 mm, 1.2 / 1.5 body
    weights; 10 -> 15.9 / 17.9 mm, 1.1 / 1.5; 1000 -> 16.2 / 18.0 mm, 0.9 / 1.3. Standing
    still: 1.3 / 0.4 / 0.3 body weights. At 1000 the residual pins the roots where the
    reference has them, against the contacts: two overlapping athletes tracked without
    separating the reference first kept 70 % of their overlap (10: 29 %)."""
    w_skate: float = 10.0
    """Foot-contact term: squared horizontal speed of feet planted in the reference.
    ``cornerman bench physics`` bouts 0-3 (multi, one fixed fit, 4 substeps), skating
    mm/frame / MPJPE mm: 0 -> 1.21 / 13.13, 2 -> 0.79 / 13.40, 5 -> 0.77 / 13.54, 10 -> 0.79 / 13.59, 50 ->
    0.84 / 13.65; on the 3D speed (the vertical too, against the foot rolling) at 10: 0.82 /
    13.91. The optimiser takes skating from 1.07 (its initial controls) to 0.79 in four
    iterations and no further (eight: 0.80)."""

    def __post_init__(self) -> None:
        check_field_types(self)  # values from Python callers; session.json goes through build_config
        if not (1 <= self.commit <= self.window):
            raise ValueError(f"PhysicsConfig: need 1 <= commit <= window, got commit={self.commit}, window={self.window}")
        if self.rollout_threads < 1:
            raise ValueError(f"PhysicsConfig.rollout_threads must be >= 1, got {self.rollout_threads}")
        if self.max_iter < 0 or self.deriv_every < 1 or self.n_alpha < 1 or self.jacobian_reuse < 1:
            raise ValueError(f"PhysicsConfig: bad solver settings max_iter={self.max_iter}, deriv_every={self.deriv_every}, n_alpha={self.n_alpha}, jacobian_reuse={self.jacobian_reuse} (need >= 0, >= 1, >= 1, >= 1)")
        if self.substeps < 1:
            raise ValueError(f"PhysicsConfig.substeps must be >= 1, got {self.substeps}")
        if len(self.floor_solref) != 2 or len(self.floor_solimp) != 3 or not np.all(np.isfinite([*self.floor_solref, *self.floor_solimp])):
            raise ValueError(
                f"PhysicsConfig: floor_solref needs 2 finite numbers and floor_solimp 3, got {self.floor_solref}, {self.floor_solimp}"
            )
        if not (0.0 < self.floor_solimp[0] < 1.0 and 0.0 < self.floor_solimp[1] < 1.0 and self.floor_solimp[2] > 0.0):
            raise ValueError(f"PhysicsConfig.floor_solimp must be (d0, dwidth in (0, 1), width > 0), got {self.floor_solimp}")
        if self.glove_radius_m < 0.0:
            raise ValueError(f"PhysicsConfig.glove_radius_m must be >= 0, got {self.glove_radius_m}")
        for name in ("feedforward_smooth_frames", "separation_clearance_m", "ik_posture_weight", "collision_clearance_m", "w_residual", "w_reg", "w_pos", "w_vel", "w_collision", "w_skate"):
            if not getattr(self, name) >= 0.0:  # also refuses NaN
                raise ValueError(f"PhysicsConfig.{name} must be >= 0, got {getattr(self, name)}")
        if not self.floor_friction > 0.0:
            raise ValueError(f"PhysicsConfig.floor_friction must be > 0, got {self.floor_friction}")
        if not self.feedforward_friction > 0.0:
            raise ValueError(f"PhysicsConfig.feedforward_friction must be > 0, got {self.feedforward_friction}")
        if self.floor_margin_m < 0.0:
            raise ValueError(f"PhysicsConfig.floor_margin_m must be >= 0, got {self.floor_margin_m}")
        if self.max_frames < 0:
            raise ValueError(f"PhysicsConfig.max_frames must be >= 0, got {self.max_frames}")


@dataclass(frozen=True)
class PhysicsInputs:
    """keypoints: the fitted joints (``source="fit"``, world z-up metres);
    bodyfit: the fitted body model (optional; its person ids must match)."""

    keypoints: Keypoints3D
    bodyfit: BodyFit | None = None


@dataclass(frozen=True)
class PhysicsOutput:
    result: PhysicsResult
    keypoints: Keypoints3D
    mjcf: str
    stats: dict[str, Any]


def _select_persons(kp: Keypoints3D) -> list[int]:
    rows = [i for i in range(kp.n_persons) if kp.valid[:, i].any(axis=-1).sum() >= 2]
    if not rows:
        raise ValueError("physics: no person has at least 2 frames of valid joints")
    return rows


def build_skeletons(
    kp: Keypoints3D, rows: list[int], bodyfit: BodyFit | None, cfg: PhysicsConfig
) -> tuple[list[Skeleton], str]:
    """One rest skeleton per keypoint person row, and which builder was used
    (``"bodyfit"`` or ``"keypoints"``; see ``PhysicsConfig.skeleton``)."""
    from pipeline.backends.humanoid_skeleton import skeleton_from_keypoints

    pids = [int(kp.person_ids[r]) for r in rows]
    why = ""
    if cfg.skeleton != "bodyfit":
        why = f"skeleton={cfg.skeleton!r}"
    elif bodyfit is None:
        why = "no BodyFit given"
    elif bodyfit.body_model != "anny":
        why = f"BodyFit body_model is {bodyfit.body_model!r}, not 'anny'"
    else:
        fit_ids = [int(i) for i in bodyfit.person_ids]
        lacking = [p for p in pids if p not in fit_ids or not bodyfit.valid[:, fit_ids.index(p)].any()]
        if lacking:
            why = f"BodyFit has no valid fit of persons {lacking}"
    if not why:
        from pipeline.backends.anny_humanoid import skeleton_from_bodyfit

        assert bodyfit is not None
        fit_ids = [int(i) for i in bodyfit.person_ids]
        skels = [
            skeleton_from_bodyfit(bodyfit, fit_ids.index(p), keypoints=kp, geometry=cfg.geometry, glove_radius_m=cfg.glove_radius_m)
            for p in pids
        ]
        log.info("physics: humanoids from the anny BodyFit (%s geometry)", cfg.geometry)
        return skels, "bodyfit"
    if cfg.geometry == "mesh":
        log.info("physics: mesh geometry needs the BodyFit skeleton; using capsules")
    log.info("physics: humanoids sized from the keypoints (%s)", why)
    return [skeleton_from_keypoints(kp, r) for r in rows], "keypoints"


def posed_humanoids(
    kp: Keypoints3D,
    bodyfit: BodyFit | None = None,
    cfg: PhysicsConfig = PhysicsConfig(),
    person_ids: list[int] | None = None,
    body_keypoints: Keypoints3D | None = None,
    min_persons: int = 1,
    what: str = "posed_humanoids",
) -> tuple[Scene, np.ndarray]:
    """The humanoids this stage builds (from ``bodyfit``, with ``cfg``'s geometry, sized
    from ``body_keypoints``, default ``kp``), posed by inverse kinematics onto ``kp``'s
    joints: no separation, no floor lift, no simulation. Returns ``(scene, qpos)``.

    ``person_ids`` restricts the persons (default: all with motion). Raises
    ``ValueError`` (prefixed with ``what``) when fewer than ``min_persons`` remain or
    one of them is not in ``body_keypoints``."""
    from pipeline.backends import mujoco_physics as mp

    rows = _select_persons(kp)
    moving = [int(kp.person_ids[r]) for r in rows]
    if person_ids is not None:
        rows = [r for r in rows if int(kp.person_ids[r]) in {int(p) for p in person_ids}]
    if len(rows) < min_persons:
        need = "two persons" if min_persons == 2 else f"{min_persons} person(s)"
        asked = f" of the requested {sorted(int(p) for p in person_ids)}" if person_ids is not None else ""
        raise ValueError(f"{what} needs {need} with motion, got {len(rows)}{asked} (persons with motion: {moving})")
    pids = [int(kp.person_ids[r]) for r in rows]
    bkp = kp if body_keypoints is None else body_keypoints
    bids = [int(i) for i in bkp.person_ids]
    lacking = [p for p in pids if p not in bids]
    if lacking:
        raise ValueError(f"{what}: persons {lacking} are not in body_keypoints (ids {bids})")
    skels, _ = build_skeletons(bkp, [bids.index(p) for p in pids], bodyfit, cfg)
    scene = mp.build_scene(skels, pids, kp.fps, kp.joint_names, humanoid_config(cfg))
    targets, weight = mp.site_targets(scene, kp, rows)
    return scene, mp.inverse_kinematics(scene, targets, weight)


def body_penetration_mm(
    kp: Keypoints3D,
    bodyfit: BodyFit | None = None,
    cfg: PhysicsConfig = PhysicsConfig(),
    person_ids: list[int] | None = None,
    body_keypoints: Keypoints3D | None = None,
) -> np.ndarray:
    """(frames,) deepest overlap in mm between two athletes' *own bodies*: the humanoids
    this stage builds (from ``bodyfit``, with ``cfg``'s geometry), each posed by inverse
    kinematics onto ``kp``'s joints; no separation, no floor lift, no simulation.

    ``pipeline.evaluate.physics_metrics`` measures penetration on fixed capsules around
    the keypoints, which need not match a real athlete's volume; this measure uses
    the body the physics stage collides. The humanoids are built as the stage builds
    them from ``body_keypoints`` (default ``kp``; pass the physics input to score
    another motion, e.g. ground truth, in the same bodies). ``person_ids`` restricts
    the persons (default: all with motion).
    Raises ``ValueError`` when fewer than two persons remain or one of them is not in
    ``body_keypoints``.
    """
    scene, qpos = posed_humanoids(kp, bodyfit, cfg, person_ids, body_keypoints, 2, "body_penetration_mm")
    return penetration_of_pose(scene, qpos)


def penetration_of_pose(scene: Scene, qpos: np.ndarray) -> np.ndarray:
    """(frames,) deepest overlap in mm between persons of ``scene`` posed at ``qpos``
    (frames, nq), e.g. from ``posed_humanoids``."""
    from pipeline.backends import mujoco_physics as mp

    contacts, _ = mp.contacts_and_sites(scene, qpos, np.zeros((qpos.shape[0], scene.model.nv)))
    return mp.deepest_inter_person_mm(contacts, qpos.shape[0])


def floor_timeconst_warning(cfg: PhysicsConfig, fps: float) -> str | None:
    """A message when ``cfg.floor_solref``'s time constant is below two MuJoCo steps at
    ``fps`` (MuJoCo then silently uses two steps: a softer floor than configured), else
    None."""
    tc = float(cfg.floor_solref[0])
    dt = 1.0 / (fps * cfg.substeps)
    if tc <= 0.0 or tc >= 2.0 * dt - 1e-12:
        return None
    need = int(np.ceil(2.0 / (fps * tc) - 1e-9))
    return (
        f"physics: floor_solref time constant {tc:g} s is below two steps ({2.0 * dt:.4g} s at "
        f"{fps:g} fps with substeps={cfg.substeps}); MuJoCo uses {2.0 * dt:.4g} s, a softer floor. "
        f"Use substeps >= {need} or a larger time constant."
    )


def humanoid_config(cfg: PhysicsConfig) -> HumanoidConfig:
    """The MJCF generator's settings of a physics stage configuration."""
    from pipeline.backends.mujoco_humanoid import HumanoidConfig

    return HumanoidConfig(
        residual_root=cfg.residual_root != "off", self_collision=cfg.self_collision, substeps=cfg.substeps,
        residual_force_frac=cfg.residual_force_frac,
        kp_per_kg=cfg.servo_kp_per_kg,
        torque_per_kg=cfg.servo_torque_per_kg,
        body_solref_timeconst_s=cfg.body_solref_s,
        residual_saturation_m=cfg.residual_saturation_m,
        armature=cfg.armature,
        body_friction=cfg.body_friction,
        friction=cfg.floor_friction,
        floor_solimp=tuple(cfg.floor_solimp),  # type: ignore[arg-type]
        floor_solref=tuple(cfg.floor_solref),  # type: ignore[arg-type]
        floor_margin_m=cfg.floor_margin_m,
        inter_person_arm_contacts=cfg.arm_contacts == "simulate",
        inter_person_foot_contacts=cfg.foot_contacts == "simulate",
    )


def run(
    inputs: PhysicsInputs,
    cfg: PhysicsConfig = PhysicsConfig(),
    progress: Callable[[int, int, str], None] | None = None,
) -> PhysicsOutput:
    """Simulate all persons of ``inputs.keypoints``; see the module docstring.

    Raises ``ValueError`` when no person has enough valid joints or the joint set
    lacks the COCO-17 joints.

    BLAS runs on one thread meanwhile, so the result does not depend on the machine's
    core count. The iLQR is chaotic, and OpenBLAS sums a matrix product's parts in
    another order on 2 threads than on 1: bench bout 2 (multi-person) ended with its
    deepest capsule overlap at 25.6 mm with ``OMP_NUM_THREADS=2`` and 6.3 mm with 1; it
    is 6.3 either way with the pin, at the same backward-pass time (the matrices are
    ≈ 250 × 250). The limit is the BLAS library's own, process-wide setting; the job
    worker runs each job in its own process.
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return _run(inputs, cfg, progress)


def _run(
    inputs: PhysicsInputs,
    cfg: PhysicsConfig,
    progress: Callable[[int, int, str], None] | None,
) -> PhysicsOutput:
    from pipeline.backends import mujoco_physics as mp
    from pipeline.backends.mujoco_ilqr import ILQRConfig
    from pipeline.backends.mujoco_tracking import CostWeights

    kp = inputs.keypoints
    if cfg.max_frames and kp.n_frames > cfg.max_frames:
        sl = slice(0, cfg.max_frames)
        kp = kp.replace(
            frame_indices=kp.frame_indices[sl], xyz_m=kp.xyz_m[sl], valid=kp.valid[sl], confidence=kp.confidence[sl],
            n_views=kp.n_views[sl], reproj_err_px=kp.reproj_err_px[sl],
        )
    t_start = time.perf_counter()
    if (msg := floor_timeconst_warning(cfg, kp.fps)) is not None:
        log.warning(msg)
    rows = _select_persons(kp)
    pids = [int(kp.person_ids[r]) for r in rows]
    skels, skeleton_kind = build_skeletons(kp, rows, inputs.bodyfit, cfg)
    hcfg = humanoid_config(cfg)
    sole_lift = max(cfg.floor_margin_m - 0.001, 0.0)
    foot_offsets_mm = 0.0
    if cfg.flat_feet and cfg.calibrate_foot_sites:
        from pipeline.backends.mujoco_foot_sites import move_sites, planted_site_offsets

        offs = planted_site_offsets(mp.build_scene(skels, pids, kp.fps, kp.joint_names, hcfg), kp, rows, sole_lift_m=sole_lift)
        skels = [move_sites(sk, o) for sk, o in zip(skels, offs, strict=True)]
        moved = [float(np.linalg.norm(v)) for o in offs for v in o.values()]
        foot_offsets_mm = 1000.0 * float(np.mean(moved)) if moved else 0.0
        log.info("physics: foot sites moved onto the planted keypoints by %.1f mm on average (%d sites)", foot_offsets_mm, len(moved))
    scfg = mp.SolverConfig(
        window=cfg.window,
        commit=cfg.commit,
        ilqr=ILQRConfig(
            max_iter=cfg.max_iter,
            deriv_every=cfg.deriv_every,
            n_alpha=cfg.n_alpha,
            alpha_min=cfg.alpha_min,
            fd_centered=cfg.fd_centered,
            substeps=cfg.substeps,
            jacobian_reuse=cfg.jacobian_reuse,
            rollout_threads=cfg.rollout_threads,
        ),
        weights=CostWeights(
            cfg.w_reg, cfg.w_pos, cfg.w_vel, cfg.w_collision, w_skate=cfg.w_skate, w_residual=cfg.w_residual,
            collision_clearance_m=cfg.collision_clearance_m,
        ),
        residual=cfg.residual_root,
        fallback_tol_m=cfg.fallback_tol_m,
        residual_torque_frac=cfg.residual_force_frac,
    )
    scene = mp.build_scene(skels, pids, kp.fps, kp.joint_names, hcfg)
    groups = [list(range(len(rows)))] if cfg.mode == "multi" else [[i] for i in range(len(rows))]
    F = kp.n_frames
    qpos = np.zeros((F, scene.model.nq))
    qvel = np.zeros((F, scene.model.nv))
    ctrl = np.zeros((F, scene.model.nu))
    force = np.zeros((F, scene.model.nu))
    resid = np.zeros((F, len(rows), 6))
    agg: dict[str, float] = {"windows": 0, "windows_with_residual": 0, "iterations": 0, "resets": 0, "kinematic_frames": 0}
    secs: dict[str, float] = {}
    done = [0]
    for g in groups:
        sub = scene if len(g) == len(rows) else mp.build_scene([skels[i] for i in g], [pids[i] for i in g], kp.fps, kp.joint_names, hcfg)
        ref, targets, weight = mp.build_reference(
            sub, kp, [rows[i] for i in g], separate=cfg.separate_reference, substeps=cfg.substeps if cfg.schedule else 0,
            flat_feet=cfg.flat_feet, sole_lift_m=sole_lift, ff_friction=cfg.feedforward_friction,
            ff_smooth_frames=cfg.feedforward_smooth_frames, separation_clearance_m=cfg.separation_clearance_m,
            posture_weight=cfg.ik_posture_weight,
        )

        def prog(d: int, n: int, msg: str, _g: list[int] = g) -> None:
            if progress is not None:
                progress(done[0] + d, n * len(groups), f"persons {[pids[i] for i in _g]}: {msg}")

        sol = mp.optimise_bout(sub, ref, targets, weight, scfg, prog)
        done[0] += sol.windows
        for i_sub, i in enumerate(g):
            ps, pf = sub.layout.persons[i_sub], scene.layout.persons[i]
            qpos[:, pf.qpos_adr : pf.qpos_adr + pf.nq] = sol.qpos[:, ps.qpos_adr : ps.qpos_adr + ps.nq]
            qvel[:, pf.qvel_adr : pf.qvel_adr + pf.nv] = sol.qvel[:, ps.qvel_adr : ps.qvel_adr + ps.nv]
            src = np.concatenate([ps.servo_ids, ps.residual_ids])
            dst = np.concatenate([pf.servo_ids, pf.residual_ids])
            ctrl[:, dst] = sol.ctrl[:, src]
            force[:, dst] = sol.actuator_force[:, src]
            resid[:, i] = sol.root_wrench[:, i_sub]
        agg["windows"] += sol.windows
        agg["windows_with_residual"] += sol.windows_with_residual
        agg["iterations"] += sol.iterations
        agg["resets"] += sol.resets
        agg["kinematic_frames"] += sol.kinematic_frames
        for k, v in sol.seconds.items():
            secs[k] = secs.get(k, 0.0) + v
    contacts, sites = mp.contacts_and_sites(scene, qpos, qvel)
    lay = scene.layout
    result = PhysicsResult(
        person_ids=np.asarray(pids, dtype=np.int64),
        frame_indices=kp.frame_indices.astype(np.int64),
        fps=float(kp.fps),
        qpos=qpos,
        qvel=qvel,
        ctrl=ctrl,
        joint_torque_nm=force,
        residual_root_force=resid,
        actuation="pd",
        contact_frame=contacts.frame,
        contact_person=contacts.person,
        contact_body=contacts.body,
        contact_depth_m=contacts.depth_m,
        body_names=contacts.body_names,
    )
    names = scene.site_names
    out_kp = Keypoints3D.empty(names, np.asarray(pids), kp.frame_indices, kp.fps, "physics")
    out_kp = out_kp.replace(
        xyz_m=sites,
        valid=np.ones(sites.shape[:3], dtype=bool),
        confidence=np.ones(sites.shape[:3]),
    )
    compute_s = time.perf_counter() - t_start
    motion_s = max(F - 1, 1) / kp.fps
    body_pen = mp.deepest_inter_person_mm(contacts, F)
    weight_n = np.array([p.mass_kg * 9.81 for p in lay.persons])
    stats: dict[str, Any] = {
        "mode": cfg.mode,
        "skeleton": skeleton_kind,
        "geometry": cfg.geometry if skeleton_kind == "bodyfit" else "capsule",
        "frames": F,
        "persons": len(rows),
        "nq": int(scene.model.nq),
        "nv": int(scene.model.nv),
        "nu": int(scene.model.nu),
        "mass_kg": [round(p.mass_kg, 2) for p in lay.persons],
        "foot_site_offset_mm_mean": round(foot_offsets_mm, 2),
        "windows": int(agg["windows"]),
        "windows_with_residual": int(agg["windows_with_residual"]),
        "iterations": int(agg["iterations"]),
        "resets": int(agg["resets"]),
        "kinematic_frames": int(agg["kinematic_frames"]),
        "residual_force_mean_frac_bw": float(np.mean(np.linalg.norm(resid[..., :3], axis=-1) / weight_n[None])),
        "residual_force_max_frac_bw": float(np.max(np.linalg.norm(resid[..., :3], axis=-1) / weight_n[None], initial=0.0)),
        "body_penetration_max_mm": float(body_pen.max(initial=0.0)),
        "body_penetration_mean_mm": float(body_pen.mean()) if body_pen.size else 0.0,
        "compute_s": compute_s,
        "realtime_factor": compute_s / motion_s,
        **{f"seconds_{k}": v for k, v in secs.items()},
    }
    return PhysicsOutput(result=result, keypoints=out_kp, mjcf=scene.mjcf, stats=stats)
