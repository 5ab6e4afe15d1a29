"""EasyMocap calibration: OpenCV FileStorage YAML ``intri.yml`` + ``extri.yml`` -> ``CameraRig``.

Layout (as written by EasyMocap's ``write_intri`` / ``write_extri``, read with
``cv2.FileStorage``):

- ``intri.yml``: ``names`` (sequence of camera names), per camera ``K_<cam>`` (3x3),
  ``dist_<cam>`` (1x5 or 5x1; ``D_<cam>`` accepted too) and optionally ``H_<cam>`` /
  ``W_<cam>`` (image height / width).
- ``extri.yml``: ``names``, per camera ``R_<cam>`` (Rodrigues vector of R_cam_world),
  ``Rot_<cam>`` (the same rotation as a 3x3 matrix) and ``T_<cam>`` (t_cam_world, metres).
  ``Rot`` is used when present (more digits); if both are present they must agree.

The image size is not part of EasyMocap's format: it comes from ``H_``/``W_`` when
present, else from ``image_size_wh``, else it is estimated as ``2 * (cx, cy)`` (the
principal point at the image centre) with a logged warning.

World frame: kept as the file's (EasyMocap's is the calibration board's frame).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path

import cv2
import numpy as np

from pipeline.geometry.rotations import R_from_rodrigues
from pipeline.io.calibration_common import (
    as_float_array,
    check_intrinsics,
    dist5,
    image_size,
    rig_from_extrinsics,
)
from pipeline.schema.camera import CameraRig

log = logging.getLogger(__name__)

INTRI_NAME = "intri.yml"
EXTRI_NAME = "extri.yml"


def easymocap_files(path: str | Path) -> tuple[Path, Path]:
    """(intri.yml, extri.yml) for a folder or either file; ``ValueError`` if one is missing."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    intri, extri = folder / INTRI_NAME, folder / EXTRI_NAME
    missing = [str(p) for p in (intri, extri) if not p.is_file()]
    if missing:
        raise ValueError(
            f"{path}: EasyMocap calibration needs {INTRI_NAME} and {EXTRI_NAME}; missing {missing}"
        )
    return intri, extri


class _Storage:
    """A read-only ``cv2.FileStorage`` with errors that name the file."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self.fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        except cv2.error as e:
            raise ValueError(f"{path}: not an OpenCV FileStorage YAML file: {e}") from e
        if not self.fs.isOpened():
            raise ValueError(f"{path}: cannot be opened as an OpenCV FileStorage file")

    def names(self) -> list[str]:
        node = self.fs.getNode("names")
        if node.empty() or not node.isSeq():
            raise ValueError(f"{self.path}: missing the 'names' sequence of camera names")
        out = []
        for i in range(node.size()):
            item = node.at(i)
            # Names written as numbers ("1") come back as real nodes.
            out.append(item.string() if item.isString() else str(int(item.real())))
        return out

    def has(self, key: str) -> bool:
        return not self.fs.getNode(key).empty()

    def mat(self, key: str, shape: tuple[int, ...]) -> np.ndarray:
        node = self.fs.getNode(key)
        if node.empty():
            raise ValueError(f"{self.path}: missing {key!r}")
        m = node.mat()
        if m is None:
            raise ValueError(f"{self.path}: {key!r} is not an opencv-matrix")
        return as_float_array(f"{self.path}", key, m, shape)

    def vector(self, key: str) -> np.ndarray:
        node = self.fs.getNode(key)
        m = node.mat()
        if m is None:
            raise ValueError(f"{self.path}: {key!r} is not an opencv-matrix")
        return np.asarray(m, dtype=np.float64).ravel()

    def scalar(self, key: str) -> float:
        return float(self.fs.getNode(key).real())

    def close(self) -> None:
        self.fs.release()


def load_easymocap(
    path: str | Path,
    *,
    image_size_wh: Mapping[str, tuple[int, int]] | tuple[int, int] | None = None,
    fps: float = 30.0,
) -> CameraRig:
    """Read an EasyMocap calibration (the folder, ``intri.yml`` or ``extri.yml``).

    Cameras are in the order of ``intri.yml``'s ``names``; every one must be in
    ``extri.yml`` too. Raises ``ValueError`` naming the file and key on any problem.
    """
    intri_path, extri_path = easymocap_files(path)
    intri, extri = _Storage(intri_path), _Storage(extri_path)
    try:
        names = intri.names()
        ext_names = set(extri.names())
        missing = [n for n in names if n not in ext_names]
        if missing:
            raise ValueError(f"{extri_path}: cameras {missing} of {intri_path.name} have no extrinsics")
        Ks, dists, Rs, ts, sizes = [], [], [], [], []
        for n in names:
            K = check_intrinsics(f"{intri_path} [{n}]", intri.mat(f"K_{n}", (3, 3)))
            dkey = f"dist_{n}" if intri.has(f"dist_{n}") else f"D_{n}"
            if not intri.has(dkey):
                raise ValueError(f"{intri_path}: missing 'dist_{n}'")
            dist = dist5(f"{intri_path} [{dkey}]", intri.vector(dkey))
            if extri.has(f"Rot_{n}"):
                R = extri.mat(f"Rot_{n}", (3, 3))
                if extri.has(f"R_{n}"):
                    R2 = R_from_rodrigues(extri.mat(f"R_{n}", (3,)))
                    if np.abs(R - R2).max() > 1e-3:
                        raise ValueError(
                            f"{extri_path}: Rot_{n} and R_{n} disagree (max difference {np.abs(R - R2).max():.2e})"
                        )
            else:
                R = R_from_rodrigues(extri.mat(f"R_{n}", (3,)))
            t = extri.mat(f"T_{n}", (3,))
            if intri.has(f"H_{n}") and intri.has(f"W_{n}"):
                wh = image_size(f"{intri_path} [{n}]", [intri.scalar(f"W_{n}"), intri.scalar(f"H_{n}")])
            elif image_size_wh is not None:
                given = image_size_wh.get(n) if isinstance(image_size_wh, Mapping) else image_size_wh
                if given is None:
                    raise ValueError(f"{intri_path}: image_size_wh has no entry for camera {n!r}")
                wh = image_size(f"{intri_path} [{n}]", given)
            else:
                wh = np.round(2 * K[:2, 2]).astype(np.int64)
                log.warning(
                    "%s [%s]: no image size in the file; assuming %s (twice the principal point)",
                    intri_path,
                    n,
                    wh.tolist(),
                )
            Ks.append(K)
            dists.append(dist)
            Rs.append(R)
            ts.append(t)
            sizes.append(wh)
    finally:
        intri.close()
        extri.close()
    return rig_from_extrinsics(str(intri_path.parent), names, Ks, dists, Rs, ts, sizes, fps)


def save_easymocap(rig: CameraRig, folder: str | Path) -> None:
    """Write ``rig`` as EasyMocap ``intri.yml`` + ``extri.yml`` with ``cv2.FileStorage``.

    Also writes ``H_``/``W_`` so the image size survives a round trip.
    """
    from pipeline.geometry.rotations import rodrigues_from_R

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    T_cw = rig.T_cam_world
    fi = cv2.FileStorage(str(folder / INTRI_NAME), cv2.FILE_STORAGE_WRITE)
    fe = cv2.FileStorage(str(folder / EXTRI_NAME), cv2.FILE_STORAGE_WRITE)
    try:
        for fs in (fi, fe):
            fs.startWriteStruct("names", cv2.FileNode_SEQ)
            for n in rig.names:
                fs.write("", n)
            fs.endWriteStruct()
        for v, n in enumerate(rig.names):
            fi.write(f"K_{n}", rig.K[v])
            fi.write(f"dist_{n}", rig.dist[v].reshape(1, 5))
            fi.write(f"H_{n}", int(rig.image_size_wh[v, 1]))
            fi.write(f"W_{n}", int(rig.image_size_wh[v, 0]))
            fe.write(f"R_{n}", rodrigues_from_R(T_cw[v, :3, :3]).reshape(3, 1))
            fe.write(f"Rot_{n}", T_cw[v, :3, :3])
            fe.write(f"T_{n}", T_cw[v, :3, 3].reshape(3, 1))
    finally:
        fi.release()
        fe.release()
