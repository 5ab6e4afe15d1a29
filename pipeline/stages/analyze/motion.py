"""Punches the body fit flattened, recovered from the filtered triangulation.

With few views the fit's smoothness and pose priors can nearly erase a punch (its wrist
moves a few centimetres where the fist travelled 0.3 m), while the filtered triangulation
keeps it. Per athlete and hand, the excursions of the filtered track's fist are candidates
(``punches.candidates`` on the filtered body); one is a punch the fit flattened when:

- ``rules``: it passes every rule of ``punches.RULES`` on the filtered track;
- ``new``: no excursion of the fit's fist overlapping it is a punch, or was rejected for
  its form (``FORM_RULES``: the fit saw that motion and judged it); the fit's rejections for
  a lack of motion (too slow, too long, too small to be a candidate) are what flattening causes;
- ``whole``: its way out lasts at least ``PunchConfig.flattened_min_out_s`` (a filter or
  triangulation spike jumps out in a frame or two), and its way out and back both lie inside
  the clip (an excursion cut by the clip's first or last frame is the filter starting up or
  running out);
- ``flattened``: over the excursion, the fit's wrist path is at most
  ``PunchConfig.flattened_max_ratio`` of the filtered wrist's (the two disagree because the
  fit moved less);
- ``measured``: the raw triangulation covers its way out (``punches.raw_peak_speed``: 60 %
  of the frames) and its peak speed there reaches ``PunchConfig.flattened_min_raw_speed_mps``.
  Where the wrist is seen by one view only the filter extrapolates, and a spike or drift of
  the filtered track has no two-view measurement behind it.

The decision is per excursion, from what the session has (fit, filtered and raw tracks),
never from the camera count: with enough views the fit keeps the punches and nothing is
added.
"""

from __future__ import annotations

import numpy as np

from pipeline.stages.analyze.body import Body
from pipeline.stages.analyze.config import PunchConfig
from pipeline.stages.analyze.punches import (
    Candidate,
    Detection,
    HandTrack,
    candidates,
    overlaps,
    raw_peak_speed,
    rule_failed,
)

MOTION_RULES: tuple[str, ...] = ("rules", "new", "whole", "flattened", "measured")
"""The checks a filtered-track excursion passes to count as a flattened punch (module docstring)."""
FORM_RULES: tuple[str, ...] = ("clinch", "guard_start", "elbow_extends", "extension", "forward")
"""Rules of ``punches.RULES`` about a punch's form: the fit's verdict on them stands."""


def path_length_m(xyz: np.ndarray, ok: np.ndarray, a: int, b: int) -> float:
    """Length (m) of the polyline ``xyz[a..b]`` (frames, 3) over consecutive valid rows."""
    step = np.linalg.norm(np.diff(xyz[a : b + 1], axis=0), axis=1)
    good = ok[a:b] & ok[a + 1 : b + 1]
    return float(step[good].sum())


def motion_failed(
    c: Candidate,
    fit_h: HandTrack,
    motion_h: HandTrack,
    fit_candidates: list[Candidate],
    raw: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    cfg: PunchConfig,
    fps: float,
) -> str | None:
    """The first check of ``MOTION_RULES`` that the filtered-track candidate ``c`` fails, None
    for a punch the fit flattened. ``fit_candidates``: the candidates of the same fist on the
    fit (``punches.candidates``); ``raw``: the raw wrist (frames, 3), validity and view counts
    on the same rows (None: no raw triangulation, ``measured`` fails)."""
    if rule_failed(c, cfg, fps) is not None:
        return "rules"
    for f in fit_candidates:
        if overlaps(c.start, c.end, f.start, f.end) and rule_failed(f, cfg, fps) in (None, *FORM_RULES):
            return "new"
    n = motion_h.wrist.shape[0]
    if c.start <= 0 or c.end >= n - 1 or c.end <= c.peak or c.peak - c.start < cfg.flattened_min_out_s * fps:
        return "whole"
    moved = path_length_m(motion_h.wrist, motion_h.ok, c.start, c.end)
    if not path_length_m(fit_h.wrist, fit_h.ok, c.start, c.end) <= cfg.flattened_max_ratio * moved:
        return "flattened"
    speed = None if raw is None else raw_peak_speed(*raw, c.start, c.peak, fps)
    if speed is None or speed < cfg.flattened_min_raw_speed_mps:
        return "measured"
    return None


def flattened_punches(
    motion_body: Body,
    motion_h: HandTrack,
    fit_body: Body,
    fit_h: HandTrack,
    raw: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    cfg: PunchConfig,
    clinch: np.ndarray | None = None,
) -> list[Detection]:
    """The punches of one fist found on the filtered track ``motion_h`` that the fit
    (``fit_body``, its track ``fit_h``) flattened, in time order (module docstring). Both
    tracks index the same analysed frames."""
    fit_candidates = candidates(fit_body, fit_h, cfg, clinch)
    out: list[Detection] = []
    for c in candidates(motion_body, motion_h, cfg, clinch):
        if motion_failed(c, fit_h, motion_h, fit_candidates, raw, cfg, motion_body.fps) is not None:
            continue
        if out and overlaps(c.start, c.end, out[-1].start, out[-1].end):  # one excursion, two bumps: keep the first
            continue
        score = np.clip((c.excursion_m - cfg.min_excursion_m) / cfg.min_excursion_m + 0.5, 0.0, 1.0)
        score *= np.clip((c.peak_speed_mps - cfg.min_peak_speed_mps) / cfg.min_peak_speed_mps + 0.5, 0.0, 1.0)
        # Lower confidence than a punch the fit itself shows: one track of two saw it.
        out.append(Detection(c.hand, c.start, c.peak, c.end, c.fastest, c.excursion_m, c.out_speed_mps,
                             c.peak_speed_mps, c.extension, float(0.5 * score)))  # fmt: skip
    return out
