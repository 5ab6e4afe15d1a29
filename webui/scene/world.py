"""Static part of the scene: ground, ring and the calibrated cameras (``/world/cams/{cam}``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import viser
import viser.transforms as vtf

from pipeline.schema.camera import CameraRig

RING_HALF_M = 3.05
"""Half the side of a standard boxing ring inside the ropes (6.1 m)."""
ROPE_HEIGHTS_M = (0.45, 0.85, 1.25)


@dataclass
class WorldHandles:
    ground: viser.GridHandle
    ring: viser.LineSegmentsHandle
    cams: dict[str, viser.CameraFrustumHandle]


def camera_pose(rig: CameraRig, view: int) -> tuple[np.ndarray, np.ndarray]:
    """(wxyz, position) of camera ``view`` in the world (OpenCV camera frame, as viser expects)."""
    T = rig.T_world_cam[view]
    return vtf.SO3.from_matrix(T[:3, :3]).wxyz, T[:3, 3].copy()


def vertical_fov_rad(rig: CameraRig, view: int) -> float:
    h = float(rig.image_size_wh[view, 1])
    return float(2.0 * np.arctan2(h / 2.0, rig.K[view, 1, 1]))


def ring_segments(half_m: float = RING_HALF_M) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2, 3) rope and post segments of the ring and their (N, 2, 3) uint8 colours.

    Corner posts: red corner at (-x, -y), blue corner at (+x, +y) (dark shades), neutral corners white.
    """
    c = np.array([[-half_m, -half_m], [half_m, -half_m], [half_m, half_m], [-half_m, half_m]])
    segs, cols = [], []
    rope = (235, 235, 235)
    for z in ROPE_HEIGHTS_M:
        for i in range(4):
            a, b = c[i], c[(i + 1) % 4]
            segs.append([[a[0], a[1], z], [b[0], b[1], z]])
            cols.append([rope, rope])
    # Darker than the identity colours, so the athletes stay the only pure red and blue.
    post_cols = [(140, 20, 20), (235, 235, 235), (15, 50, 110), (235, 235, 235)]
    for i in range(4):
        segs.append([[c[i, 0], c[i, 1], 0.0], [c[i, 0], c[i, 1], ROPE_HEIGHTS_M[-1] + 0.1]])
        cols.append([post_cols[i], post_cols[i]])
    return np.asarray(segs, dtype=np.float32), np.asarray(cols, dtype=np.uint8)


def add_world(server: viser.ViserServer, rig: CameraRig) -> WorldHandles:
    """Ground grid, ring ropes/posts and one frustum per camera at its calibrated pose."""
    ground = server.scene.add_grid(
        "/world/ground", width=12.0, height=12.0, plane="xy", cell_size=0.5, section_size=1.0, plane_opacity=0.0
    )
    segs, cols = ring_segments()
    ring = server.scene.add_line_segments("/world/ring", segs, cols, thickness=0.025)
    cams: dict[str, viser.CameraFrustumHandle] = {}
    for v, name in enumerate(rig.names):
        wxyz, pos = camera_pose(rig, v)
        w, h = (float(x) for x in rig.image_size_wh[v])
        cams[name] = server.scene.add_camera_frustum(
            f"/world/cams/{name}",
            fov=vertical_fov_rad(rig, v),
            aspect=w / h,
            scale=0.35,
            color=(40, 40, 40),
            wxyz=wxyz,
            position=pos,
        )
        server.scene.add_label(f"/world/cams/{name}/label", name, position=(0.0, 0.0, 0.0))
    return WorldHandles(ground, ring, cams)


def align_client_camera(client: viser.ClientHandle, rig: CameraRig, view: int) -> None:
    """Put the browser's 3D camera at camera ``view``'s calibrated pose and field of view."""
    wxyz, pos = camera_pose(rig, view)
    R = vtf.SO3(wxyz).as_matrix()
    with client.atomic():
        client.camera.fov = vertical_fov_rad(rig, view)
        client.camera.position = pos
        client.camera.look_at = pos + R[:, 2] * 5.0
        client.camera.up_direction = -R[:, 1]
