"""What the bout report shows: the analyze stage's events and series, the athletes' ring
positions and the session's names, gathered once (``load_report_data``) so that the
rendering (``pipeline.report.html.render_report``) is a pure function of this data.

Also the bout's periods (rounds, or fixed spans when the rounds are not known; sliced by
``pipeline.stages.analyze.periods``), each summarised by ``pipeline.stages.analyze.athlete_summary``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipeline.schema.analytics import AthleteSeries, BoutEvents
from pipeline.stages.analyze.periods import Period, bout_periods, slice_bout

if TYPE_CHECKING:
    from pipeline.schema import SessionConfig

__all__ = ["ATHLETE_COLORS", "Period", "ReportData", "ReportOptions", "load_report_data", "mid_hip_positions", "periods", "slice_bout"]

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
        layout_advice: why the session's cameras see depth poorly, so that punches can be
            missed (``pipeline.geometry.layout``); "" when two cameras are 45-135 deg apart or
            the calibration cannot be read.
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
    layout_advice: str = ""

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


def periods(data: ReportData, options: ReportOptions) -> tuple[list[Period], str]:
    """The summary's periods (``pipeline.stages.analyze.periods.bout_periods``) and a sentence
    saying where they come from."""
    spans, kind = bout_periods(data.duration_s, data.rounds_s, options.period_s)
    if kind == "rounds":
        return spans, "Rounds from the session's round times."
    return spans, (
        f"The session gives no round times: the bout is split into {options.period_s:g} s periods"
        + (" (one period: the bout is shorter)." if len(spans) == 1 else ".")
    )


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
        layout_advice=_layout_advice(session_dir, cfg),
    )  # fmt: skip


def _layout_advice(session_dir: Path, cfg: SessionConfig) -> str:
    """``pipeline.geometry.layout.layout_advice`` of the session's cameras; "" when there is none
    or the calibration cannot be read (the report is about the analysis, which exists)."""
    from pipeline.geometry.layout import layout_advice
    from pipeline.io.session_rig import session_rig

    try:
        return layout_advice(session_rig(session_dir, cfg)) or ""
    except (ValueError, OSError, KeyError, TypeError):
        return ""
