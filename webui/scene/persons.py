"""Per-person scene nodes, updated per frame.

Paths: ``/world/persons/{pid}/skeleton`` (bones) and ``/joints``, ``/body`` (fit mesh),
``/physics`` (physics geoms). The node set is fixed when a session is (re)loaded; a
frame change only streams new positions/vertices, batched in one ``server.atomic()``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import viser

from pipeline.schema.joints import bone_indices
from pipeline.schema.keypoints3d import Keypoints3D
from webui.colors import IdentityPalette
from webui.scene.body import BodyMeshCache
from webui.scene.session_data import SessionData, frame_row
from webui.scope import Scope


def skeleton_segments(kp: Keypoints3D, row: int | None, person_index: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """Bones of one person at one row: (bones, 2, 3) segments, (joints, 3) joints, any-valid.

    The arrays keep a fixed size (so the scene node is updated, not rebuilt): invalid bones
    collapse to a zero-length segment and invalid joints sit on a valid one.
    """
    bones = bone_indices(kp.joint_names)
    nj = len(kp.joint_names)
    if row is None:
        return np.zeros((len(bones), 2, 3), np.float32), np.zeros((nj, 3), np.float32), False
    xyz = kp.xyz_m[row, person_index]
    valid = kp.valid[row, person_index]
    if not valid.any():
        return np.zeros((len(bones), 2, 3), np.float32), np.zeros((nj, 3), np.float32), False
    anchor = xyz[valid].mean(axis=0)
    joints = np.where(valid[:, None], xyz, anchor)
    segs = np.zeros((len(bones), 2, 3))
    for k, (a, b) in enumerate(bones):
        if valid[a] and valid[b]:
            segs[k] = (xyz[a], xyz[b])
        else:
            segs[k] = (anchor, anchor)
    return segs.astype(np.float32), joints.astype(np.float32), True


@dataclass
class PersonNodes:
    person_id: int
    skeleton: viser.LineSegmentsHandle
    joints: viser.PointCloudHandle
    body: viser.MeshHandle | None = None
    physics: viser.MeshHandle | None = None


@dataclass
class DisplayOptions:
    source: str = "filtered"
    show_skeleton: bool = True
    show_body: bool = True
    show_physics: bool = True


@dataclass
class PersonsScene:
    """Scene nodes of every person of a loaded session."""

    server: Scope
    """The whole server (every client sees these nodes) or one client (its own nodes)."""
    data: SessionData
    palette: IdentityPalette
    body_cache: BodyMeshCache | None = None
    physics_geoms: Any = None
    nodes: dict[int, PersonNodes] = field(default_factory=dict)

    def build(self) -> None:
        """(Re)create the nodes of every person (call after a reload)."""
        self.remove()
        n_bones = max((len(bone_indices(kp.joint_names)) for kp in self.data.keypoints.values()), default=0)
        n_joints = max((len(kp.joint_names) for kp in self.data.keypoints.values()), default=1)
        for pid in self.data.person_ids:
            rgb = np.array(self.palette.rgb(pid), dtype=np.uint8)
            base = f"/world/persons/{pid}"
            seg_cols = np.broadcast_to(rgb, (max(n_bones, 1), 2, 3)).copy()
            sk = self.server.scene.add_line_segments(
                f"{base}/skeleton", np.zeros((max(n_bones, 1), 2, 3), np.float32), seg_cols, thickness=0.03
            )
            jt = self.server.scene.add_point_cloud(
                f"{base}/joints", np.zeros((n_joints, 3), np.float32), colors=(int(rgb[0]), int(rgb[1]), int(rgb[2])), point_size=0.035, point_shape="circle"
            )
            self.nodes[pid] = PersonNodes(pid, sk, jt)

    def remove(self) -> None:
        for n in self.nodes.values():
            for h in (n.skeleton, n.joints, n.body, n.physics):
                if h is not None:
                    h.remove()
        self.nodes.clear()

    def _update_body(self, n: PersonNodes, frame: int, show: bool) -> None:
        bf = self.data.bodyfit
        verts = None
        if show and bf is not None and self.body_cache is not None and self.body_cache.faces is not None:
            hit = np.flatnonzero(bf.person_ids == n.person_id)
            row = frame_row_of(bf.frame_indices, frame)
            if hit.size and row is not None and bool(bf.valid[row, hit[0]]):
                verts = self.body_cache.get(int(hit[0]), row)
        if verts is None:
            if n.body is not None:
                n.body.visible = False
            return
        if n.body is None:
            assert self.body_cache is not None and self.body_cache.faces is not None
            n.body = self.server.scene.add_mesh_simple(
                f"/world/persons/{n.person_id}/body", verts, self.body_cache.faces, color=self.palette.rgb(n.person_id), opacity=0.85
            )
        else:
            n.body.vertices = verts
            n.body.visible = True

    def _update_physics(self, n: PersonNodes, frame: int, show: bool) -> None:
        ph = self.data.physics
        mesh = None
        if show and ph is not None and self.physics_geoms is not None:
            row = frame_row_of(ph.frame_indices, frame)
            if row is not None:
                mesh = self.physics_geoms.person_mesh(n.person_id, row)
        if mesh is None:
            if n.physics is not None:
                n.physics.visible = False
            return
        verts, faces = mesh
        if n.physics is None:
            r, g, b = (int(0.6 * c + 0.4 * 255) for c in self.palette.rgb(n.person_id))
            col = (r, g, b)
            n.physics = self.server.scene.add_mesh_simple(
                f"/world/persons/{n.person_id}/physics", verts, faces, color=col, opacity=0.6, flat_shading=True
            )
        else:
            n.physics.vertices = verts
            n.physics.visible = True

    def update(self, frame: int, opts: DisplayOptions) -> None:
        """Show every person at ``frame`` (one atomic scene update)."""
        kp = self.data.keypoints.get(opts.source)
        row = frame_row(kp, frame) if kp is not None else None
        with self.server.atomic():
            for pid, n in self.nodes.items():
                ok = False
                if kp is not None and pid in kp.person_ids:
                    segs, joints, ok = skeleton_segments(kp, row, kp.person_index(pid))
                    if ok:
                        n.skeleton.points = _pad(segs, n.skeleton.points.shape[0], joints[0])
                        n.joints.points = _pad(joints, n.joints.points.shape[0], joints[0])
                n.skeleton.visible = ok and opts.show_skeleton
                n.joints.visible = ok and opts.show_skeleton
                self._update_body(n, frame, opts.show_body)
                self._update_physics(n, frame, opts.show_physics)


def frame_row_of(frame_indices: np.ndarray, frame: int) -> int | None:
    i = int(np.searchsorted(frame_indices, frame))
    if i < frame_indices.shape[0] and int(frame_indices[i]) == frame:
        return i
    return None


def _pad(arr: np.ndarray, n: int, fill: np.ndarray) -> np.ndarray:
    """Pad/trim ``arr`` to ``n`` rows (sources may use different joint sets); extra rows sit at ``fill``."""
    if arr.shape[0] >= n:
        return arr[:n]
    extra = np.broadcast_to(fill, (n - arr.shape[0],) + arr.shape[1:]).astype(arr.dtype)
    return np.concatenate([arr, extra])
