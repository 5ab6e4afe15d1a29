"""Camera rig around the ring: cameras on a circle, looking at the ring centre."""

from __future__ import annotations

import numpy as np

from pipeline.geometry.rotations import look_at_T_world_cam
from pipeline.schema.camera import CameraRig

LOOK_AT_M = np.array([0.0, 0.0, 0.9])
"""Point every camera looks at (ring centre, roughly hip height)."""


def make_rig(
    n_cameras: int,
    image_size_wh: tuple[int, int],
    fps: float,
    distortion: bool,
    rng: np.random.Generator,
    step_deg: float | None = None,
) -> CameraRig:
    """``n_cameras`` on a circle of radius 6-7 m, 1.8-3.0 m high, ``step_deg`` apart around it
    (None: evenly spread), each with ±7 deg of jitter; fx = 0.8-1.0 x width, principal point
    near the image centre. With ``distortion`` each camera gets k1 in [-0.25, -0.1], a small k2
    and a tiny tangential term. ``step_deg`` changes no random draw."""
    w, h = image_size_wh
    phase = rng.uniform(-np.pi, np.pi)
    steps = 2 * np.pi * np.arange(n_cameras) / n_cameras if step_deg is None else np.deg2rad(step_deg) * np.arange(n_cameras)
    angles = phase + steps + rng.uniform(-0.12, 0.12, n_cameras)
    radius = rng.uniform(6.0, 7.0, n_cameras)
    height = rng.uniform(1.8, 3.0, n_cameras)
    fx = rng.uniform(0.8, 1.0, n_cameras) * w
    Ks, dists, Ts = [], [], []
    for i in range(n_cameras):
        eye = np.array([radius[i] * np.cos(angles[i]), radius[i] * np.sin(angles[i]), height[i]])
        Ts.append(look_at_T_world_cam(eye, LOOK_AT_M))
        K = np.array(
            [
                [fx[i], 0.0, w / 2 - 0.5 + rng.uniform(-8, 8)],
                [0.0, fx[i] * rng.uniform(0.998, 1.002), h / 2 - 0.5 + rng.uniform(-8, 8)],
                [0.0, 0.0, 1.0],
            ]
        )
        Ks.append(K)
        d = np.zeros(5)
        if distortion:
            d[0] = rng.uniform(-0.25, -0.1)
            d[1] = rng.uniform(0.0, 0.08)
            d[2:4] = rng.uniform(-5e-4, 5e-4, 2)
        dists.append(d)
    return CameraRig(
        names=tuple(f"cam{i + 1:02d}" for i in range(n_cameras)),
        K=np.stack(Ks),
        dist=np.stack(dists),
        T_world_cam=np.stack(Ts),
        image_size_wh=np.tile(np.array([w, h], dtype=np.int64), (n_cameras, 1)),
        fps=float(fps),
    )
