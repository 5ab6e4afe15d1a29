"""anny's skeleton for one fitted person: rest bones and per-frame bone transforms (numpy API).

Used by the exporters (BVH, glTF) that need the rig rather than the mesh. Everything is
computed by anny itself: the rest skeleton is ``body.rest_mesh`` (anny's bone heads for the
person's phenotypes) and the poses are ``fk.forward_kinematics`` of the fit's ``pose`` and
``root_translation_m`` (float64, the model built once per process by ``model.anny_body``).

Frames and units (metres throughout, right-handed, z-up):

* **Rest frame**: anny's A-pose of the person's shape, facing -y, the subject's left on +x,
  soles at z = 0, pelvis at x = 0 (``body.RestMesh``'s frame: anny's native coordinates plus
  ``offset_m``). Rest bone frames are axis-aligned with it: bone ``b``'s rest frame is the
  rest frame translated to its head, ``T_rest_bone = [I | rest_head_m[b]]``.
* **World frame**: the session's world (z-up, metres), where the fit lives.
* **Posing** (cornerman's convention, ``fk`` module docstring): bone ``c`` turns by
  ``R_parent_local[c] = R(pose_aa[c])`` relative to its parent, in the rest frame's axes;
  its world rotation is ``R_world_bone[c] = R_world_bone[parent] @ R_parent_local[c]``
  (root: ``R(pose_aa[0])``) and its head is
  ``head_world_m[c] = head_world_m[parent] + R_world_bone[parent] @ (h[c] - h[parent])``,
  the root's head being ``root_translation_m``. So ``T_world_bone = [R_world_bone | head_world_m]``
  and a rest-frame point ``p`` carried rigidly by bone ``b`` lands at
  ``R_world_bone[b] @ (p - rest_head_m[b]) + head_world_m[b]`` (anny's linear blend skinning
  blends exactly these per-bone maps).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from pipeline.backends.anny.body import rest_mesh
from pipeline.backends.anny.fk import forward_kinematics, rotmat
from pipeline.backends.anny.model import DEFAULT_RIG, DEFAULT_TOPOLOGY, anny_body
from pipeline.schema.results import BodyFit


@dataclass(frozen=True)
class AnnySkeleton:
    """The rest (A-pose) skeleton of one anny shape, in the rest frame (module docstring).

    Fields:
        rig: anny rig name (``BodyFit.rig``).
        bone_names: (bones,) anny bone labels, in ``BodyFit.pose`` order (no spaces).
        parent: (bones,) int64 parent index, -1 for the root (index 0); parents precede children.
        rest_head_m: (bones, 3) rest bone heads (joint centres), metres.
        rest_tail_m: (bones, 3) rest bone tails (the child's head; for leaves the far end of
            the bone's own vertices: top of the head, fingertips, toe tips), metres.
        offset_m: (3,) rest frame minus anny's native model coordinates (lifts the soles to z = 0).
    """

    rig: str
    bone_names: tuple[str, ...]
    parent: np.ndarray
    rest_head_m: np.ndarray
    rest_tail_m: np.ndarray
    offset_m: np.ndarray

    @property
    def n_bones(self) -> int:
        return len(self.bone_names)

    @property
    def rest_offset_m(self) -> np.ndarray:
        """(bones, 3) each head minus its parent's head (the root: its own head), rest-frame axes."""
        off = self.rest_head_m.copy()
        off[1:] -= self.rest_head_m[self.parent[1:]]
        return off

    @property
    def children(self) -> tuple[tuple[int, ...], ...]:
        """Child bone indices of each bone, in index order (empty for the leaves)."""
        return tuple(tuple(int(c) for c in np.flatnonzero(self.parent == b)) for b in range(self.n_bones))


@dataclass(frozen=True)
class BonePoses:
    """World transforms of every bone over some frames.

    Fields:
        R_parent_local: (frames, bones, 3, 3) rotation of each bone relative to its parent,
            rest-frame axes (root: relative to the world), i.e. ``R(BodyFit.pose)``.
        R_world_bone: (frames, bones, 3, 3) world rotation of each bone frame (identity at rest).
        head_world_m: (frames, bones, 3) world positions of the bone heads, metres.
    """

    R_parent_local: np.ndarray
    R_world_bone: np.ndarray
    head_world_m: np.ndarray

    @property
    def T_world_bone(self) -> np.ndarray:
        """(frames, bones, 4, 4) homogeneous ``[R_world_bone | head_world_m]``."""
        n, nb = self.head_world_m.shape[:2]
        T = np.zeros((n, nb, 4, 4))
        T[..., :3, :3] = self.R_world_bone
        T[..., :3, 3] = self.head_world_m
        T[..., 3, 3] = 1.0
        return T


def anny_skeleton(shape: np.ndarray | None, rig: str = DEFAULT_RIG) -> AnnySkeleton:
    """The rest skeleton of ``shape`` (6 anny phenotypes in [0, 1]; None = anny's average).

    Cost: builds anny once per process (warm cache ~1-3 s). ``ValueError`` for an
    out-of-range shape or an unknown rig."""
    rest = rest_mesh(shape, rig=rig)
    return AnnySkeleton(
        rig=rig,
        bone_names=rest.bone_names,
        parent=rest.bone_parent.astype(np.int64),
        rest_head_m=rest.bone_head_m,
        rest_tail_m=rest.bone_tail_m,
        offset_m=rest.offset_m,
    )


def bone_poses(skeleton: AnnySkeleton, pose_aa: np.ndarray, root_m: np.ndarray) -> BonePoses:
    """Posed bones of ``skeleton`` by anny's forward kinematics.

    Args:
        pose_aa: (frames, bones, 3) parent-relative axis-angle, radians (``BodyFit.pose`` rows).
        root_m: (frames, 3) world position of the root head (``BodyFit.root_translation_m``).
    ``ValueError`` when the shapes do not match the skeleton.
    """
    pose_aa = np.asarray(pose_aa, dtype=np.float64)
    root_m = np.asarray(root_m, dtype=np.float64)
    n = pose_aa.shape[0] if pose_aa.ndim == 3 else -1
    if pose_aa.shape != (n, skeleton.n_bones, 3) or root_m.shape != (n, 3):
        raise ValueError(
            f"bone_poses: need pose_aa (frames, {skeleton.n_bones}, 3) and root_m (frames, 3), "
            f"got {pose_aa.shape} and {root_m.shape}"
        )
    body = anny_body(skeleton.rig, DEFAULT_TOPOLOGY)
    if body.bone_names != skeleton.bone_names:
        raise ValueError(
            f"bone_poses: skeleton bones {skeleton.bone_names[:3]}... are not rig {skeleton.rig!r}'s"
        )
    with torch.no_grad():
        pose_t = torch.as_tensor(pose_aa)
        heads = torch.as_tensor(skeleton.rest_head_m, dtype=torch.float64)[None]
        # FK uses head differences only, so rest-frame heads give the same world heads as native ones.
        G, x = forward_kinematics(body, pose_t, torch.as_tensor(root_m), heads)
        R_local = rotmat(pose_t)
    return BonePoses(R_parent_local=R_local.numpy(), R_world_bone=G.numpy(), head_world_m=x.numpy())


def _check_fit(bodyfit: BodyFit, person_index: int) -> None:
    if bodyfit.body_model != "anny":
        raise ValueError(f"anny skeleton: the fit is body_model={bodyfit.body_model!r}, not 'anny'")
    if not 0 <= person_index < bodyfit.person_ids.shape[0]:
        raise ValueError(
            f"anny skeleton: person_index {person_index} out of range {bodyfit.person_ids.shape[0]}"
        )


def fit_skeleton(bodyfit: BodyFit, person_index: int) -> AnnySkeleton:
    """The rest skeleton of person ``person_index`` (index into ``bodyfit.person_ids``) of an
    anny fit; ``ValueError`` when the fit is not anny's or its bones are not the rig's."""
    _check_fit(bodyfit, person_index)
    skel = anny_skeleton(bodyfit.shape[person_index], rig=bodyfit.rig)
    if tuple(bodyfit.bone_names) != skel.bone_names:
        raise ValueError(
            f"anny skeleton: the fit's bones {tuple(bodyfit.bone_names[:3])}... are not rig {bodyfit.rig!r}'s "
            f"{skel.bone_names[:3]}..."
        )
    return skel


def fit_bone_poses(
    bodyfit: BodyFit, person_index: int, rows: np.ndarray | None = None, skeleton: AnnySkeleton | None = None
) -> BonePoses:
    """Posed bones of person ``person_index`` at frame rows ``rows`` (indices into
    ``bodyfit.frame_indices``; None = all). Rows where ``bodyfit.valid`` is False hold whatever
    the fit stored there (zeros: rest pose at the origin); the caller masks them."""
    skel = fit_skeleton(bodyfit, person_index) if skeleton is None else skeleton
    _check_fit(bodyfit, person_index)
    r = (
        np.arange(bodyfit.frame_indices.shape[0])
        if rows is None
        else np.asarray(rows, dtype=np.int64).reshape(-1)
    )
    return bone_poses(skel, bodyfit.pose[r, person_index], bodyfit.root_translation_m[r, person_index])
