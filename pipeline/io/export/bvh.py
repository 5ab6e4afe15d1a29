"""BVH export of the body fit: one file per athlete, the fitted anny rig and its joint angles.

What a file holds:

* **Hierarchy**: the fit's bones (``BodyFit.bone_names``, anny's rig) with their parents. Each
  ``OFFSET`` is the bone's rest head minus its parent's head for the athlete's fitted shape
  (anny's A-pose, ``backends.anny.skeleton``); the root's ``OFFSET`` is ``0 0 0`` and its
  position channels carry its absolute position, so readers that add the offset to the
  position and readers that replace it agree. Leaf bones (feet, wrists, head) end in an
  ``End Site`` at the bone's tail (toe tip, fingertip, top of the head).
* **Motion**: the fit's own joint rotations (``BodyFit.pose``, not re-solved from keypoints)
  and root position (``BodyFit.root_translation_m``), one line per fitted frame;
  ``Frame Time`` = 1 / fps (times the frame step when the fit skips frames). Frames where the
  athlete was not fitted (``BodyFit.valid`` False) repeat the nearest fitted frame.
* **Channels**: root ``Xposition Yposition Zposition Zrotation Xrotation Yrotation``, other
  joints ``Zrotation Xrotation Yrotation``, in degrees. A joint's local rotation is
  ``Rz(z) @ Rx(x) @ Ry(y)`` (intrinsic Z, X, Y: the usual BVH reading, Blender's included), and
  a joint's world transform is its parent's times ``Translate(OFFSET) @ Rotation``.
* **Units and axes**: centimetres (import in Blender with *Scale* 0.01 to get metres), y-up:
  a world point ``(x, y, z)`` (cornerman's z-up world, metres) is written as
  ``100 * (x, z, -y)``. The rest pose faces +z (the subject's left on +x). Blender's importer
  (File > Import > Motion Capture (.bvh), default *Forward* -Z, *Up* Y) maps this back to
  cornerman's world axes exactly.

Only the anny body model has a rig here; ``--source physics`` (MuJoCo's humanoid) and the
keypoint sources are refused with a ``ValueError``: BVH comes from the fit.
"""

from __future__ import annotations

import re
import warnings
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.io.export.params import fit_for_export

if TYPE_CHECKING:
    from pipeline.backends.anny.skeleton import AnnySkeleton
    from pipeline.io.export.selection import ExportSelection

BVH_UNITS_PER_M = 100.0
"""BVH length unit: centimetres."""

C_BVH_WORLD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Rotation taking cornerman's z-up world axes to BVH's y-up ones: ``(x, y, z) -> (x, z, -y)``."""

EULER_ORDER = "ZXY"
"""Rotation channel order (intrinsic: ``R = Rz @ Rx @ Ry``)."""


def joint_name(name: str) -> str:
    """``name`` made safe for BVH readers (Blender's included): anything but letters, digits,
    ``_``, ``.`` and ``-`` (spaces, braces) becomes ``_``."""
    return re.sub(r"[^A-Za-z0-9_.\-]+", "_", name.strip()) or "joint"


def fill_invalid(valid: np.ndarray) -> np.ndarray:
    """(frames,) bool -> (frames,) index of the nearest valid frame (ties: the earlier one).

    ``ValueError`` when no frame is valid."""
    idx = np.flatnonzero(valid)
    if idx.size == 0:
        raise ValueError("no valid frame")
    f = np.arange(len(valid))
    pos = np.searchsorted(idx, f)  # first valid frame at or after f
    lo = idx[np.maximum(pos - 1, 0)]
    hi = idx[np.minimum(pos, idx.size - 1)]
    return np.where(np.abs(f - lo) <= np.abs(hi - f), lo, hi)


def _hierarchy(skel: AnnySkeleton) -> list[str]:
    off = skel.rest_offset_m @ C_BVH_WORLD.T * BVH_UNITS_PER_M
    tip = (skel.rest_tail_m - skel.rest_head_m) @ C_BVH_WORLD.T * BVH_UNITS_PER_M
    children = skel.children
    lines = ["HIERARCHY"]

    def emit(b: int, depth: int) -> None:
        ind = "\t" * depth
        if b == 0:
            lines.append(f"ROOT {joint_name(skel.bone_names[b])}")
            lines.append(f"{ind}{{")
            lines.append(f"{ind}\tOFFSET 0.000000 0.000000 0.000000")
            lines.append(f"{ind}\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation")
        else:
            lines.append(f"{ind}JOINT {joint_name(skel.bone_names[b])}")
            lines.append(f"{ind}{{")
            lines.append(f"{ind}\tOFFSET {off[b, 0]:.6f} {off[b, 1]:.6f} {off[b, 2]:.6f}")
            lines.append(f"{ind}\tCHANNELS 3 Zrotation Xrotation Yrotation")
        for c in children[b]:
            emit(c, depth + 1)
        if not children[b]:
            lines.append(f"{ind}\tEnd Site")
            lines.append(f"{ind}\t{{")
            lines.append(f"{ind}\t\tOFFSET {tip[b, 0]:.6f} {tip[b, 1]:.6f} {tip[b, 2]:.6f}")
            lines.append(f"{ind}\t}}")
        lines.append(f"{ind}}}")

    emit(0, 0)
    return lines


def depth_first_order(skel: AnnySkeleton) -> list[int]:
    """Bone indices in the order their channels appear in a motion line."""
    order: list[int] = []
    stack = [0]
    children = skel.children
    while stack:
        b = stack.pop()
        order.append(b)
        stack.extend(reversed(children[b]))
    return order


def bvh_text(skel: AnnySkeleton, pose_aa: np.ndarray, root_m: np.ndarray, frame_time_s: float) -> str:
    """The BVH file of one athlete.

    Args:
        skel: the athlete's rest skeleton (``backends.anny.skeleton.fit_skeleton``).
        pose_aa: (frames, bones, 3) ``BodyFit.pose`` rows (parent-relative axis-angle, radians).
        root_m: (frames, 3) world position of the root head, metres.
        frame_time_s: seconds between two motion lines (> 0).
    """
    n, nb = pose_aa.shape[:2]
    if nb != skel.n_bones or root_m.shape != (n, 3) or n == 0:
        raise ValueError(f"bvh: pose {pose_aa.shape} / root {root_m.shape} do not fit {skel.n_bones} bones")
    R_world = Rotation.from_rotvec(pose_aa.reshape(-1, 3)).as_matrix()
    R_bvh = C_BVH_WORLD @ R_world @ C_BVH_WORLD.T
    with warnings.catch_warnings():  # gimbal lock still yields angles that rebuild the matrix
        warnings.simplefilter("ignore", UserWarning)
        euler_deg = Rotation.from_matrix(R_bvh).as_euler(EULER_ORDER, degrees=True).reshape(n, nb, 3)
    pos = root_m @ C_BVH_WORLD.T * BVH_UNITS_PER_M
    order = depth_first_order(skel)
    values = np.concatenate([pos, euler_deg[:, order].reshape(n, -1)], axis=1)
    lines = _hierarchy(skel)
    lines += ["MOTION", f"Frames: {n}", f"Frame Time: {frame_time_s:.8f}"]
    lines += [" ".join(f"{v:.5f}" for v in row) for row in values]
    return "\n".join(lines) + "\n"


def _file_stem(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.\-]+", "_", name).strip("_") or "athlete"


def build_bvh(sel: ExportSelection) -> dict[str, bytes]:
    """The registry's ``bvh`` format: ``<athlete>.bvh`` per selected athlete.

    ``ValueError`` for a non-anny fit, a source other than the fit, irregular frame steps, or
    an athlete with no fitted frame in the selection; ``LookupError`` when the fit has not run."""
    from pipeline.backends.anny.skeleton import fit_skeleton

    fit = fit_for_export(sel, "bvh")
    if fit.body_model != "anny":
        raise ValueError(
            f"--format bvh: the fit used body_model={fit.body_model!r}; BVH export has anny's rig only "
            "(use --format params for SMPL/SMPL-X parameters)"
        )
    steps = np.unique(np.diff(fit.frame_indices))
    if steps.size > 1 or (steps.size == 1 and steps[0] <= 0):
        raise ValueError(
            f"--format bvh: the fit's frames are not evenly spaced (steps {steps.tolist()}); BVH needs one rate"
        )
    step = int(steps[0]) if steps.size else 1
    files: dict[str, bytes] = {}
    for pi, pid in enumerate(fit.person_ids.tolist()):
        name = sel.name_of(pid)
        valid = fit.valid[:, pi]
        if not valid.any():
            raise ValueError(
                f"--format bvh: athlete {name!r} (id {pid}) has no fitted frame in the selection; "
                "choose other --frames or leave them out with --athlete"
            )
        rows = fill_invalid(valid)
        skel = fit_skeleton(fit, pi)
        text = bvh_text(skel, fit.pose[rows, pi], fit.root_translation_m[rows, pi], step / fit.fps)
        fname = f"{_file_stem(name)}.bvh"
        if fname in files:
            fname = f"{_file_stem(name)}_{pid}.bvh"
        files[fname] = text.encode()
    return files
