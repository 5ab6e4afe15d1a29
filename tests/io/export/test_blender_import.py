"""The BVH and glTF exports opened by Blender's own importers (Debian's ``blender`` package):
bone heads and skinned vertices where anny puts them (≤ 1 mm). Skipped where Blender is not
installed (``apt-get install blender python3-numpy``)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from pipeline.io.export import ExportSelection, export_files
from pipeline.schema.results import BodyFit
from tests.io.export.fitted_session import ATHLETES, write_fitted_session

BLENDER = shutil.which("blender")
pytestmark = pytest.mark.skipif(
    BLENDER is None, reason="Blender is not installed (apt-get install blender python3-numpy)"
)
TOL_M = 1e-3


def test_blender_imports_bvh_and_glb_where_anny_puts_the_body(tmp_path: Path) -> None:
    from pipeline.backends.anny.body import posed_mesh
    from pipeline.backends.anny.mesh import decimated_vertices
    from pipeline.backends.anny.skeleton import fit_bone_poses

    s = tmp_path / "bout"
    fit: BodyFit = write_fitted_session(s)
    sel = ExportSelection(s, names=dict(enumerate(ATHLETES)))
    (tmp_path / "Red.bvh").write_bytes(
        export_files(ExportSelection(s, athletes=(0,), names=sel.names), "bvh")["Red.bvh"]
    )
    (glb,) = export_files(sel, "gltf").values()
    (tmp_path / "bout.glb").write_bytes(glb)
    rows = [0, 4, fit.frame_indices.size - 1]
    cfg = {
        "bvh": str(tmp_path / "Red.bvh"),
        "glb": str(tmp_path / "bout.glb"),
        "fps": fit.fps,
        "frames": rows,
    }
    (tmp_path / "in.json").write_text(json.dumps(cfg))
    script = Path(__file__).with_name("blender_import.py")
    r = subprocess.run(
        [
            str(BLENDER),
            "-b",
            "--factory-startup",
            "--python",
            str(script),
            "--",
            str(tmp_path / "in.json"),
            str(tmp_path / "out.json"),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0 and (tmp_path / "out.json").exists(), r.stdout[-2000:] + r.stderr[-2000:]
    out = json.loads((tmp_path / "out.json").read_text())
    assert out["actions"] == sorted(f"bout_{n}" for n in ATHLETES) and out["cameras"] == 3

    heads = fit_bone_poses(fit, 0, np.array(rows)).head_world_m  # (frames, bones, 3)
    for k, f in enumerate(rows):
        got = np.array([out["bvh_heads"][str(f)][n] for n in fit.bone_names])
        err = np.linalg.norm(got - heads[k], axis=-1)
        assert err.max() <= TOL_M, (
            f"BVH in Blender, frame row {f}: bone heads off by {1000 * err.max():.2f} mm"
        )

    _, src = decimated_vertices()
    for pi, name in enumerate(ATHLETES):
        want, _ = posed_mesh(fit, pi, np.array(rows), decimate=False)
        for k, f in enumerate(rows):
            if not fit.valid[f, pi]:
                continue
            got = np.array(out["glb_verts"][str(f)][f"{name}_body"])
            ref = np.asarray(want[k], dtype=np.float64)[src]
            # Blender may reorder vertices on import: match each to its nearest anny vertex.
            d = np.sqrt(((got[:, None, :] - ref[None, :, :]) ** 2).sum(-1)).min(axis=1)
            assert len(got) == len(ref) and d.max() <= TOL_M, (
                f"GLB in Blender, {name} row {f}: {1000 * d.max():.2f} mm"
            )
