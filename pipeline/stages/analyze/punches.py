"""Punch detection: a fist's excursion away from its guard position, relative to the neck.

Per athlete and hand, in the athlete's facing frame (``body.facing_frames``), the wrist
relative to the neck is ``r(t)``. The guard position ``g(t)`` is the running median of
``r`` over the frames where the fist is nearly still (``rest_speed_mps``), and the
excursion ``D(t) = |r - g|``. Every peak of ``D`` at least ``min_excursion_m`` high is a
``Candidate``: it starts and ends where ``D`` drops below ``edge_frac`` of its peak, and
its strike is the first frame after the fastest one on the way out where the fist has
slowed to ``arrive_frac`` of that speed (it has arrived at full extension or on the
target; also for a hook, whose excursion can be largest mid-arc). Two peaks of one excursion
(the fist set off again before it was back at the guard: a double jab, a body shot then a
hook) are two candidates split at the smallest excursion between them (``split_at_valleys``).

A candidate is a punch when it passes every rule of ``RULES`` (thresholds in
``PunchConfig``), the checks a coach makes by eye:

- ``excursion``: the fist goes ``min_excursion_m`` from its guard (``fast_min_excursion_m``
  when its measured speed is fast, below);
- ``duration``: out and back within ``max_duration_s`` (a hand held out is no punch);
- ``out_speed``: the way out reaches ``min_speed_mps`` relative to the neck;
- ``clinch``: the strike is not within ``clinch_margin_s`` of a grip (the stage passes the
  clinch frames and those where the bodies are close with a hand of each at the other's
  torso: hands taking, holding or leaving a grip; ``defence.clinch_frames``);
- ``guard_start``: the fist starts from the guard, no lower than ``max_start_drop`` arm
  lengths below the neck (an arm swinging up from the hip is not thrown from the guard);
- ``elbow_extends``: the elbow opens from the start to the strike by ``min_elbow_open_deg``
  (a punch drives the fist out by extending the arm; raising a hanging arm bends it);
- ``extension``: shoulder-to-wrist at the strike at least ``min_extension`` arm lengths;
- ``forward``: the fist ends ``min_forward_m`` farther towards the opponent than it started
  (blocks, parries, catches and hands leaving a clinch grip do not go at him);
- ``peak_speed``: the world-frame glove speed over the punch reaches ``min_peak_speed_mps``
  (feints and guard adjustments are slower);
- ``measured_speed``: where the raw triangulation saw the wrist in every frame of the way out,
  the peak speed it measures there (``Candidate.measured_mps``) reaches
  ``min_measured_speed_mps``: the smoothed analysed track slows a punch and a feint alike, the
  raw one tells them apart (where it bridged a gap it reads low, and does not reject).

A measured speed of at least ``fast_measured_mps`` passes ``out_speed`` and ``peak_speed`` and
lowers the ``excursion`` threshold to ``fast_min_excursion_m``: a fit from two views can slow a
punch to a third of its speed and shorten it, and a fist held out at the target pulls the guard
estimate towards it; the raw triangulation's speed still tells a punch from a feint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.signal import find_peaks

from pipeline.stages.analyze.body import Body, fill_gaps, to_local
from pipeline.stages.analyze.config import PunchConfig

RULES: tuple[str, ...] = (
    "excursion", "duration", "out_speed", "clinch", "guard_start", "elbow_extends", "extension", "forward", "peak_speed",
    "measured_speed",
)  # fmt: skip
"""The punch rules, in the order they are checked (module docstring; ``rule_failed``)."""


@dataclass(frozen=True)
class HandTrack:
    """Signals of one fist (frames = the analysed frames).

    Fields: r (frames, 3) wrist - neck in the facing frame, metres; ok (frames,) bool;
    speed_rel (frames,) |dr/dt| (central differences), m/s; excursion (frames,) distance
    from the guard position, m (0 where not ok); wrist (frames, 3) world wrist; arm_m the
    arm's length (median shoulder-elbow + elbow-wrist), metres; elbow_deg (frames,) the
    elbow's angle between upper arm and forearm, degrees in [0, 180] (180 = straight arm),
    with elbow_ok (frames,) where shoulder, elbow and wrist are all estimated.
    """

    hand: str
    r: np.ndarray
    ok: np.ndarray
    speed_rel: np.ndarray
    excursion: np.ndarray
    wrist: np.ndarray
    arm_m: float
    elbow_deg: np.ndarray
    elbow_ok: np.ndarray


@dataclass(frozen=True)
class Candidate:
    """One excursion of a fist and what the punch rules measure on it (rows index the
    analysed frames).

    Fields: start / peak (strike) / end / fastest (largest speed relative to the neck on
    the way out) / top (largest excursion) rows; excursion_m at the top, m; out_speed_mps
    at ``fastest``, relative to the neck, m/s; peak_speed_mps the largest world-frame
    frame-to-frame wrist speed over start .. end, m/s; extension shoulder-to-wrist at the
    strike over the arm's length (NaN without one); forward_m the fist's advance towards
    the opponent from start to strike, m; start_drop the fist's height below the neck at the
    start over the arm's length (positive = below; NaN without an arm length);
    elbow_open_deg the elbow angle at the strike minus at the start, degrees (NaN where
    the elbow is not estimated); near_clinch: the strike is within the clinch margin.
    """

    hand: str
    start: int
    peak: int
    end: int
    fastest: int
    top: int
    excursion_m: float
    out_speed_mps: float
    peak_speed_mps: float
    extension: float
    forward_m: float
    start_drop: float
    elbow_open_deg: float
    near_clinch: bool
    measured_mps: float = float("nan")
    """Peak glove speed on the raw triangulation over the way out (``raw_peak_speed``, along the
    analysed path), kept within ``PunchConfig.raw_speed_max_ratio`` of ``peak_speed_mps``, m/s;
    NaN where the raw triangulation does not measure it."""
    measured_whole: bool = False
    """The raw triangulation saw the wrist in every frame of the way out (start .. strike + 1):
    no gap bridged by a straight line, which lowers the peak, so a low ``measured_mps`` is low."""


@dataclass(frozen=True)
class Detection:
    """One detected punch (row indices into the analysed frames)."""

    hand: str
    start: int
    peak: int
    end: int
    fastest: int
    """Row of the largest speed (relative to the neck) on the way out."""
    excursion_m: float
    out_speed_mps: float
    peak_speed_mps: float
    extension: float
    confidence: float


def _central_speed(x: np.ndarray, ok: np.ndarray, fps: float) -> np.ndarray:
    v = np.zeros(x.shape[0])
    if x.shape[0] < 3:
        return v
    d = np.linalg.norm(x[2:] - x[:-2], axis=1) * fps / 2.0
    good = ok[2:] & ok[:-2] & ok[1:-1]
    v[1:-1] = np.where(good, d, 0.0)
    return v


def _running_median(r: np.ndarray, use: np.ndarray, half: int) -> np.ndarray:
    """(frames, 3) median of the rows of ``r`` where ``use``, over a centred window of
    2 * half + 1 frames; where a window holds none, the median over every usable row."""
    vals = np.where(use[:, None], r, np.nan)
    pad = np.concatenate([np.full((half, 3), np.nan), vals, np.full((half, 3), np.nan)])
    win = sliding_window_view(pad, 2 * half + 1, axis=0)  # (frames, 3, window)
    cnt = np.sum(np.isfinite(win[:, 0]), axis=1)
    out = np.zeros_like(r)
    have = cnt > 0
    if have.any():
        out[have] = np.nanmedian(win[have], axis=2)
    fallback = np.nanmedian(vals, axis=0) if use.any() else np.zeros(3)
    out[~have] = fallback
    return out


def elbow_angle_deg(shoulder: np.ndarray, elbow: np.ndarray, wrist: np.ndarray) -> np.ndarray:
    """(frames,) angle at the elbow between upper arm and forearm, degrees in [0, 180]
    (180 = straight); 0 where a segment has no length."""
    u, f = shoulder - elbow, wrist - elbow
    n = np.linalg.norm(u, axis=-1) * np.linalg.norm(f, axis=-1)
    c = np.sum(u * f, axis=-1) / np.maximum(n, 1e-12)
    return np.where(n > 1e-12, np.degrees(np.arccos(np.clip(c, -1.0, 1.0))), 0.0)


def hand_track(body: Body, R: np.ndarray, r_ok: np.ndarray, hand: str, cfg: PunchConfig) -> HandTrack:
    """The signals of ``body``'s ``hand`` fist in the facing frames ``R`` (valid ``r_ok``)."""
    w, wok = body.point(f"{hand}_wrist")
    e, eok = body.point(f"{hand}_elbow")
    s, sok = body.point(f"{hand}_shoulder")
    neck, nok = body.point("mid:left_shoulder+right_shoulder")
    ok = wok & nok & r_ok
    r = np.where(ok[:, None], to_local(R, w - neck), 0.0)
    speed = _central_speed(r, ok, body.fps)
    half = max(1, int(round(0.5 * cfg.guard_window_s * body.fps)))
    guard = _running_median(r, ok & (speed < cfg.rest_speed_mps), half)
    exc = np.where(ok, np.linalg.norm(r - guard, axis=1), 0.0)
    arm_ok = wok & eok & sok
    arm = np.linalg.norm(s - e, axis=1) + np.linalg.norm(e - w, axis=1)
    arm_m = float(np.median(arm[arm_ok])) if arm_ok.any() else float("nan")
    return HandTrack(hand, r, ok, speed, exc, w, arm_m, elbow_angle_deg(s, e, w), arm_ok)


def _edge(exc: np.ndarray, ok: np.ndarray, k: int, level: float, step: int) -> int:
    i = k
    while 0 <= i + step < exc.shape[0] and ok[i + step] and exc[i] > level:
        i += step
    return i


FIVE_POINT = np.array([1.0, -8.0, 0.0, 8.0, -1.0]) / 12.0
"""Five-point central derivative (Savitzky-Golay, cubic, 5 frames), applied as a correlation."""
SEVEN_POINT = np.array([22.0, -67.0, -58.0, 0.0, 58.0, 67.0, -22.0]) / 252.0
"""Seven-point cubic Savitzky-Golay derivative: less noise, a little more smoothing."""


def raw_peak_speed(
    raw_xyz: np.ndarray,
    raw_ok: np.ndarray,
    raw_views: np.ndarray,
    start: int,
    peak: int,
    fps: float,
    path_xyz: np.ndarray | None = None,
) -> float | None:
    """Largest speed (m/s) of a joint over rows ``start`` .. ``peak + 1`` from its raw
    positions (frames, 3), short gaps interpolated. None when under 60 % of the frames
    involved have a raw estimate.

    With ``path_xyz`` (frames, 3; the same joint on the analysed, smooth keypoints) the raw
    five-point derivative is projected on the analysed path's direction of motion at each
    frame: the smooth estimate knows where the fist goes, the raw one how fast. The noise
    across the path (two of its three components) then neither adds to the speed nor biases
    it upwards, and the short kernel keeps the ~0.1 s punch's peak. Without it, the five-point
    derivative's norm when the joint was mostly triangulated from three views or more
    (median), else the seven-point one's (a two-view DLT has no redundancy)."""
    n = raw_xyz.shape[0]
    lo, hi = max(0, start - 3), min(n, peak + 5)
    ok = raw_ok[lo:hi]
    if hi - lo < 7 or ok.mean() < 0.6 or ok.sum() < 2:
        return None
    x, _ = fill_gaps(raw_xyz[lo:hi], ok, hi - lo)
    good = np.flatnonzero(ok)
    x[: good[0]], x[good[-1] + 1 :] = x[good[0]], x[good[-1]]
    if path_xyz is not None:
        kernel = FIVE_POINT
        p = path_xyz[lo:hi]
        heading = np.zeros_like(p)
        heading[1:-1] = p[2:] - p[:-2]
        heading /= np.maximum(np.linalg.norm(heading, axis=1, keepdims=True), 1e-12)
    else:
        kernel = FIVE_POINT if float(np.median(raw_views[lo:hi][ok])) >= 3 else SEVEN_POINT
    half = kernel.size // 2
    speeds = []
    for t in range(max(half, start - lo), min(hi - lo - half, peak - lo + 2)):
        v = kernel @ x[t - half : t + half + 1] * fps
        speeds.append(float(v @ heading[t]) if path_xyz is not None else float(np.linalg.norm(v)))
    return max(speeds) if speeds else None


def _valleys(exc: np.ndarray, peaks: np.ndarray) -> np.ndarray:
    """(peaks - 1,) row of the smallest excursion between each two consecutive peaks: where the
    fist turned from coming back to going out again."""
    rows = [a + int(np.argmin(exc[a : b + 1])) for a, b in zip(peaks[:-1], peaks[1:], strict=True)]
    return np.array(rows, dtype=np.int64)


def overlaps(start: int, end: int, other_start: int, other_end: int) -> bool:
    """Two excursions (rows start .. end) share more than one frame; punches split at a valley
    (``PunchConfig.split_at_valleys``) share that frame only."""
    return start < other_end and other_start < end


def _near_clinch(clinch: np.ndarray | None, n: int, margin: int) -> np.ndarray:
    out = np.zeros(n, dtype=bool)
    if clinch is not None and clinch.any():
        for i in np.flatnonzero(clinch):
            out[max(0, i - margin) : i + margin + 1] = True
    return out


def candidates(
    body: Body,
    h: HandTrack,
    cfg: PunchConfig,
    clinch: np.ndarray | None = None,
    raw: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> list[Candidate]:
    """Every excursion peak of one fist at least ``min_excursion_m`` high, measured for the
    rules, in time order. ``clinch`` (frames,) bool marks clinch (or grip) frames; ``raw``: the
    fist's raw wrist (frames, 3), validity and view counts on the same rows, where its speed is
    measured (``Candidate.measured_mps``; with ``speed_source="raw"`` only), and then peaks down to
    ``fast_min_excursion_m`` are candidates too (the ``excursion`` rule judges them)."""
    exc, ok, v = h.excursion, h.ok, h.speed_rel
    n = exc.shape[0]
    if n < 5 or not ok.any():
        return []
    measure = raw is not None and cfg.speed_source == "raw"
    lowest = min(cfg.min_excursion_m, cfg.fast_min_excursion_m) if measure else cfg.min_excursion_m
    peaks, _ = find_peaks(exc, height=lowest, prominence=0.5 * cfg.min_excursion_m)
    max_out = max(2, int(round(cfg.max_out_s * body.fps)))
    near_clinch = _near_clinch(clinch, n, int(round(cfg.clinch_margin_s * body.fps)))
    shoulder, _ = body.point(f"{h.hand}_shoulder")
    has_arm = bool(np.isfinite(h.arm_m) and h.arm_m > 0)
    valleys = _valleys(exc, peaks) if cfg.split_at_valleys else np.zeros(0, dtype=np.int64)
    out: list[Candidate] = []
    for i, k0 in enumerate(peaks):
        level = cfg.edge_frac * exc[k0]
        a, b = _edge(exc, ok, k0, level, -1), _edge(exc, ok, k0, level, +1)
        a = max(a, k0 - max_out)
        if valleys.size:  # the fist set off again before it was back: the punch ends there
            a = max(a, int(valleys[i - 1]) if i > 0 else a)
            b = min(b, int(valleys[i]) if i < valleys.size else b)
        t_out = a + int(np.argmax(v[a : k0 + 1]))
        v_out = float(v[t_out])
        slow = np.flatnonzero(v[t_out + 1 : b + 1] < cfg.arrive_frac * v_out)
        k = t_out + 1 + int(slow[0]) if slow.size else int(k0)
        # The largest frame-to-frame displacement over the punch (out and back), as a
        # speed: the same estimator the synthetic ground truth uses.
        step = np.linalg.norm(np.diff(h.wrist[a : b + 1], axis=0), axis=1) * body.fps
        good = ok[a:b] & ok[a + 1 : b + 1]
        peak_speed = float(step[good].max()) if good.any() else v_out
        ext = float(np.linalg.norm(h.wrist[k] - shoulder[k]) / h.arm_m) if has_arm else float("nan")
        drop = float(-h.r[a, 2] / h.arm_m) if has_arm else float("nan")
        both = h.elbow_ok[k] and h.elbow_ok[a]
        opened = float(h.elbow_deg[k] - h.elbow_deg[a]) if both else float("nan")
        measured, whole = float("nan"), False
        if raw is not None and measure:
            m = raw_peak_speed(*raw, int(a), int(k), body.fps, h.wrist if cfg.speed_along_path else None)
            if m is not None:
                measured = float(np.clip(m, peak_speed, cfg.raw_speed_max_ratio * peak_speed))
                whole = bool(raw[1][a : k + 2].all())
        out.append(
            Candidate(h.hand, int(a), int(k), int(b), int(t_out), int(k0), float(exc[k0]), v_out, peak_speed, ext,
                      float(h.r[k, 0] - h.r[a, 0]), drop, opened, bool(near_clinch[k]), measured, whole)  # fmt: skip
        )
    return out


def rule_failed(c: Candidate, cfg: PunchConfig, fps: float) -> str | None:
    """The first rule of ``RULES`` that ``c`` fails, None for a punch. A measure that could
    not be taken (NaN: no arm length, elbow not estimated) fails its rule, except the elbow's
    and the measured speed's: without them the other rules decide. A measured speed of at least
    ``fast_measured_mps`` passes both speed rules on the analysed keypoints and needs an
    excursion of ``fast_min_excursion_m`` only."""
    fast = bool(c.measured_mps >= cfg.fast_measured_mps)
    checks = {
        "excursion": c.excursion_m >= (cfg.fast_min_excursion_m if fast else cfg.min_excursion_m),
        "duration": 2 <= c.end - c.start <= cfg.max_duration_s * fps,
        "out_speed": c.out_speed_mps >= cfg.min_speed_mps or fast,
        "clinch": not c.near_clinch,
        "guard_start": c.start_drop <= cfg.max_start_drop,
        "elbow_extends": not c.elbow_open_deg < cfg.min_elbow_open_deg,
        "extension": c.extension >= cfg.min_extension,
        "forward": c.forward_m >= cfg.min_forward_m,
        "peak_speed": c.peak_speed_mps >= cfg.min_peak_speed_mps or fast,
        "measured_speed": not (c.measured_whole and c.measured_mps < cfg.min_measured_speed_mps),
    }
    for name in RULES:
        if not checks[name]:
            return name
    return None


def detect(
    body: Body,
    h: HandTrack,
    cfg: PunchConfig,
    clinch: np.ndarray | None = None,
    raw: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> list[Detection]:
    """The punches of one fist, in time order: the candidates that pass every rule (see the
    module docstring). ``clinch`` (frames,) bool marks clinch frames; ``raw`` the fist's raw
    wrist track (``candidates``)."""
    idx = [body.names.index(f"{h.hand}_{j}") for j in ("wrist", "elbow", "shoulder") if f"{h.hand}_{j}" in body.names]
    out: list[Detection] = []
    for c in candidates(body, h, cfg, clinch, raw):
        if rule_failed(c, cfg, body.fps) is not None:
            continue
        score = np.clip((c.excursion_m - cfg.min_excursion_m) / cfg.min_excursion_m + 0.5, 0.0, 1.0)
        score *= np.clip((c.peak_speed_mps - cfg.min_peak_speed_mps) / cfg.min_peak_speed_mps + 0.5, 0.0, 1.0)
        kp_conf = float(body.confidence[c.start : c.end + 1][:, idx].mean()) if idx else 1.0
        det = Detection(c.hand, c.start, c.peak, c.end, c.fastest, c.excursion_m, c.out_speed_mps,
                        c.peak_speed_mps, c.extension, float(score * kp_conf))  # fmt: skip
        if out and overlaps(det.start, det.end, out[-1].start, out[-1].end):  # one excursion, two bumps: keep the larger
            if det.excursion_m > out[-1].excursion_m:
                out[-1] = det
            continue
        out.append(det)
    return out
