"""Hand-made boxers for the analytics tests: two athletes in guard facing each other along x,
and fist trajectories (min-jerk out, hold, back) written into their joints."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pipeline.schema import COCO17_FEET, Keypoints3D

J = {n: i for i, n in enumerate(COCO17_FEET)}
FPS = 50.0

# Orthodox guard, facing +x, stance centre at the origin (metres).
GUARD_POSE: dict[str, tuple[float, float, float]] = {
    "nose": (0.09, 0.0, 1.6), "left_eye": (0.07, 0.03, 1.64), "right_eye": (0.07, -0.03, 1.64),
    "left_ear": (0.0, 0.075, 1.62), "right_ear": (0.0, -0.075, 1.62),
    "left_shoulder": (0.0, 0.18, 1.45), "right_shoulder": (0.0, -0.18, 1.45),
    "left_elbow": (0.12, 0.24, 1.2), "right_elbow": (0.05, -0.24, 1.2),
    "left_wrist": (0.3, 0.12, 1.45), "right_wrist": (0.2, -0.1, 1.48),
    "left_hip": (0.0, 0.1, 0.95), "right_hip": (0.0, -0.1, 0.95),
    "left_knee": (0.12, 0.12, 0.5), "right_knee": (-0.12, -0.12, 0.5),
    "left_ankle": (0.22, 0.13, 0.08), "right_ankle": (-0.22, -0.15, 0.08),
    "left_big_toe": (0.35, 0.1, 0.02), "left_small_toe": (0.32, 0.16, 0.02), "left_heel": (0.18, 0.13, 0.02),
    "right_big_toe": (-0.1, -0.12, 0.02), "right_small_toe": (-0.12, -0.18, 0.02), "right_heel": (-0.26, -0.15, 0.02),
}  # fmt: skip


def minjerk(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x**3 * (10 - 15 * x + 6 * x * x)


def profile(n_frames: int, t0_s: float, out_s: float, hold_s: float = 0.04, back_s: float = 0.16) -> np.ndarray:
    """(frames,) 0 -> 1 -> 0: the punch's extension over time."""
    t = np.arange(n_frames) / FPS
    return minjerk((t - t0_s) / out_s) - minjerk((t - t0_s - out_s - hold_s) / back_s)


def pose(southpaw: bool = False) -> np.ndarray:
    """(23, 3) the guard pose (mirrored left/right for a southpaw)."""
    out = np.zeros((len(COCO17_FEET), 3))
    for name, p in GUARD_POSE.items():
        out[J[name]] = p
    if southpaw:
        out[:, 1] *= -1
        swapped = out.copy()
        for name in COCO17_FEET:
            if name.startswith("left_"):
                a, b = J[name], J["right_" + name[5:]]
                swapped[a], swapped[b] = out[b], out[a]
        out = swapped
    return out


def two_boxers(n_frames: int = 100, distance_m: float = 1.0, southpaw: tuple[bool, bool] = (False, False)) -> np.ndarray:
    """(frames, 2, 23, 3): athlete 0 at the origin facing +x, athlete 1 at x = distance facing -x."""
    a = pose(southpaw[0])
    b = pose(southpaw[1]) * np.array([-1.0, -1.0, 1.0]) + np.array([distance_m, 0.0, 0.0])
    return np.tile(np.stack([a, b])[None], (n_frames, 1, 1, 1))


def throw(xyz: np.ndarray, person: int, hand: str, prof: np.ndarray, path: Callable[[np.ndarray], np.ndarray]) -> None:
    """Move ``person``'s ``hand`` wrist along ``path(prof)`` (frames, 3) in place; the elbow
    follows halfway between shoulder and wrist, a little lower (the arm's length changes a
    few cm: the analytics take its median)."""
    w = path(prof)
    s = xyz[:, person, J[f"{hand}_shoulder"]]
    xyz[:, person, J[f"{hand}_wrist"]] = w
    xyz[:, person, J[f"{hand}_elbow"]] = 0.5 * (s + w) + np.array([0.0, 0.0, -0.08])


def straight(start: np.ndarray, end: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    return lambda p: start + p[:, None] * (end - start)


def bezier(c0: np.ndarray, c1: np.ndarray, c2: np.ndarray, c3: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    def f(p: np.ndarray) -> np.ndarray:
        u = p[:, None]
        return (1 - u) ** 3 * c0 + 3 * (1 - u) ** 2 * u * c1 + 3 * (1 - u) * u**2 * c2 + u**3 * c3

    return f


def keypoints(xyz: np.ndarray, source: str = "fit") -> Keypoints3D:
    f, p, j = xyz.shape[:3]
    return Keypoints3D(
        joint_names=COCO17_FEET, person_ids=np.arange(p), frame_indices=np.arange(f), fps=FPS, xyz_m=xyz,
        valid=np.ones((f, p, j), dtype=bool), confidence=np.ones((f, p, j)), n_views=np.full((f, p, j), 4),
        reproj_err_px=np.zeros((f, p, j)), source=source,
    )  # fmt: skip
