"""glTF/GLB export: read the file back with pygltflib, skin its mesh ourselves from the file's
accessors (inverse bind matrices, animation keys, joints and weights) and compare with anny's
posed vertices; check the structure (validator, accessor counts, POSITION bounds, cameras)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib
import pytest

from pipeline.artifacts import ArtifactStore
from pipeline.artifacts.store import Manifest
from pipeline.io.export import gltf as gltf_mod
from pipeline.io.export.registry import export_files
from pipeline.io.export.selection import ExportSelection
from pipeline.schema.results import BodyFit
from tests.conftest import write_tiny_session

N_FRAMES = 12
INVALID_ROWS = (3, 4)  # person 1 not fitted there
CHECK_ROWS = (0, 2, 5, 8, 11)
YUP_TO_ZUP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
_DTYPES = {5126: "<f4", 5121: "u1", 5123: "<u2", 5125: "<u4"}
_WIDTH = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def _fit(bones: tuple[str, ...], rig: str) -> BodyFit:
    rng = np.random.default_rng(7)
    n, b = N_FRAMES, len(bones)
    t = np.linspace(0.0, 1.0, n)[:, None, None, None]
    pose = 0.35 * rng.standard_normal((1, 2, b, 3)) + 0.4 * t * rng.standard_normal((1, 2, b, 3))
    pose[:, :, 0] += np.array([0.0, 0.0, np.pi / 2])  # root turned: the y/z swap would show
    root = np.array([[0.5, -0.3, 0.95], [-0.7, 0.6, 0.9]])[None] + t[..., 0] * np.array([0.4, 0.2, 0.05])
    valid = np.ones((n, 2), dtype=bool)
    valid[list(INVALID_ROWS), 1] = False
    return BodyFit(
        body_model="anny", rig=rig, bone_names=bones, person_ids=np.array([0, 1]), frame_indices=np.arange(10, 10 + n),
        fps=50.0, shape=rng.uniform(0.2, 0.8, (2, 6)), pose=pose, root_translation_m=root, valid=valid,
        loss_final=np.zeros(2),
    )  # fmt: skip


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[ExportSelection, BodyFit]:
    from pipeline.backends.anny.body import DEFAULT_RIG, bone_names

    sdir = write_tiny_session(tmp_path_factory.mktemp("gltf") / "s")
    fit = _fit(bone_names(), DEFAULT_RIG)
    manifest = Manifest(stage="fit", code_version="test", config={}, config_hash="", inputs={})
    ArtifactStore(sdir).write(manifest, {"bodyfit": fit})
    return ExportSelection(sdir, names={0: "Red", 1: "Blue"}), fit


@pytest.fixture(scope="module")
def glbs(session: tuple[ExportSelection, BodyFit]) -> dict[str, bytes]:
    sel, _ = session
    out = {}
    for fmt in ("gltf", "gltf-full"):
        files = export_files(sel, fmt)
        assert len(files) == 1 and next(iter(files)).endswith(".glb")
        out[fmt] = next(iter(files.values()))
    return out


def _read(g: Any, i: Any) -> np.ndarray:
    acc = g.accessors[i]
    view = g.bufferViews[acc.bufferView]
    blob = g.binary_blob()
    width = _WIDTH[acc.type]
    start = view.byteOffset + (acc.byteOffset or 0)
    data = np.frombuffer(blob, dtype=_DTYPES[acc.componentType], count=acc.count * width, offset=start)
    return data.reshape(acc.count, width).astype(np.float64)


def _trs(node: Any) -> np.ndarray:
    M = np.eye(4)
    if node.rotation is not None:
        from scipy.spatial.transform import Rotation

        M[:3, :3] = Rotation.from_quat(node.rotation).as_matrix()
    if node.scale is not None:
        M[:3, :3] = M[:3, :3] @ np.diag(node.scale)
    if node.translation is not None:
        M[:3, 3] = node.translation
    return M


def _posed_nodes(g: Any, t_s: float) -> list[np.ndarray]:
    """Global matrix of every node at animation time ``t_s`` (keys sampled exactly there)."""
    import copy

    nodes = [copy.deepcopy(n) for n in g.nodes]
    anim = g.animations[0]
    for ch in anim.channels:
        s = anim.samplers[ch.sampler]
        times = _read(g, s.input)[:, 0]
        k = int(np.argmin(np.abs(times - t_s)))
        assert abs(times[k] - t_s) < 1e-5
        setattr(nodes[ch.target.node], ch.target.path, _read(g, s.output)[k].tolist())
    world = [np.eye(4)] * len(nodes)

    def walk(i: int, parent: np.ndarray) -> None:
        world[i] = parent @ _trs(nodes[i])
        for c in nodes[i].children or []:
            walk(c, world[i])

    for r in g.scenes[g.scene].nodes:
        walk(r, np.eye(4))
    return world


def _skinned(g: Any, mesh_node: int, t_s: float) -> np.ndarray:
    """(verts, 3) skinned positions of ``mesh_node``'s mesh at ``t_s``, back in the z-up world."""
    world = _posed_nodes(g, t_s)
    skin = g.skins[g.nodes[mesh_node].skin]
    ibm = _read(g, skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    J = np.stack([world[j] for j in skin.joints]) @ ibm  # (joints, 4, 4)
    attrs = g.meshes[g.nodes[mesh_node].mesh].primitives[0].attributes
    v = np.c_[_read(g, attrs.POSITION), np.ones(_read(g, attrs.POSITION).shape[0])]
    out = np.zeros_like(v)
    for s in (0, 1):
        joints, weights = getattr(attrs, f"JOINTS_{s}", None), getattr(attrs, f"WEIGHTS_{s}", None)
        if joints is None:
            continue
        j, w = _read(g, joints).astype(int), _read(g, weights)
        for k in range(4):
            out += w[:, k, None] * np.einsum("vij,vj->vi", J[j[:, k]], v)
    return out[:, :3] @ YUP_TO_ZUP.T


def _body_nodes(g: Any) -> dict[str, int]:
    return {g.nodes[i].name: i for i in range(len(g.nodes)) if g.nodes[i].skin is not None}


@pytest.mark.parametrize("fmt", ["gltf", "gltf-full"])
def test_skinned_file_reproduces_anny_posed_vertices(
    glbs: dict[str, bytes], session: tuple[ExportSelection, BodyFit], fmt: str
) -> None:
    from pipeline.backends.anny.body import posed_mesh

    _, fit = session
    g = pygltflib.GLTF2.load_from_bytes(glbs[fmt])
    bodies = _body_nodes(g)
    assert sorted(bodies) == ["Blue_body", "Red_body"]
    for pi, name in enumerate(("Red", "Blue")):
        node = bodies[f"{name}_body"]
        extras = g.meshes[g.nodes[node].mesh].extras
        anny_vertex = extras["anny_vertex"]
        rows = [r for r in CHECK_ROWS if fit.valid[r, pi]]
        ours, _ = posed_mesh(fit, pi, np.array(rows), decimate=False)
        if fmt == "gltf":
            assert isinstance(anny_vertex, list) and 1000 < len(anny_vertex) < 2000
            ours = ours[:, anny_vertex]
        else:
            assert anny_vertex == "all" and ours.shape[1] == 13718
        for i, r in enumerate(rows):
            theirs = _skinned(g, node, r / fit.fps)
            err = np.linalg.norm(theirs - ours[i], axis=1)
            assert err.max() < 1e-3, f"{fmt} {name} row {r}: max error {err.max() * 1000:.3f} mm"
    # an athlete not fitted at a frame is scaled to zero there (and only there)
    blue = next(i for i, n in enumerate(g.nodes) if n.name == "Blue")
    w3 = _posed_nodes(g, INVALID_ROWS[0] / fit.fps)[blue]
    w5 = _posed_nodes(g, 5 / fit.fps)[blue]
    assert np.allclose(w3[:3, :3], 0.0) and np.allclose(w5[:3, :3], np.eye(3))


def test_structure_and_sizes(glbs: dict[str, bytes], session: tuple[ExportSelection, BodyFit]) -> None:
    from pygltflib.validator import validate

    sel, fit = session
    g = pygltflib.GLTF2.load_from_bytes(glbs["gltf"])
    validate(g)  # raises on a malformed accessor, view, mesh or animation channel
    extras = g.asset.extras
    assert extras["up"] == "+y" and extras["units"] == "m" and "(x, z, -y)" in extras["axes"]
    assert extras["fps"] == fit.fps and extras["frames"] == N_FRAMES and extras["first_video_frame"] == 10
    for i in _body_nodes(g).values():
        prim = g.meshes[g.nodes[i].mesh].primitives[0]
        a = prim.attributes
        pos = _read(g, a.POSITION)
        n = pos.shape[0]
        for acc in (a.NORMAL, a.JOINTS_0, a.WEIGHTS_0, a.JOINTS_1, a.WEIGHTS_1):
            assert g.accessors[acc].count == n
        np.testing.assert_allclose(g.accessors[a.POSITION].min, pos.min(axis=0))
        np.testing.assert_allclose(g.accessors[a.POSITION].max, pos.max(axis=0))
        assert 1.4 < pos[:, 1].max() - pos[:, 1].min() < 2.1  # standing adult along glTF's +y
        idx = _read(g, prim.indices)
        assert idx.max() < n and 2000 < idx.size // 3 < 5000  # "a few thousand faces"
        wsum = _read(g, a.WEIGHTS_0).sum(axis=1) + _read(g, a.WEIGHTS_1).sum(axis=1)
        np.testing.assert_allclose(wsum, 1.0, atol=1e-6)
        skin = g.skins[g.nodes[i].skin]
        assert g.accessors[skin.inverseBindMatrices].count == len(skin.joints) == len(fit.bone_names)
        color = g.materials[prim.material].pbrMetallicRoughness.baseColorFactor
        assert (color[0] > color[2]) == (g.nodes[i].name == "Red_body")
    for s in g.animations[0].samplers:
        assert g.accessors[s.input].count == g.accessors[s.output].count == N_FRAMES
    floor = next(n for n in g.nodes if n.name == "floor")
    fpos = _read(g, g.meshes[floor.mesh].primitives[0].attributes.POSITION)
    assert np.allclose(fpos[:, 1], 0.0)
    roots_zup = fit.root_translation_m.reshape(-1, 3)
    assert fpos[:, 0].min() < roots_zup[:, 0].min() and fpos[:, 0].max() > roots_zup[:, 0].max()
    assert -fpos[:, 2].max() < roots_zup[:, 1].min() and -fpos[:, 2].min() > roots_zup[:, 1].max()
    # size: two decimated bodies (~80 kB each) and 12 frames of keys; the full mesh ~10x
    assert len(glbs["gltf"]) < 400_000 < 2_000_000 < len(glbs["gltf-full"]) < 3_000_000


def test_cameras_match_the_rig(glbs: dict[str, bytes], session: tuple[ExportSelection, BodyFit]) -> None:
    from pipeline.runner.rig import rig_for
    from pipeline.schema.session import SessionConfig

    sel, _ = session
    rig = rig_for("downstream", sel.session_dir, SessionConfig.load(sel.session_dir))
    g = pygltflib.GLTF2.load_from_bytes(glbs["gltf"])
    cams = {n.name: n for n in g.nodes if n.camera is not None}
    assert sorted(cams) == sorted(f"cam_{c}" for c in rig.names)
    for v, c in enumerate(rig.names):
        M = YUP_TO_ZUP @ _trs(cams[f"cam_{c}"])[:3]
        np.testing.assert_allclose(M[:, 3], rig.T_world_cam[v, :3, 3], atol=1e-5)
        np.testing.assert_allclose(-M[:, 2], rig.T_world_cam[v, :3, 2], atol=1e-6)  # glTF looks down -z
        h, fy = rig.image_size_wh[v, 1], rig.K[v, 1, 1]
        assert g.cameras[cams[f"cam_{c}"].camera].perspective.yfov == pytest.approx(2 * np.arctan(h / 2 / fy))


def test_four_influences_and_bad_inputs(
    session: tuple[ExportSelection, BodyFit], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    sel, fit = session
    monkeypatch.setattr(gltf_mod, "INFLUENCES", 4)
    monkeypatch.setattr(gltf_mod, "INCLUDE_CAMERAS", False)
    g = pygltflib.GLTF2.load_from_bytes(gltf_mod.export_glb(sel))
    a = g.meshes[g.nodes[_body_nodes(g)["Red_body"]].mesh].primitives[0].attributes
    assert getattr(a, "JOINTS_1", None) is None and np.allclose(
        _read(g, a.WEIGHTS_0).sum(axis=1), 1.0, atol=1e-6
    )
    assert not any(n.camera is not None for n in g.nodes) and g.asset.extras["cameras"] == "not requested"
    monkeypatch.setattr(gltf_mod, "INFLUENCES", 5)
    with pytest.raises(ValueError, match="INFLUENCES"):
        gltf_mod.export_glb(sel)
    empty = write_tiny_session(tmp_path / "nofit")
    with pytest.raises(LookupError, match="fit stage has not produced bodyfit.npz"):
        export_files(ExportSelection(empty), "gltf")
    smpl = dataclasses.replace(fit, body_model="smpl", rig="smpl", shape=np.zeros((2, 10)))
    ArtifactStore(empty).write(
        Manifest(stage="fit", code_version="test", config={}, config_hash="", inputs={}), {"bodyfit": smpl}
    )
    with pytest.raises(ValueError, match="needs an anny body fit"):
        export_files(ExportSelection(empty), "gltf-full")
