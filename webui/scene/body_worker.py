"""Pose a fit's body meshes in a child process: ``python -m webui.scene.body_worker [--body-model-path P]``.

Reads a ``BodyFit`` (npz bytes, ``pipeline.schema.base.to_arrays``) from stdin and writes
records (``webui.scene.body.write_record``) to stdout: ``faces`` once, then ``verts`` of each
person per chunk of frame rows, or one ``error`` record when the body model is unavailable
or posing fails. The viewer (``BodyMeshCache``) reads them; torch lives only here.
"""

from __future__ import annotations

import argparse
import io
import sys

import numpy as np

from pipeline.schema.base import from_arrays
from pipeline.schema.results import BodyFit
from webui.scene.body import write_record


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m webui.scene.body_worker", description=__doc__)
    p.add_argument("--body-model-path", default="", help="SMPL/SMPL-X model folder (SMPL fits only)")
    p.add_argument("--chunk", type=int, default=64, help="frame rows per record (>= 1)")
    args = p.parse_args(argv)
    out = sys.stdout.buffer
    with np.load(io.BytesIO(sys.stdin.buffer.read()), allow_pickle=False) as z:
        bodyfit = from_arrays(BodyFit, {k: z[k] for k in z.files})
    try:
        if bodyfit.body_model == "anny":
            from pipeline.backends.anny.body import posed_mesh
        else:
            from pipeline.backends.smpl.body import posed_mesh as smpl_mesh

            def posed_mesh(bodyfit: BodyFit, person_index: int, frames: np.ndarray, decimate: bool = True) -> tuple[np.ndarray, np.ndarray]:
                return smpl_mesh(bodyfit, person_index, frames, args.body_model_path)  # the full SMPL mesh
    except ImportError as e:
        write_record(out, {"kind": "error", "message": f"body model backend unavailable: {e}"})
        return 0
    n = bodyfit.frame_indices.shape[0]
    sent_faces = False
    try:
        for pi in range(bodyfit.person_ids.shape[0]):
            for start in range(0, n, max(1, args.chunk)):
                rows = np.arange(start, min(n, start + max(1, args.chunk)))
                verts, faces = posed_mesh(bodyfit, pi, rows, decimate=True)
                if not sent_faces:
                    write_record(out, {"kind": "faces"}, np.asarray(faces, dtype=np.int64))
                    sent_faces = True
                write_record(out, {"kind": "verts", "person": pi, "start": int(start)}, np.asarray(verts, dtype=np.float32))
    except (ValueError, RuntimeError) as e:
        write_record(out, {"kind": "error", "message": f"posing the body meshes failed: {e}"})
    except BrokenPipeError:  # the viewer stopped reading (it closed or the results were reloaded)
        return 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
