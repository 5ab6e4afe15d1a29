"""``backends.anny.skeleton``: the rest skeleton and the posed bones agree with anny's own FK."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

import torch  # noqa: E402

from pipeline.backends.anny.fk import forward_kinematics  # noqa: E402
from pipeline.backends.anny.model import anny_body  # noqa: E402
from pipeline.backends.anny.skeleton import anny_skeleton, bone_poses  # noqa: E402


def test_posed_bones_match_anny_fk_on_native_heads_and_compose_parent_local() -> None:
    rng = np.random.default_rng(0)
    shape = rng.uniform(0.2, 0.8, 6)
    skel = anny_skeleton(shape)
    body = anny_body()
    assert skel.bone_names == body.bone_names and skel.parent[0] == -1
    pose = rng.normal(0, 0.4, (4, skel.n_bones, 3))
    root = rng.normal(0, 1.0, (4, 3))
    bp = bone_poses(skel, pose, root)
    with torch.no_grad():  # reference: anny's native rest heads (no offset)
        heads = body.rest_heads(body.shape_coeffs(torch.as_tensor(shape)[None]))
        G, x = forward_kinematics(body, torch.as_tensor(pose), torch.as_tensor(root), heads)
    np.testing.assert_allclose(skel.rest_head_m, heads[0].numpy() + skel.offset_m, atol=1e-12)
    np.testing.assert_allclose(bp.head_world_m, x.numpy(), atol=1e-12)
    np.testing.assert_allclose(bp.R_world_bone, G.numpy(), atol=1e-12)
    np.testing.assert_allclose(bp.head_world_m[:, 0], root, atol=1e-12)
    # world = parent world @ local, heads follow the rest offsets rotated by the parent
    p = skel.parent[1:]
    np.testing.assert_allclose(
        bp.R_world_bone[:, 1:], bp.R_world_bone[:, p] @ bp.R_parent_local[:, 1:], atol=1e-12
    )
    moved = bp.head_world_m[:, p] + np.einsum("nbij,bj->nbi", bp.R_world_bone[:, p], skel.rest_offset_m[1:])
    np.testing.assert_allclose(bp.head_world_m[:, 1:], moved, atol=1e-12)
    np.testing.assert_allclose(bp.T_world_bone[..., :3, 3], bp.head_world_m)
    # rest pose: heads are the rest heads moved so that the root sits at root_m
    rest = bone_poses(skel, np.zeros_like(pose[:1]), root[:1])
    np.testing.assert_allclose(
        rest.head_world_m[0], skel.rest_head_m - skel.rest_head_m[0] + root[0], atol=1e-12
    )
    assert np.all(skel.rest_tail_m[:, 2] >= -1e-9) and skel.rest_head_m[:, 2].max() < 2.2
    with pytest.raises(ValueError, match="pose_aa"):
        bone_poses(skel, pose[:, :3], root)
