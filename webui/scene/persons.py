"""Per-person scene nodes, updated per frame.

Paths: ``/world/persons/{pid}/skeleton`` (bones) and ``/joints``, ``/body`` (fit mesh),
``/physics`` (physics geoms). The node set is fixed when a session is (re)loaded; a
frame change only streams new positions/vertices, batched in one ``server.atomic()``.
"""

from __future__ import annotations

from dataclasses import astuple, dataclass, field
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


DIM_RGB: tuple[int, int, int] = (150, 150, 150)
"""Colour of a layer that is out of date (``webui.staleness``): grey, whoever it shows."""
DIM_OPACITY = 0.25
"""Opacity of an out-of-date mesh (fresh: ``BODY_OPACITY`` / ``PHYSICS_OPACITY``)."""
BODY_OPACITY = 0.85
PHYSICS_OPACITY = 0.6


@dataclass
class PersonNodes:
    person_id: int
    skeleton: viser.LineSegmentsHandle
    joints: viser.PointCloudHandle
    body: viser.MeshHandle | None = None
    physics: viser.MeshHandle | None = None
    dimmed: dict[str, bool] = field(default_factory=dict)
    """Part (skeleton / body / physics) -> drawn dimmed now (only changes are sent)."""


@dataclass
class DisplayOptions:
    source: str = "filtered"
    show_skeleton: bool = True
    show_body: bool = True
    show_physics: bool = True
    dim_skeleton: bool = False
    """The skeleton's source is out of date: grey."""
    dim_body: bool = False
    """The fit is out of date: body meshes grey and faint."""
    dim_physics: bool = False
    """The physics result is out of date: its geoms grey and faint."""


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
    shown: tuple | None = None
    """What the nodes show now (frame, options, meshes posed so far); ``update`` sends nothing
    when asked for the same again. None after ``build``."""

    def build(self) -> None:
        """(Re)create the nodes of every person (call after a reload)."""
        self.remove()
        self.shown = None
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

    def skeleton_rgb(self, pid: int, dim: bool) -> tuple[int, int, int]:
        return DIM_RGB if dim else self.palette.rgb(pid)

    def body_rgb(self, pid: int, dim: bool) -> tuple[int, int, int]:
        return DIM_RGB if dim else self.palette.rgb(pid)

    def physics_rgb(self, pid: int, dim: bool) -> tuple[int, int, int]:
        if dim:
            return DIM_RGB
        r, g, b = (int(0.6 * c + 0.4 * 255) for c in self.palette.rgb(pid))
        return r, g, b

    def _set_skeleton_colour(self, n: PersonNodes, dim: bool) -> None:
        rgb = np.array(self.skeleton_rgb(n.person_id, dim), dtype=np.uint8)
        n.skeleton.colors = np.broadcast_to(rgb, n.skeleton.points.shape).copy()
        n.joints.colors = np.broadcast_to(rgb, n.joints.points.shape).copy()
        n.dimmed["skeleton"] = dim

    def _set_mesh_look(self, n: PersonNodes, part: str, dim: bool) -> None:
        mesh = n.body if part == "body" else n.physics
        if mesh is None:
            return
        if part == "body":
            mesh.color, mesh.opacity = self.body_rgb(n.person_id, dim), DIM_OPACITY if dim else BODY_OPACITY
        else:
            mesh.color, mesh.opacity = self.physics_rgb(n.person_id, dim), DIM_OPACITY if dim else PHYSICS_OPACITY
        n.dimmed[part] = dim

    def recolor(self) -> None:
        """Apply the palette's (new) colours to every node, keeping dimmed parts grey."""
        with self.server.atomic():
            for n in self.nodes.values():
                self._set_skeleton_colour(n, n.dimmed.get("skeleton", False))
                for part in ("body", "physics"):
                    self._set_mesh_look(n, part, n.dimmed.get(part, False))

    def remove(self) -> None:
        for n in self.nodes.values():
            for h in (n.skeleton, n.joints, n.body, n.physics):
                if h is not None:
                    h.remove()
        self.nodes.clear()

    def _update_body(self, n: PersonNodes, frame: int, show: bool, dim: bool = False) -> None:
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
                f"/world/persons/{n.person_id}/body", verts, self.body_cache.faces, color=self.body_rgb(n.person_id, dim),
                opacity=DIM_OPACITY if dim else BODY_OPACITY,
            )
            n.dimmed["body"] = dim
        else:
            n.body.vertices = verts
            n.body.visible = True
            if n.dimmed.get("body", False) != dim:
                self._set_mesh_look(n, "body", dim)

    def _update_physics(self, n: PersonNodes, frame: int, show: bool, dim: bool = False) -> None:
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
            n.physics = self.server.scene.add_mesh_simple(
                f"/world/persons/{n.person_id}/physics", verts, faces, color=self.physics_rgb(n.person_id, dim),
                opacity=DIM_OPACITY if dim else PHYSICS_OPACITY, flat_shading=True,
            )
            n.dimmed["physics"] = dim
        else:
            n.physics.vertices = verts
            n.physics.visible = True
            if n.dimmed.get("physics", False) != dim:
                self._set_mesh_look(n, "physics", dim)

    def update(self, frame: int, opts: DisplayOptions) -> None:
        """Show every person at ``frame`` (one atomic scene update; nothing is sent when the
        frame, the options and the posed meshes are those shown already)."""
        posed = self.body_cache.progress if self.body_cache is not None else None
        key = (frame, astuple(opts), posed)  # new data, meshes or geoms come with ``build``
        if key == self.shown:
            return
        self.shown = key
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
                if n.dimmed.get("skeleton", False) != opts.dim_skeleton:
                    self._set_skeleton_colour(n, opts.dim_skeleton)
                self._update_body(n, frame, opts.show_body, opts.dim_body)
                self._update_physics(n, frame, opts.show_physics, opts.dim_physics)


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
