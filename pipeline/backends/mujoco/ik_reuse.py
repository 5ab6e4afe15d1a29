"""Reuse of an earlier inverse kinematics of the reference (``reference.inverse_kinematics``).

The IK is warm-started in time: frame f starts from frame f-1's pose, and the first pose's
root comes from each person's first frame with targets. Frame f's pose therefore depends on
the compiled scene, the IK's settings and the inputs of frames 0..f (site targets, their
weights, the feet that must stand flat), nothing else. A reference built on inputs equal to
an earlier one's up to frame k (bit for bit, compared by a per-frame hash) can copy that
earlier IK's frames 0..k-1 and solve on from frame k: the result is the one a solve from
frame 0 gives, bit for bit (the physics stage pins BLAS to one thread, so the same
operations on the same numbers give the same bits).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import mujoco
import numpy as np

from pipeline.backends.mujoco.scene import Scene
from pipeline.schema.base import check_array


@dataclass(frozen=True)
class ReferenceIK:
    """The inverse kinematics of a reference, as a later reference can reuse it.

    qpos (frames, nq): the IK's pose at each frame (before balance and separation);
    input_digest (frames,) uint64: hash of what each frame's solve read (``ik_input_digests``);
    model_digest: hash of the compiled scene and the IK's settings (``ik_model_digest``);
    reused_frames (0..frames): how many leading frames were copied from an earlier IK;
    why: why none were ("" when some were, or when there was nothing to reuse).
    """

    qpos: np.ndarray
    input_digest: np.ndarray
    model_digest: str
    reused_frames: int = 0
    why: str = ""

    def __post_init__(self) -> None:
        F = self.input_digest.shape[0]
        check_array("ReferenceIK.input_digest", self.input_digest, (F,), "u")
        check_array("ReferenceIK.qpos", self.qpos, (F, None), "f")
        if not 0 <= self.reused_frames <= F:
            raise ValueError(f"ReferenceIK.reused_frames must be in 0..{F}, got {self.reused_frames}")


def _blake(*parts: bytes) -> bytes:
    h = hashlib.blake2b(digest_size=8)
    for p in parts:
        h.update(p)
    return h.digest()


def ik_model_digest(scene: Scene, flat: bool, sole_lift_m: float, posture_weight: float) -> str:
    """Hash (16 hex digits) of everything the IK reads apart from the per-frame inputs: the
    compiled model (its MJB bytes: bodies, joints and their ranges, geoms, sites, rest pose),
    the tracked sites and their names, and the settings ``flat`` (flat feet on),
    ``sole_lift_m`` and ``posture_weight``."""
    m = scene.model
    mjb = np.zeros(mujoco.mj_sizeModel(m), dtype=np.uint8)
    mujoco.mj_saveModel(m, None, mjb)
    ids = np.ascontiguousarray(scene.site_ids, dtype=np.int64)
    settings = np.array([float(flat), float(sole_lift_m), float(posture_weight)])
    digest = _blake(
        mjb.tobytes(),
        ids.tobytes(),
        str(ids.shape).encode(),
        "\n".join(scene.site_names).encode(),
        settings.tobytes(),
    )
    return digest.hex()


def ik_input_digests(targets: np.ndarray, weight: np.ndarray, flat: np.ndarray | None) -> np.ndarray:
    """(frames,) uint64: hash of each frame's IK inputs, bit for bit: ``targets`` (frames,
    persons, sites, 3), ``weight`` (frames, persons, sites) and ``flat`` (frames, persons, 2)
    bool or None (no flat feet)."""
    F = weight.shape[0]
    t = np.ascontiguousarray(targets, dtype=np.float64)
    w = np.ascontiguousarray(weight, dtype=np.float64)
    fl = None if flat is None else np.ascontiguousarray(flat, dtype=bool)
    out = np.zeros(F, dtype=np.uint64)
    for f in range(F):
        parts = [t[f].tobytes(), w[f].tobytes()] + ([] if fl is None else [fl[f].tobytes()])
        out[f] = np.uint64(int.from_bytes(_blake(*parts), "little"))
    return out


def reusable_ik_frames(
    stored: ReferenceIK | None, input_digest: np.ndarray, model_digest: str, weight: np.ndarray
) -> tuple[int, str]:
    """How many leading frames of ``stored`` a new IK may copy (0..frames), and why none
    ("" when some or when ``stored`` is None): the frames before the first whose inputs'
    hash (``input_digest``, (frames,)) differs, as long as the scene and settings
    (``model_digest``) are the same and every person has a frame with targets among them
    (``weight`` (frames, persons, sites): the first pose's root comes from that frame)."""
    if stored is None:
        return 0, ""
    if stored.model_digest != model_digest:
        return 0, "the humanoids or the IK settings changed"
    if stored.input_digest.shape != input_digest.shape:
        return 0, f"the frames changed ({stored.input_digest.shape[0]} -> {input_digest.shape[0]})"
    diff = np.flatnonzero(stored.input_digest != input_digest)
    k = int(diff[0]) if diff.size else int(input_digest.shape[0])
    if k == 0:
        return 0, "the IK's inputs changed from frame 0 on"
    seen = (weight[:k].sum(axis=-1) > 0).any(axis=0)  # (persons,)
    if not seen.all():
        lacking = np.flatnonzero(~seen).tolist()
        return 0, f"persons (rows) {lacking} have no targets before frame {k}, the first changed IK input"
    return k, ""
