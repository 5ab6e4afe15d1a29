"""The body mesh worker's stream: records round-trip, a truncated one is an error (the posing itself is
covered by ``tests/webui/test_scene.py::test_body_meshes_are_posed_in_the_background``)."""

from __future__ import annotations

import io

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
