"""Configuration of the ``analyze`` stage: ``AnalyzeConfig`` and its parts.

How the thresholds were chosen and what they give: docs/design/analytics.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

AnalyzeSource = Literal["auto", "physics", "fit", "filtered"]


def _positive(owner: str, **values: float) -> None:
    bad = {k: v for k, v in values.items() if not v > 0}
    if bad:
        raise ValueError(f"{owner}: must be > 0, got {bad}")


@dataclass(frozen=True)
class PunchConfig:
    """Punch detection: an excursion of a fist away from its guard position."""

    guard_window_s: float = 1.5
    """Span of the running median that gives each fist's guard position (seconds, > 0)."""
    rest_speed_mps: float = 1.5
    """Only frames where the fist moves slower than this relative to the neck count towards
    the guard position (m/s, > 0)."""
    min_excursion_m: float = 0.18
    """Smallest distance of the fist from its guard at the strike (m, > 0): feints and
    guard adjustments travel less."""
    min_speed_mps: float = 2.0
    """Smallest peak speed of the fist relative to the neck on the way out (m/s, > 0)."""
    min_peak_speed_mps: float = 3.0
    """Smallest peak speed of the fist in the world frame over the punch, on the analysed
    keypoints (m/s, > 0); low, because smoothed 3D results flatten punches."""
    min_forward_m: float = 0.04
    """The fist must end this much farther forward (towards the opponent) than it started
    (m, >= 0): a punch goes at him; a block, a parry or a hand leaving a clinch grip does not.
    A margin above the 3D noise, not a punch's reach: a punch the fit flattens (two views) keeps
    its direction but advances a fraction of the way."""
    min_extension: float = 0.45
    """Smallest shoulder-to-wrist distance at the strike over the arm's length, in [0, 1]."""
    max_start_drop: float = 0.5
    """A punch starts from the guard: the fist at its start lies at most this many arm lengths
    below the neck (shoulders' midpoint); an arm swinging up from the hip starts lower (> 0)."""
    min_elbow_open_deg: float = 0.0
    """The elbow opens by at least this from the start to the strike (degrees, in [-180, 180]):
    a punch extends the arm, raising a hanging arm bends it."""
    max_out_s: float = 0.3
    """Longest way out (s, > 0): the start and the fastest frame are looked for this far
    before the excursion's peak at most."""
    arrive_frac: float = 0.3
    """The strike is the first frame after the fastest one where the fist's speed (relative
    to the neck) drops below this fraction of that fastest speed, in (0, 1)."""
    clinch_margin_s: float = 0.3
    """Excursions whose strike lies in a grip (a clinch, or close bodies with a hand of each at
    the other's torso), or within this of one, are the hands taking or leaving the grip, not
    punches (s, >= 0)."""
    edge_frac: float = 0.25
    """A punch starts / ends where the excursion falls below this fraction of its peak, in (0, 1)."""
    max_duration_s: float = 1.0
    """Longer excursions are not punches (a hand held out, a clinch grip), seconds."""
    split_at_valleys: bool = True
    """Two punches of one fist thrown without a full return to the guard (a double jab, a body
    shot then a hook) are one excursion with two peaks: split it at the smallest excursion between
    the peaks, where the fist turned to go out again, so that each is judged on its own."""
    speed_source: Literal["raw", "analysed"] = "raw"
    """Where the peak glove speed is measured. ``raw``: on the unfiltered triangulation when
    the stage gets it (``punches.raw_peak_speed``: filters and the fit's smoothness prior
    flatten a punch's peak); ``analysed``: the analysed keypoints' largest frame-to-frame speed."""
    speed_along_path: bool = True
    """With ``speed_source="raw"``: the raw derivative is taken along the analysed wrist's
    direction of motion (``punches.raw_peak_speed``), which drops the raw noise across the
    path; False takes its norm (five-point with 3+ views, seven-point with 2)."""
    raw_speed_max_ratio: float = 2.0
    """The raw measurement is kept between the analysed speed and this multiple of it (>= 1),
    so that a raw triangulation outlier cannot make a punch out of a reach."""
    min_measured_speed_mps: float = 4.0
    """With ``speed_source="raw"``, where the raw triangulation saw the wrist in every frame of
    the way out, the peak speed it measures there (``punches.Candidate.measured_mps``) must reach
    this (m/s, >= 0): a feint or a glove moved up to block is slower than a punch, which the
    smoothed analysed track, slowing both, does not tell apart."""
    fast_measured_mps: float = 5.5
    """... and where it reaches this, the fist passes the two speed rules on the analysed track
    (``min_speed_mps``, ``min_peak_speed_mps``): a fit from few views slows a punch to a
    third of its speed, the raw triangulation keeps it (m/s, > 0) ..."""
    fast_min_excursion_m: float = 0.12
    """... and it needs to go only this far from its guard (m, > 0): a two-view fit shortens a
    punch, and a fist held out at the target before pulls the guard estimate out."""
    max_gap_frames: int = 4
    """Gaps in a joint's estimate up to this many frames are interpolated (>= 0)."""
    flattened: bool = False
    """Also look for punches the body fit flattened on the filtered triangulation's wrist,
    when the stage gets it (``pipeline.stages.analyze.motion``); off by default, its false
    punches outweigh its finds with 2 views (docs/design/analytics.md)."""
    flattened_max_ratio: float = 0.95
    """A filtered-track excursion counts as flattened when the fit's wrist path over it is at
    most this fraction of the filtered wrist's (in (0, 1])."""
    flattened_min_out_s: float = 0.06
    """... and its way out (start to strike) lasts at least this (s, > 0): a filter or
    triangulation spike jumps out in a frame or two."""
    flattened_min_raw_speed_mps: float = 5.0
    """... and the raw triangulation's peak wrist speed over its way out reaches this (m/s, > 0):
    a real punch measured by two views, not the filter's drift where one view saw the wrist."""

    def __post_init__(self) -> None:
        _positive("PunchConfig", guard_window_s=self.guard_window_s, rest_speed_mps=self.rest_speed_mps,
                  min_excursion_m=self.min_excursion_m, min_speed_mps=self.min_speed_mps,
                  min_peak_speed_mps=self.min_peak_speed_mps, max_duration_s=self.max_duration_s,
                  max_out_s=self.max_out_s, fast_measured_mps=self.fast_measured_mps,
                  fast_min_excursion_m=self.fast_min_excursion_m)  # fmt: skip
        if not (0.0 < self.flattened_max_ratio <= 1.0 and self.flattened_min_raw_speed_mps > 0 and self.flattened_min_out_s > 0):
            raise ValueError(
                f"PunchConfig: flattened_max_ratio must be in (0, 1], flattened_min_raw_speed_mps and "
                f"flattened_min_out_s > 0; got {self.flattened_max_ratio}, {self.flattened_min_raw_speed_mps}, "
                f"{self.flattened_min_out_s}"
            )
        if not self.min_measured_speed_mps >= 0.0:
            raise ValueError(f"PunchConfig.min_measured_speed_mps must be >= 0, got {self.min_measured_speed_mps}")
        if not self.raw_speed_max_ratio >= 1.0:
            raise ValueError(f"PunchConfig.raw_speed_max_ratio must be >= 1, got {self.raw_speed_max_ratio}")
        if not (0.0 < self.edge_frac < 1.0 and 0.0 < self.arrive_frac < 1.0 and 0.0 <= self.min_extension <= 1.0):
            raise ValueError(
                f"PunchConfig: edge_frac and arrive_frac must be in (0, 1), min_extension in [0, 1]; got "
                f"{self.edge_frac}, {self.arrive_frac}, {self.min_extension}"
            )
        if not self.min_forward_m >= 0.0:
            raise ValueError(f"PunchConfig.min_forward_m must be >= 0, got {self.min_forward_m}")
        if not (self.max_start_drop > 0 and -180.0 <= self.min_elbow_open_deg <= 180.0):
            raise ValueError(
                f"PunchConfig: max_start_drop must be > 0 and min_elbow_open_deg in [-180, 180]; "
                f"got {self.max_start_drop}, {self.min_elbow_open_deg}"
            )
        if self.max_gap_frames < 0 or self.clinch_margin_s < 0:
            raise ValueError(
                f"PunchConfig: max_gap_frames and clinch_margin_s must be >= 0, got {self.max_gap_frames}, {self.clinch_margin_s}"
            )


@dataclass(frozen=True)
class ViewEvidenceConfig:
    """Punches the fit flattened, confirmed by the 2D tracks of each camera
    (``pipeline.stages.analyze.evidence2d``): a weak 3D excursion that one view shows as a
    fast, long excursion of the wrist away from the neck."""

    enabled: bool = False
    """Look for such punches when the stage gets the 2D tracks and their association (off by
    default; docs/design/analytics.md says why)."""
    unmeasured_only: bool = True
    """Take such punches only where the raw triangulation did not measure the fist's way out
    (under 60 % of its frames triangulated: the wrist was hidden in a view); where it did, its
    measured speed has judged the excursion (``PunchConfig.min_measured_speed_mps``)."""
    min_excursion_3d_m: float = 0.12
    """Smallest 3D excursion of the fist from its guard that is looked at (m, > 0; the punch
    rules' own threshold is ``PunchConfig.min_excursion_m``)."""
    view_min_excursion_m: float = 0.15
    """Smallest projected excursion of the wrist from its guard in one view over the way out
    and back (m across the line of sight, > 0)."""
    view_min_speed_mps: float = 4.0
    """Smallest projected speed of the wrist relative to the neck in that view on the way out
    (m/s, > 0)."""
    min_conf: float = 0.1
    """2D keypoints below this confidence are not used, in [0, 1]."""
    lift_speed: bool = True
    """With ``PunchConfig.speed_source="raw"``, where the raw triangulation does not measure a
    punch's peak speed (one view saw the wrist), raise it to the fastest view's projected wrist
    speed, kept within ``PunchConfig.raw_speed_max_ratio`` of the analysed speed
    (``evidence2d.view_peak_speed``). Independent of ``enabled``: it needs the 2D tracks only."""
    scale_window_s: float = 1.5
    """Span of the running median of the athlete's image torso length that sets each view's
    metres per pixel (s, > 0)."""

    def __post_init__(self) -> None:
        _positive("ViewEvidenceConfig", min_excursion_3d_m=self.min_excursion_3d_m,
                  view_min_excursion_m=self.view_min_excursion_m, view_min_speed_mps=self.view_min_speed_mps,
                  scale_window_s=self.scale_window_s)  # fmt: skip
        if not 0.0 <= self.min_conf <= 1.0:
            raise ValueError(f"ViewEvidenceConfig.min_conf must be in [0, 1], got {self.min_conf}")


@dataclass(frozen=True)
class TypeConfig:
    """Punch type rules, on the fist's path from the guard to the strike in the boxer's
    facing frame (x towards the opponent, y to his left, z up). Path shapes are measured in
    shares of the chord (the straight line from start to strike), so that a path the 3D
    estimate shrinks keeps its type."""

    uppercut_min_sag: float = 0.2
    """An uppercut scoops: its path sags below the chord by at least this share of the
    chord's length, in (0, 1) ..."""
    uppercut_min_climb: float = 0.06
    """... and the fist climbs from the path's lowest point to the strike by at least this
    share of the chord's length, in (0, 1) (a straight body shot sinks and stays low)."""
    uppercut_min_rise: float = 0.6
    """An uppercut with a shallower scoop arrives rising: the upward share of its arrival
    direction (from the fastest frame of the way out to the strike) is at least this, in (0, 1) ..."""
    uppercut_rise_min_sag: float = 0.1
    """... and its path still dips below the chord by at least this share of the chord's length,
    in [0, 1) (a fist going straight up from the guard is a straight punch the 3D estimate tilted)."""
    hook_min_bulge: float = 0.16
    """A hook's path bulges outwards (to the punching side) from the chord by at least this
    share of the chord's length, in (0, 1) ..."""
    hook_min_swing_deg: float = 15.0
    """... and swings out first: the way from the start to the bulge's apex heads at least this
    far outwards of the straight line from the start to the opponent (degrees, in [0, 90)). A
    straight punch turned aside by a parry bulges as much (its end turns inwards), but heads
    at the opponent until the contact."""
    aim_ahead_m: float = 0.9
    """Where a straight punch heads: the opponent's centreline this far ahead of the thrower's
    neck (m, in (0.3, 3); the neck-to-head distance at punching range)."""
    body_level_frac: float = 0.9
    """A straight punch is a body shot when the fist at the strike is below this fraction of
    the way from the opponent's mid-hip to his mid-shoulder height, in (0, 1.5)."""

    def __post_init__(self) -> None:
        shares = {"uppercut_min_sag": self.uppercut_min_sag, "uppercut_min_climb": self.uppercut_min_climb,
                  "uppercut_min_rise": self.uppercut_min_rise, "hook_min_bulge": self.hook_min_bulge}  # fmt: skip
        bad = {k: v for k, v in shares.items() if not 0.0 < v < 1.0}
        if bad:
            raise ValueError(f"TypeConfig: must be in (0, 1), got {bad}")
        if not 0.0 <= self.uppercut_rise_min_sag < 1.0:
            raise ValueError(f"TypeConfig.uppercut_rise_min_sag must be in [0, 1), got {self.uppercut_rise_min_sag}")
        if not 0.0 <= self.hook_min_swing_deg < 90.0:
            raise ValueError(f"TypeConfig.hook_min_swing_deg must be in [0, 90), got {self.hook_min_swing_deg}")
        if not 0.3 < self.aim_ahead_m < 3.0:
            raise ValueError(f"TypeConfig.aim_ahead_m must be in (0.3, 3), got {self.aim_ahead_m}")
        if not 0.0 < self.body_level_frac < 1.5:
            raise ValueError(f"TypeConfig.body_level_frac must be in (0, 1.5), got {self.body_level_frac}")


@dataclass(frozen=True)
class OutcomeConfig:
    """Target region and outcome, from the gaps between the glove and the opponent's head,
    trunk and arms (``pipeline.evaluate.glove_contact``) around the strike."""

    contact_tol_m: float = 0.04
    """A gap up to this counts as contact (m, >= 0): it absorbs the 3D estimate's error."""
    target_radius_m: float = 0.2
    """A missed punch's target region is the nearest one within this gap, else "none" (m, >= 0)."""
    window_frames: int = 2
    """Frames either side of the strike where contact is looked for (>= 0)."""
    filtered_reach: bool = True
    """Where the thrower's raw wrist was seen by fewer than ``filtered_reach_views`` views, take
    each gap as the smaller of the analysed glove's and the glove placed by the filtered
    triangulation (when the stage gets it): a two-view fit shortens punches, so its gaps err
    on the large side, and a landed punch would read as missed."""
    filtered_reach_views: float = 3.0
    """Median number of views of the raw wrist over the punch below which ``filtered_reach``
    applies (> 0; 3 = when the wrist was mostly triangulated from two views)."""
    use_contacts: bool = True
    """Use the physics stage's recorded contacts (glove or forearm on the opponent's head,
    trunk or arms) when analysing the physics result; they decide where they exist."""

    def __post_init__(self) -> None:
        if not self.filtered_reach_views > 0:
            raise ValueError(f"OutcomeConfig.filtered_reach_views must be > 0, got {self.filtered_reach_views}")
        if self.contact_tol_m < 0 or self.target_radius_m < 0 or self.window_frames < 0:
            raise ValueError(
                f"OutcomeConfig: contact_tol_m, target_radius_m and window_frames must be >= 0, got "
                f"{self.contact_tol_m}, {self.target_radius_m}, {self.window_frames}"
            )


@dataclass(frozen=True)
class DefenceConfig:
    """Slips and ducks (the defender's head leaving a punch's line), blocks and parries
    (``blocks``) and clinches."""

    slip_min_m: float = 0.12
    """Sideways head displacement across the punch's line that makes a slip (m, > 0)."""
    duck_min_m: float = 0.12
    """Head drop that makes a duck (m, > 0)."""
    evade_before_s: float = 0.3
    """The head's position this long before the strike is the reference (s, > 0)."""
    clinch_torso_m: float = 0.6
    """A clinch frame has the torso centres (mean of shoulders and hips) closer than this (m, > 0)."""
    clinch_wrap_m: float = 0.5
    """... and a wrist of each athlete within this of the other's torso centre (m, > 0) ..."""
    clinch_reach_m: float = 0.06
    """... that reaches, along the line between the torso centres, at least as far as the other's
    centre less this (m, >= 0): the arms go around him, a guard between close bodies does not."""
    clinch_min_s: float = 0.3
    """Clinches shorter than this are dropped; gaps shorter than this are bridged (s, > 0)."""
    parry_min_speed_mps: float = 1.0
    """A parrying glove moves across the punch's line at least this fast before the contact (m/s, > 0)."""
    parry_min_deflection_m: float = 0.05
    """... and deflects the punching glove sideways, its way, by at least this (m, > 0)."""
    deflect_window_s: float = 0.06
    """Span before a contact over which velocities are taken, and after it over which the
    deflection is measured (s, > 0; at least one frame)."""
    parry_measured: bool = False
    """Also run the parry test on the raw triangulation's limbs (where it has them) when the
    analysed 3D finds none (the fit smooths a parry's glove contact away); finds parries at
    the cost of some false ones taken from blocks (docs/design/analytics.md)."""

    def __post_init__(self) -> None:
        _positive("DefenceConfig", slip_min_m=self.slip_min_m, duck_min_m=self.duck_min_m,
                  evade_before_s=self.evade_before_s, clinch_torso_m=self.clinch_torso_m,
                  clinch_wrap_m=self.clinch_wrap_m, clinch_min_s=self.clinch_min_s,
                  parry_min_speed_mps=self.parry_min_speed_mps, parry_min_deflection_m=self.parry_min_deflection_m,
                  deflect_window_s=self.deflect_window_s)  # fmt: skip
        if not self.clinch_reach_m >= 0:
            raise ValueError(f"DefenceConfig.clinch_reach_m must be >= 0, got {self.clinch_reach_m}")


@dataclass(frozen=True)
class RingConfig:
    """Stance and guard series."""

    square_m: float = 0.08
    """Feet level to within this along the line to the opponent make a square stance (m, >= 0)."""
    stance_smooth_s: float = 0.3
    """Running median of the foot offset before the stance is decided (s, >= 0)."""
    chin_below_ears_m: float = 0.1
    """The chin is taken this far below the ears' midpoint (m, >= 0)."""

    def __post_init__(self) -> None:
        if self.square_m < 0 or self.stance_smooth_s < 0 or self.chin_below_ears_m < 0:
            raise ValueError(
                f"RingConfig: square_m, stance_smooth_s and chin_below_ears_m must be >= 0, got "
                f"{self.square_m}, {self.stance_smooth_s}, {self.chin_below_ears_m}"
            )


@dataclass(frozen=True)
class WorkRateConfig:
    """Punches per minute."""

    window_s: float = 60.0
    """Trailing window of the punches-per-minute series (s, > 0)."""
    min_window_s: float = 5.0
    """Near the start the window is the time elapsed, but at least this (s, > 0)."""

    def __post_init__(self) -> None:
        _positive("WorkRateConfig", window_s=self.window_s, min_window_s=self.min_window_s)


@dataclass(frozen=True)
class CorrectionConfig:
    """How annotators' event edits (``correct_event``, ``add_event``, ``delete_event``) find
    their event after a re-run."""

    match_frames: int = 2
    """An edit names an event by athlete, kind and the frame of its peak (strike); it matches
    the nearest such event within this many frames (>= 0)."""

    def __post_init__(self) -> None:
        if self.match_frames < 0:
            raise ValueError(f"CorrectionConfig.match_frames must be >= 0, got {self.match_frames}")


@dataclass(frozen=True)
class AnalyzeConfig:
    """Boxing analytics on the 3D keypoints: punches, slips and ducks, clinches, stance,
    guard, distance and work rate."""

    source: AnalyzeSource = "auto"
    """3D result analysed: ``auto`` = physics, else fit, else filtered (``pipeline.schema.sources``)."""
    punch: PunchConfig = field(default_factory=PunchConfig)
    views: ViewEvidenceConfig = field(default_factory=ViewEvidenceConfig)
    types: TypeConfig = field(default_factory=TypeConfig)
    outcome: OutcomeConfig = field(default_factory=OutcomeConfig)
    defence: DefenceConfig = field(default_factory=DefenceConfig)
    ring: RingConfig = field(default_factory=RingConfig)
    work_rate: WorkRateConfig = field(default_factory=WorkRateConfig)
    corrections: CorrectionConfig = field(default_factory=CorrectionConfig)
