"""Keypoints as a flat list of labelled markers (the TRC and C3D layouts)."""

from __future__ import annotations

import re

import numpy as np

from pipeline.schema.keypoints3d import Keypoints3D


def marker_labels(kp: Keypoints3D, names: dict[int, str]) -> list[str]:
    """One label per (person, joint), person-major: the joint name, prefixed ``{athlete}_`` when
    ``kp`` holds several persons (whitespace in names becomes ``_``)."""
    if kp.n_persons == 1:
        return list(kp.joint_names)
    out: list[str] = []
    for pid in kp.person_ids.tolist():
        who = re.sub(r"\s+", "_", names.get(int(pid)) or f"person{int(pid)}")
        out.extend(f"{who}_{j}" for j in kp.joint_names)
    return out


def marker_arrays(kp: Keypoints3D) -> tuple[np.ndarray, np.ndarray]:
    """``(xyz_m, valid)``: (frames, persons * joints, 3) metres in the world frame (z-up) and
    (frames, persons * joints) bool, in ``marker_labels`` order."""
    f, p, j = kp.xyz_m.shape[:3]
    return kp.xyz_m.reshape(f, p * j, 3), kp.valid.reshape(f, p * j)


def zup_to_yup(xyz: np.ndarray) -> np.ndarray:
    """World z-up to y-up by a rotation of -90 deg about x: ``(x, y, z) -> (x, z, -y)``
    (so up is +Y, the world's x stays X, and the frame stays right-handed)."""
    return np.stack([xyz[..., 0], xyz[..., 2], -xyz[..., 1]], axis=-1)
