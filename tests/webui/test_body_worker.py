"""The body mesh worker's stream: records round-trip, a truncated one is an error (the posing itself is
covered by ``tests/webui/test_scene.py::test_body_meshes_are_posed_in_the_background``)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from webui.scene.body import read_record, write_record


def test_records_round_trip_and_truncation_is_reported() -> None:
    rng = np.random.default_rng(0)
    verts = rng.normal(size=(4, 7, 3)).astype(np.float32)
    faces = rng.integers(0, 7, size=(5, 3)).astype(np.int64)
    buf = io.BytesIO()
    write_record(buf, {"kind": "faces"}, faces)
    write_record(buf, {"kind": "verts", "person": 1, "start": 64}, verts)
    write_record(buf, {"kind": "error", "message": "no model"})
    buf.seek(0)
    (h1, a1), (h2, a2), (h3, a3) = (read_record(buf) for _ in range(3))  # type: ignore[misc]
    assert h1["kind"] == "faces" and a1 is not None and a1.dtype == np.int64 and np.array_equal(a1, faces)
    assert (h2["person"], h2["start"]) == (1, 64) and a2 is not None and np.array_equal(a2, verts)
    assert h3 == {"kind": "error", "message": "no model"} and a3 is None
    assert read_record(buf) is None  # end of the stream
    cut = io.BytesIO(buf.getvalue()[: len(buf.getvalue()) // 2])
    read_record(cut)
    with pytest.raises(ValueError, match="bytes"):
        read_record(cut)


@pytest.mark.slow
def test_posed_meshes_are_cached_for_the_next_viewer(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A second cache of the same fit loads the vertices from disk (no worker) and they equal the posed ones."""
    from pipeline.backends.anny.body import DEFAULT_RIG, bone_names
    from pipeline.schema.results import BodyFit
    from webui.scene.body import BodyMeshCache

    bones, n = bone_names(), 3
    fit = BodyFit(
        body_model="anny", rig=DEFAULT_RIG, bone_names=bones, person_ids=np.array([0]), frame_indices=np.arange(n),
        fps=25.0, shape=np.full((1, 6), 0.5), pose=np.zeros((n, 1, len(bones), 3)),
        root_translation_m=np.zeros((n, 1, 3)) + np.arange(n)[:, None, None] * 0.1, valid=np.ones((n, 1), dtype=bool),
        loss_final=np.zeros(1),
    )  # fmt: skip
    first = BodyMeshCache(fit, cache=tmp_path)
    first.start()
    first.join(120)
    assert first.error is None and not first.from_cache and len(list(tmp_path.glob("*.npz"))) == 1
    second = BodyMeshCache(fit, cache=tmp_path)
    monkeypatch.setattr("webui.scene.body.subprocess.Popen", None)  # a worker start would fail loudly
    second.start()
    second.join(30)
    assert second.from_cache and second.error is None and second.progress == 1.0
    for row in range(n):
        np.testing.assert_array_equal(second.get(0, row), first.get(0, row))
    assert np.array_equal(second.faces, first.faces)
