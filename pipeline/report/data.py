"""What the bout report shows: the analyze stage's events and series, the athletes' ring
positions and the session's names, gathered once (``load_report_data``) so that the
rendering (``pipeline.report.html.render_report``) is a pure function of this data.

Also the slicing of a bout into periods (rounds, or fixed spans when the rounds are not
known), each summarised by ``pipeline.stages.analyze.athlete_summary``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from pipeline.schema.analytics import AthleteSeries, BoutEvents

ATHLETE_COLORS: tuple[str, ...] = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#8c564b", "#e377c2")
"""Default athlete colours by person order (the viewer's red and blue corners first)."""


@dataclass(frozen=True)
class ReportOptions:
    """How the report bins and splits the bout."""

    period_s: float = 60.0
    """Length of a summary period when the session gives no round times (s, > 0)."""
    bin_s: float = 10.0
    """Width of a work-rate timeline bin (s, > 0)."""
    speed_bin_mps: float = 0.5
    """Width of a peak-speed histogram bin (m/s, > 0)."""
    heat_cell_m: float = 0.25
    """Side of a ring-position heatmap cell (m, > 0)."""

    def __post_init__(self) -> None:
        bad = {k: v for k, v in vars(self).items() if not (np.isfinite(v) and v > 0)}
        if bad:
            raise ValueError(f"ReportOptions: must be finite and > 0, got {bad}")


@dataclass(frozen=True)
class ReportData:
    """Everything the report renders.

    Fields:
        title: bout name.
        events, series: the analyze stage's artifacts.
        source: the 3D result analysed (``physics``, ``fit``, ``filtered``).
        names: person id -> athlete name (missing ids show as ``athlete <id>``).
        colors: person id -> CSS colour (missing ids take ``ATHLETE_COLORS`` by order).
        date: the bout's date as given by the app ("" = unknown).
        analysed_unix_s: when the analyze stage ran (Unix seconds, 0 = unknown).
        positions_xy_m: (frames, persons, 2) horizontal mid-hip position in the world frame
            (metres), on ``series``' frames and persons; None when the 3D result is missing.
        positions_valid: (frames, persons) bool, where ``positions_xy_m`` is known.
        ring_xy_m: (corners, 2) the ring's outline in the world frame (metres), or None when
            the session does not give it (the report then draws the positions' bounding box).
        rounds_s: (start, end) of each round in seconds from the first analysed frame; empty
            when the session gives no round times (the report then splits the bout in
            ``ReportOptions.period_s`` spans).
    """

    title: str
    events: BoutEvents
    series: AthleteSeries
    source: str = ""
    names: dict[int, str] = field(default_factory=dict)
    colors: dict[int, str] = field(default_factory=dict)
    date: str = ""
    analysed_unix_s: float = 0.0
    positions_xy_m: np.ndarray | None = None
    positions_valid: np.ndarray | None = None
    ring_xy_m: np.ndarray | None = None
    rounds_s: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        f, p = self.series.n_frames, self.series.person_ids.shape[0]
        if (self.positions_xy_m is None) != (self.positions_valid is None):
            raise ValueError("ReportData: positions_xy_m and positions_valid go together")
        if self.positions_xy_m is not None and self.positions_valid is not None:
            if self.positions_xy_m.shape != (f, p, 2) or self.positions_valid.shape != (f, p):
                raise ValueError(
                    f"ReportData: positions must be ({f}, {p}, 2) and ({f}, {p}), got "
                    f"{self.positions_xy_m.shape} and {self.positions_valid.shape}"
                )
        if self.ring_xy_m is not None and (
            self.ring_xy_m.ndim != 2 or self.ring_xy_m.shape[1] != 2 or len(self.ring_xy_m) < 3
        ):
            raise ValueError(f"ReportData.ring_xy_m must be (corners >= 3, 2), got {self.ring_xy_m.shape}")
        for a, b in self.rounds_s:
            if not (0 <= a < b):
                raise ValueError(
                    f"ReportData.rounds_s: each round needs 0 <= start < end seconds, got ({a}, {b})"
                )

    @property
    def person_ids(self) -> list[int]:
        return [int(p) for p in self.series.person_ids]

    @property
    def duration_s(self) -> float:
        return self.series.n_frames / self.series.fps

    def name_of(self, pid: int) -> str:
        return self.names.get(int(pid), f"athlete {int(pid)}")

    def color_of(self, pid: int) -> str:
        if int(pid) in self.colors:
            return self.colors[int(pid)]
        return ATHLETE_COLORS[self.person_ids.index(int(pid)) % len(ATHLETE_COLORS)]


@dataclass(frozen=True)
class Period:
    """A span of the bout: ``label`` and its seconds from the first analysed frame [start_s, end_s)."""

    label: str
    start_s: float
    end_s: float


def periods(data: ReportData, options: ReportOptions) -> tuple[list[Period], str]:
    """The summary's periods and a sentence saying where they come from."""
    dur = data.duration_s
    if data.rounds_s:
        return [
            Period(f"round {k + 1}", a, min(b, dur)) for k, (a, b) in enumerate(data.rounds_s) if a < dur
        ], ("Rounds from the session's round times.")
    n = max(1, int(np.ceil(dur / options.period_s - 1e-9)))
    out = [Period(f"{_mmss(k * options.period_s)}–{_mmss(min(dur, (k + 1) * options.period_s))}",
                  k * options.period_s, min(dur, (k + 1) * options.period_s)) for k in range(n)]  # fmt: skip
    return out, (
        f"The session gives no round times: the bout is split into {options.period_s:g} s periods"
        + (" (one period: the bout is shorter)." if n == 1 else ".")
    )


def _mmss(t_s: float) -> str:
    t = int(round(t_s))
    return f"{t // 60}:{t % 60:02d}"


def slice_bout(
    events: BoutEvents, series: AthleteSeries, start_s: float, end_s: float
) -> tuple[BoutEvents, AthleteSeries]:
    """The events and series of [start_s, end_s) seconds from the first analysed frame.

    A punch belongs to the span of its peak frame, a slip or duck to the span of the punch
    it evaded, and a clinch is clipped to the span; so the spans of a bout add up to it.
    Raises ``ValueError`` when the span holds no analysed frame."""
    fr = series.frame_indices
    f0 = (fr[0] if fr.size else 0) + start_s * series.fps
    f1 = (fr[0] if fr.size else 0) + end_s * series.fps
    rows = (fr >= f0 - 1e-6) & (fr < f1 - 1e-6)
    if not rows.any():
        raise ValueError(f"slice_bout: no analysed frame in [{start_s}, {end_s}) s")
    lo, hi = int(fr[rows][0]), int(fr[rows][-1])
    sub = replace(
        series, frame_indices=fr[rows], valid=series.valid[rows], distance_m=series.distance_m[rows],
        distance_valid=series.distance_valid[rows], stance=series.stance[rows], stance_width_m=series.stance_width_m[rows],
        guard_height_m=series.guard_height_m[rows], punches_per_min=series.punches_per_min[rows],
    )  # fmt: skip
    keep = (events.punch_peak_frame >= lo) & (events.punch_peak_frame <= hi)
    new_index = np.cumsum(keep) - 1
    ev_keep = keep[events.evade_punch] if events.n_evades else np.zeros(0, bool)
    c_start = np.maximum(events.clinch_start_frame, lo)
    c_end = np.minimum(events.clinch_end_frame, hi)
    c_keep = c_start <= c_end
    ev = replace(
        events,
        punch_person=events.punch_person[keep], punch_hand=events.punch_hand[keep], punch_type=events.punch_type[keep],
        punch_start_frame=events.punch_start_frame[keep], punch_peak_frame=events.punch_peak_frame[keep],
        punch_end_frame=events.punch_end_frame[keep], punch_peak_speed_mps=events.punch_peak_speed_mps[keep],
        punch_extension=events.punch_extension[keep], punch_target=events.punch_target[keep],
        punch_outcome=events.punch_outcome[keep], punch_confidence=events.punch_confidence[keep],
        punch_source=events.punch_source[keep], evade_source=events.evade_source[ev_keep],
        clinch_source=events.clinch_source[c_keep],
        evade_person=events.evade_person[ev_keep], evade_kind=events.evade_kind[ev_keep],
        evade_start_frame=events.evade_start_frame[ev_keep], evade_peak_frame=events.evade_peak_frame[ev_keep],
        evade_end_frame=events.evade_end_frame[ev_keep], evade_displacement_m=events.evade_displacement_m[ev_keep],
        evade_punch=new_index[events.evade_punch[ev_keep]].astype(np.int64) if events.n_evades else events.evade_punch,
        clinch_start_frame=c_start[c_keep], clinch_end_frame=c_end[c_keep],
    )  # fmt: skip
    return ev, sub


def mid_hip_positions(
    session_dir: Path, source: str, series: AthleteSeries
) -> tuple[np.ndarray, np.ndarray] | None:
    """(frames, persons, 2) mid-hip xy (m) and (frames, persons) validity on ``series``'
    frames and persons, from the analysed 3D result; None when it is missing or lacks hips."""
    from pipeline.artifacts import ArtifactStore
    from pipeline.schema.keypoints3d import Keypoints3D
    from pipeline.schema.sources import RESULT_ARTIFACTS

    if source not in RESULT_ARTIFACTS:
        return None
    stage, art = RESULT_ARTIFACTS[source]
    store = ArtifactStore(session_dir)
    if not store.has(stage, f"{art}.npz"):
        return None
    kp = store.load(stage, art, Keypoints3D)
    if "left_hip" not in kp.joint_names or "right_hip" not in kp.joint_names:
        return None
    jl, jr = kp.joint_names.index("left_hip"), kp.joint_names.index("right_hip")
    f, p = series.n_frames, series.person_ids.shape[0]
    xy, ok = np.zeros((f, p, 2)), np.zeros((f, p), dtype=bool)
    rows = np.searchsorted(kp.frame_indices, series.frame_indices)
    rows_c = np.minimum(rows, max(kp.n_frames - 1, 0))
    same = (
        (rows < kp.n_frames) & (kp.frame_indices[rows_c] == series.frame_indices) if kp.n_frames else rows < 0
    )
    for i, pid in enumerate(series.person_ids.tolist()):
        if pid not in kp.person_ids.tolist():
            continue
        k = kp.person_index(pid)
        both = kp.valid[rows_c, k, jl] & kp.valid[rows_c, k, jr] & same
        xy[:, i] = np.where(
            both[:, None], 0.5 * (kp.xyz_m[rows_c, k, jl, :2] + kp.xyz_m[rows_c, k, jr, :2]), 0.0
        )
        ok[:, i] = both
    return xy, ok


def load_report_data(session_dir: Path, names: dict[int, str] | None = None, colors: dict[int, str] | None = None,
                     date: str = "") -> ReportData:  # fmt: skip
    """The report's data of a session folder: the analyze stage's artifacts, the analysed
    result's mid-hip positions and the names in ``session.json`` (``names`` overrides them).

    Raises ``LookupError`` when the analyze stage has not run, ``ValueError`` on a malformed
    ``session.json`` or artifact."""
    from pipeline.artifacts import ArtifactStore
    from pipeline.io.events_export import ANALYZE_STAGE, load_analytics
    from pipeline.schema import SessionConfig

    session_dir = Path(session_dir)
    cfg = SessionConfig.load(session_dir)
    events, series, source = load_analytics(session_dir)
    m = ArtifactStore(session_dir).manifest(ANALYZE_STAGE)
    pos = mid_hip_positions(session_dir, source, series)
    return ReportData(
        title=cfg.name or session_dir.name, events=events, series=series, source=source,
        names={**dict(enumerate(cfg.athletes)), **(names or {})}, colors=dict(colors or {}), date=date,
        analysed_unix_s=float(m.created_unix_s) if m is not None else 0.0,
        positions_xy_m=pos[0] if pos else None, positions_valid=pos[1] if pos else None,
        ring_xy_m=np.array(cfg.ring_xy_m) if cfg.ring_xy_m else None, rounds_s=cfg.rounds_s,
    )  # fmt: skip
