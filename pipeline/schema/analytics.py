"""Boxing analytics: the events of a bout and the per-athlete series (the ``analyze`` stage's
artifacts ``events.npz`` and ``series.npz``).

Frames are video frame indices (those of the analysed ``Keypoints3D``); intervals are
inclusive. Categorical fields are fixed-width unicode arrays whose values come from the
vocabularies below (npz without pickle).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.schema.base import check_array

PUNCH_TYPES: tuple[str, ...] = (
    "jab",
    "cross",
    "lead_hook",
    "rear_hook",
    "lead_uppercut",
    "rear_uppercut",
    "body_shot",
)
"""Punch types: straights to the head (jab = lead hand, cross = rear hand), hooks and
uppercuts by hand, and ``body_shot`` = a straight punch to the body with either hand
(hooks and uppercuts keep their type whatever they hit; ``target`` says where)."""
HANDS: tuple[str, ...] = ("left", "right")
TARGETS: tuple[str, ...] = ("head", "body", "guard", "none")
"""Region of the opponent the glove ends at: head, trunk, arms/gloves, or nothing near."""
OUTCOMES: tuple[str, ...] = ("landed", "blocked", "missed")
"""landed: the glove reaches the head or trunk; blocked: it stops on the gloves or arms;
missed: it touches neither."""
OUTCOME_COLORS: dict[str, str] = {"landed": "#1a7f37", "blocked": "#e0a100", "missed": "#8c8c8c"}
"""Colour (CSS hex) of each punch outcome wherever one is drawn: the report's charts, the viewer."""
EVADE_KINDS: tuple[str, ...] = ("slip", "duck", "block", "parry")
"""Defence against one punch (``BoutEvents.evade_*`` rows). slip: the head leaves the punch's
line sideways; duck: it drops under it; block: the punch's glove stops on the defender's glove
or forearm; parry: the defender's glove meets the punching arm moving across its line and
deflects it (``pipeline.stages.analyze.blocks``)."""
EVENT_SOURCES: tuple[str, ...] = ("detector", "corrected", "annotator")
"""Who made an event: the detector, the detector with an annotator's correction of its type or
outcome (``correct_event``), or an annotator (``add_event``; its speed, extension and
displacement are measured on the 3D over the annotated frames, 0 where the 3D is missing)."""
STANCE_CODES: dict[int, str] = {1: "orthodox", -1: "southpaw", 0: "square"}
"""``AthleteSeries.stance`` values: left foot forward, right foot forward, neither."""


def _check_vocab(name: str, arr: np.ndarray, vocab: tuple[str, ...], n: int) -> None:
    check_array(name, arr, (n,), "U")
    bad = sorted(set(arr.tolist()) - set(vocab))
    if bad:
        raise ValueError(f"{name}: unknown values {bad}; expected one of {vocab}")


def _no_source() -> np.ndarray:
    return np.zeros(0, dtype="<U1")


def _fill_source(obj: object, name: str, n: int) -> None:
    """An empty source array on ``n`` rows means every row is the detector's (artifacts written
    before the field existed, or built without it)."""
    arr = getattr(obj, name)
    if isinstance(arr, np.ndarray) and arr.shape == (0,) and n > 0:
        object.__setattr__(obj, name, np.full(n, "detector", dtype="<U9"))


def _check_intervals(name: str, start: np.ndarray, end: np.ndarray, n: int, peak: np.ndarray | None = None) -> None:
    check_array(f"{name}_start_frame", start, (n,), "iu")
    check_array(f"{name}_end_frame", end, (n,), "iu")
    if peak is not None:
        check_array(f"{name}_peak_frame", peak, (n,), "iu")
        bad = np.flatnonzero((start > peak) | (peak > end))
    else:
        bad = np.flatnonzero(start > end)
    if bad.size:
        i = int(bad[0])
        mid = f" <= peak {int(peak[i])}" if peak is not None else ""
        raise ValueError(f"{name} {i}: frames must satisfy start {int(start[i])}{mid} <= end {int(end[i])}")


@dataclass(frozen=True)
class BoutEvents:
    """Punches, defence (slips, ducks, blocks, parries) and clinches found in a bout
    (``punches``, ``evades``, ``clinches`` rows).

    Fields:
        fps: frame rate of the frame indices (Hz).
        person_ids: (persons,) the athletes analysed.
        punch_person: (punches,) athlete who threw it.
        punch_hand: (punches,) ``HANDS``.
        punch_type: (punches,) ``PUNCH_TYPES``.
        punch_start_frame / punch_peak_frame / punch_end_frame: (punches,) the glove
            leaves the guard / is farthest out (the strike) / is back; start <= peak <= end.
        punch_peak_speed_mps: (punches,) peak glove (wrist) speed in the world frame, m/s.
        punch_extension: (punches,) shoulder-to-wrist distance at the strike over the arm's
            length, ~0.4 (guard) to 1 (straight arm).
        punch_target: (punches,) ``TARGETS``.
        punch_outcome: (punches,) ``OUTCOMES``.
        punch_confidence: (punches,) in [0, 1]: a heuristic score (how clearly the motion
            passes the detection thresholds, times the keypoints' confidence), not a
            calibrated probability.
        evade_person: (evades,) athlete who defended.
        evade_kind: (evades,) ``EVADE_KINDS``: slip, duck, block or parry.
        evade_start_frame / evade_peak_frame / evade_end_frame: (evades,) frames (a block:
            first contact / closest approach / last contact; a parry: the defender's glove
            starts across / first contact / end of the deflection window).
        evade_displacement_m: (evades,) metres, >= 0: a slip's sideways and a duck's downward
            head displacement at the peak; a block's or parry's sideways deflection of the
            punching glove after the contact.
        evade_punch: (evades,) row of the punch defended.
        clinch_start_frame / clinch_end_frame: (clinches,) inclusive frames of each clinch
            (both athletes' torsos close with the arms wrapped around the other).
        punch_source / evade_source / clinch_source: (punches,) / (evades,) / (clinches,)
            ``EVENT_SOURCES``: detector, corrected (an annotator changed its type or outcome)
            or annotator (added by hand); empty = all ``"detector"``.
    """

    fps: float
    person_ids: np.ndarray
    punch_person: np.ndarray
    punch_hand: np.ndarray
    punch_type: np.ndarray
    punch_start_frame: np.ndarray
    punch_peak_frame: np.ndarray
    punch_end_frame: np.ndarray
    punch_peak_speed_mps: np.ndarray
    punch_extension: np.ndarray
    punch_target: np.ndarray
    punch_outcome: np.ndarray
    punch_confidence: np.ndarray
    evade_person: np.ndarray
    evade_kind: np.ndarray
    evade_start_frame: np.ndarray
    evade_peak_frame: np.ndarray
    evade_end_frame: np.ndarray
    evade_displacement_m: np.ndarray
    evade_punch: np.ndarray
    clinch_start_frame: np.ndarray
    clinch_end_frame: np.ndarray
    punch_source: np.ndarray = field(default_factory=_no_source)
    evade_source: np.ndarray = field(default_factory=_no_source)
    clinch_source: np.ndarray = field(default_factory=_no_source)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"BoutEvents.fps must be positive, got {self.fps}")
        check_array("BoutEvents.person_ids", self.person_ids, (None,), "iu")
        n = self.punch_person.shape[0] if isinstance(self.punch_person, np.ndarray) else -1
        check_array("BoutEvents.punch_person", self.punch_person, (n,), "iu")
        _check_vocab("BoutEvents.punch_hand", self.punch_hand, HANDS, n)
        _check_vocab("BoutEvents.punch_type", self.punch_type, PUNCH_TYPES, n)
        _check_vocab("BoutEvents.punch_target", self.punch_target, TARGETS, n)
        _check_vocab("BoutEvents.punch_outcome", self.punch_outcome, OUTCOMES, n)
        _check_intervals("BoutEvents.punch", self.punch_start_frame, self.punch_end_frame, n, self.punch_peak_frame)
        check_array("BoutEvents.punch_peak_speed_mps", self.punch_peak_speed_mps, (n,), "f", finite=True)
        check_array("BoutEvents.punch_extension", self.punch_extension, (n,), "f", finite=True)
        check_array("BoutEvents.punch_confidence", self.punch_confidence, (n,), "f", finite=True)
        if n and (self.punch_confidence.min() < 0 or self.punch_confidence.max() > 1):
            raise ValueError(f"BoutEvents.punch_confidence must lie in [0, 1], got {self.punch_confidence.min()}..{self.punch_confidence.max()}")
        unknown = np.setdiff1d(self.punch_person, self.person_ids)
        if unknown.size:
            raise ValueError(f"BoutEvents.punch_person uses ids {unknown.tolist()} not in person_ids {self.person_ids.tolist()}")
        m = self.evade_person.shape[0] if isinstance(self.evade_person, np.ndarray) else -1
        check_array("BoutEvents.evade_person", self.evade_person, (m,), "iu")
        _check_vocab("BoutEvents.evade_kind", self.evade_kind, EVADE_KINDS, m)
        _check_intervals("BoutEvents.evade", self.evade_start_frame, self.evade_end_frame, m, self.evade_peak_frame)
        check_array("BoutEvents.evade_displacement_m", self.evade_displacement_m, (m,), "f", finite=True)
        check_array("BoutEvents.evade_punch", self.evade_punch, (m,), "iu")
        if m and (self.evade_punch.min() < 0 or self.evade_punch.max() >= n):
            raise ValueError(f"BoutEvents.evade_punch must index the {n} punches, got {self.evade_punch.tolist()}")
        c = self.clinch_start_frame.shape[0] if isinstance(self.clinch_start_frame, np.ndarray) else -1
        _check_intervals("BoutEvents.clinch", self.clinch_start_frame, self.clinch_end_frame, c)
        for name, k in (("punch_source", n), ("evade_source", m), ("clinch_source", c)):
            _fill_source(self, name, k)
            _check_vocab(f"BoutEvents.{name}", getattr(self, name), EVENT_SOURCES, k)

    @property
    def n_punches(self) -> int:
        return int(self.punch_person.shape[0])

    @property
    def n_evades(self) -> int:
        return int(self.evade_person.shape[0])

    @property
    def n_clinches(self) -> int:
        return int(self.clinch_start_frame.shape[0])

    @classmethod
    def empty(cls, fps: float, person_ids: np.ndarray) -> BoutEvents:
        """No events (a bout without punches, or too short to analyse)."""
        i, f, s = np.zeros(0, np.int64), np.zeros(0), np.zeros(0, dtype="<U1")
        return cls(
            fps=float(fps), person_ids=np.asarray(person_ids, dtype=np.int64),
            punch_person=i, punch_hand=s, punch_type=s, punch_start_frame=i, punch_peak_frame=i, punch_end_frame=i,
            punch_peak_speed_mps=f, punch_extension=f, punch_target=s, punch_outcome=s, punch_confidence=f,
            evade_person=i, evade_kind=s, evade_start_frame=i, evade_peak_frame=i, evade_end_frame=i,
            evade_displacement_m=f, evade_punch=i, clinch_start_frame=i, clinch_end_frame=i,
        )  # fmt: skip


@dataclass(frozen=True)
class AthleteSeries:
    """Per-frame measurements of each athlete (and of the pair).

    Fields:
        frame_indices: (frames,) video frame indices (strictly increasing).
        fps: frame rate (Hz).
        person_ids: (persons,) the athletes.
        valid: (frames, persons) bool: the athlete's body is known in that frame; the
            per-athlete series below mean nothing where it is False.
        distance_m: (frames,) horizontal distance between the two athletes' mid-hips
            (0 where ``distance_valid`` is False).
        distance_valid: (frames,) bool: both athletes known (and there are two).
        stance: (frames, persons) int: +1 orthodox (left foot in front), -1 southpaw,
            0 square (feet level to within ``RingConfig.square_m``).
        stance_width_m: (frames, persons) horizontal distance between the ankles.
        guard_height_m: (frames, persons, 2) height of the (left, right) wrist above the
            chin (negative = below the chin).
        punches_per_min: (frames, persons) punches thrown in the trailing window
            (``WorkRateConfig.window_s``) per minute.
        position_xy_m: (frames, persons, 2) horizontal mid-hip position in the world frame,
            metres (0 where ``position_valid`` is False); empty in artifacts written before
            the field existed (read as never known).
        position_valid: (frames, persons) bool: the mid-hip is known.
    """

    frame_indices: np.ndarray
    fps: float
    person_ids: np.ndarray
    valid: np.ndarray
    distance_m: np.ndarray
    distance_valid: np.ndarray
    stance: np.ndarray
    stance_width_m: np.ndarray
    guard_height_m: np.ndarray
    punches_per_min: np.ndarray
    position_xy_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 2)))
    position_valid: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))

    def __post_init__(self) -> None:
        f = self.frame_indices.shape[0] if isinstance(self.frame_indices, np.ndarray) else -1
        p = self.person_ids.shape[0] if isinstance(self.person_ids, np.ndarray) else -1
        if isinstance(self.position_xy_m, np.ndarray) and self.position_xy_m.size == 0 and min(f, p) >= 0:
            object.__setattr__(self, "position_xy_m", np.zeros((f, p, 2)))
            object.__setattr__(self, "position_valid", np.zeros((f, p), dtype=bool))
        check_array("AthleteSeries.frame_indices", self.frame_indices, (f,), "iu")
        check_array("AthleteSeries.person_ids", self.person_ids, (p,), "iu")
        check_array("AthleteSeries.valid", self.valid, (f, p), "b")
        check_array("AthleteSeries.distance_m", self.distance_m, (f,), "f", finite=True)
        check_array("AthleteSeries.distance_valid", self.distance_valid, (f,), "b")
        check_array("AthleteSeries.stance", self.stance, (f, p), "i")
        check_array("AthleteSeries.stance_width_m", self.stance_width_m, (f, p), "f", finite=True)
        check_array("AthleteSeries.guard_height_m", self.guard_height_m, (f, p, 2), "f", finite=True)
        check_array("AthleteSeries.punches_per_min", self.punches_per_min, (f, p), "f", finite=True)
        check_array("AthleteSeries.position_xy_m", self.position_xy_m, (f, p, 2), "f", finite=True)
        check_array("AthleteSeries.position_valid", self.position_valid, (f, p), "b")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"AthleteSeries.fps must be positive, got {self.fps}")
        bad = np.setdiff1d(np.unique(self.stance), list(STANCE_CODES))
        if bad.size:
            raise ValueError(f"AthleteSeries.stance: unknown codes {bad.tolist()}; expected {sorted(STANCE_CODES)}")

    @property
    def n_frames(self) -> int:
        return int(self.frame_indices.shape[0])
