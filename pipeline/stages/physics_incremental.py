"""What the physics stage keeps for an incremental re-run, and how it decides what to reuse.

After an edit at frame f (an identity swap, say), the fitted motion changes from about f
on. A re-run rebuilds the scene and the kinematic reference (cheap), compares the
reference frame by frame with the previous run's, and re-plans only from the first
receding-horizon window that reads a changed frame: a window starting at s with horizon H
reads frames s..s+H (the cost at every state, the servo schedule, the reference controls),
so it is reused only when all of them are unchanged. The re-planned windows start from the
stored state, warm start and carried controls (``PhysicsCheckpoints``;
``pipeline.backends.mujoco.physics.optimise_bout``, ``resume``).

A frame is unchanged when every value of the reference the optimiser reads moved by at
most a tolerance (``reference_values``, ``first_beyond``; ``PhysicsConfig.incremental_tol_m``,
``incremental_tol_rad``, ``REFERENCE_TOL_BW``): the servo schedule's spline and the
stance-long planted feet carry a fading part of an edit many frames back (bit for bit, the
schedule alone reaches ``SPLINE_REACH_FRAMES`` back), and those sub-millimetre tails are
not re-planned. The reused frames are then the previous run's result for a reference
within the tolerances of the new one, so an incremental re-run differs from a full one
there by what the optimiser makes of such a difference (docs/design/incremental.md).

The humanoids (sizes, masses, geometry, keypoint sites) are the athletes' bodies,
estimated once from the whole bout: an incremental re-run keeps the previous run's
skeletons as long as the body fit's shapes are unchanged (``body_digest``). Rebuilt, they
would move a little with any edit (their keypoint sites and feet are medians over every
frame), which would change every frame of the simulation; a full run re-estimates them.

The reference's inverse kinematics, warm-started frame to frame, is stored too
(``PhysicsCheckpoints.ik_qpos``): a re-run copies its frames before the first whose IK
inputs changed, bit for bit what solving them again gives, and solves on from there
(``pipeline.backends.mujoco.ik_reuse``; the manifest's ``ik_reused_frames``, ``ik_incremental``).

Pure numpy: no mujoco import here.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from pipeline.schema.base import check_array
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit, PhysicsResult

if TYPE_CHECKING:
    from pipeline.backends.mujoco.ik_reuse import ReferenceIK
    from pipeline.backends.mujoco.physics import BoutSolution, WindowRecord
    from pipeline.backends.mujoco.skeleton import Skeleton
    from pipeline.backends.mujoco.tracking import Reference


@dataclass(frozen=True)
class PhysicsCheckpoints:
    """Per frame and per receding-horizon window, what an incremental re-run needs
    (saved as ``checkpoints.npz`` beside the result; shapes name frames F, persons P,
    sites S, windows W, carried controls L).

    person_ids (P,), frame_indices (F,): the layout the checkpoints belong to.
    input_digest (F,) uint64: hash of the stage's inputs at each frame (every person's
    fitted joints and body-fit pose); reference_digest (F,) uint64: hash of every
    per-frame array of the kinematic reference the optimiser tracks.
    body_digest: hash of what the humanoids were built from (``body_digest``);
    skeletons_json: the humanoids' skeletons, one per person (``skeletons_to_json``);
    sole_m (P,): each person's foot keypoints' height above the sole (m; a median over
    every frame, so kept with the humanoids).
    window_start (W,): first frame of each window; window_qpos (W, nq), window_qvel
    (W, nv), window_warm (W, nv): the state and MuJoCo warm start it started from;
    window_carry (W, L, nu), window_carry_len (W,): the controls carried into it (rows
    past ``window_carry_len`` are padding); window_residual (W,) bool,
    window_iterations (W,), window_reset (W,) bool, window_kinematic (W,),
    window_cost_first (W,), window_cost_final (W,): how it went (for the stats).
    foot_site_offset_mm_mean: the stat of the run that calibrated the foot sites.
    reference_values (F, K) float32, reference_tol (K,) float32: every per-frame value of
    the kinematic reference the optimiser reads, one column each, and the change of each
    that counts as none (``reference_values``); None in checkpoints written before them
    (an incremental re-run then re-plans every window).
    ik_qpos (F, nq): the reference's inverse kinematics (before balance and separation);
    ik_input_digest (F,) uint64: hash of each frame's IK inputs; ik_model_digest: hash of
    the scene and IK settings (``pipeline.backends.mujoco.ik_reuse``); None and "" in
    checkpoints written before them (an incremental re-run then solves the IK of every frame).
    """

    person_ids: np.ndarray
    frame_indices: np.ndarray
    input_digest: np.ndarray
    reference_digest: np.ndarray
    body_digest: str
    skeletons_json: str
    sole_m: np.ndarray
    window_start: np.ndarray
    window_qpos: np.ndarray
    window_qvel: np.ndarray
    window_warm: np.ndarray
    window_carry: np.ndarray
    window_carry_len: np.ndarray
    window_residual: np.ndarray
    window_iterations: np.ndarray
    window_reset: np.ndarray
    window_kinematic: np.ndarray
    window_cost_first: np.ndarray
    window_cost_final: np.ndarray
    foot_site_offset_mm_mean: float = 0.0
    reference_values: np.ndarray | None = None
    reference_tol: np.ndarray | None = None
    ik_qpos: np.ndarray | None = None
    ik_input_digest: np.ndarray | None = None
    ik_model_digest: str = ""

    def __post_init__(self) -> None:
        F, P, W = self.frame_indices.shape[0], self.person_ids.shape[0], self.window_start.shape[0]
        if (self.reference_values is None) != (self.reference_tol is None):
            raise ValueError("PhysicsCheckpoints: reference_values and reference_tol go together")
        if self.reference_values is not None and self.reference_tol is not None:
            check_array("PhysicsCheckpoints.reference_values", self.reference_values, (F, None), "f")
            check_array(
                "PhysicsCheckpoints.reference_tol", self.reference_tol, (self.reference_values.shape[1],), "f"
            )
        if (self.ik_qpos is None) != (self.ik_input_digest is None) or (self.ik_qpos is None) != (
            self.ik_model_digest == ""
        ):
            raise ValueError("PhysicsCheckpoints: ik_qpos, ik_input_digest and ik_model_digest go together")
        if self.ik_qpos is not None and self.ik_input_digest is not None:
            check_array("PhysicsCheckpoints.ik_qpos", self.ik_qpos, (F, None), "f")
            check_array("PhysicsCheckpoints.ik_input_digest", self.ik_input_digest, (F,), "u")
        check_array("PhysicsCheckpoints.input_digest", self.input_digest, (F,), "u")
        check_array("PhysicsCheckpoints.reference_digest", self.reference_digest, (F,), "u")
        check_array("PhysicsCheckpoints.sole_m", self.sole_m, (P,), "f")
        if P != len(json.loads(self.skeletons_json)):
            raise ValueError(
                f"PhysicsCheckpoints: {P} persons but {len(json.loads(self.skeletons_json))} skeletons"
            )
        for name in ("window_qpos", "window_qvel", "window_warm"):
            check_array(f"PhysicsCheckpoints.{name}", getattr(self, name), (W, None), "f")
        check_array("PhysicsCheckpoints.window_carry", self.window_carry, (W, None, None), "f")
        for name in ("window_carry_len", "window_iterations", "window_kinematic"):
            check_array(f"PhysicsCheckpoints.{name}", getattr(self, name), (W,), "iu")
        for name in ("window_residual", "window_reset"):
            check_array(f"PhysicsCheckpoints.{name}", getattr(self, name), (W,), "b")

    def stored_ik(self) -> ReferenceIK | None:
        """The stored inverse kinematics as the backend takes it (``reference_and_ik``'s
        ``stored_ik``), or None when these checkpoints predate it."""
        if self.ik_qpos is None or self.ik_input_digest is None:
            return None
        from pipeline.backends.mujoco.ik_reuse import ReferenceIK

        return ReferenceIK(qpos=self.ik_qpos, input_digest=self.ik_input_digest, model_digest=self.ik_model_digest)

    def records(self) -> tuple[WindowRecord, ...]:
        """The windows as the backend's records (``optimise_bout``'s ``resume``)."""
        from pipeline.backends.mujoco.physics import WindowRecord

        return tuple(
            WindowRecord(
                start=int(self.window_start[w]),
                qpos=self.window_qpos[w],
                qvel=self.window_qvel[w],
                warm=self.window_warm[w],
                carry=self.window_carry[w, : int(self.window_carry_len[w])],
                residual=bool(self.window_residual[w]),
                iterations=int(self.window_iterations[w]),
                reset=bool(self.window_reset[w]),
                kinematic=int(self.window_kinematic[w]),
                cost_first=float(self.window_cost_first[w]),
                cost_final=float(self.window_cost_final[w]),
            )
            for w in range(self.window_start.shape[0])
        )


@dataclass(frozen=True)
class PhysicsPrevious:
    """The stage's previous run, read back by the runner: its result, its scene (MJCF
    text) and its checkpoints."""

    result: PhysicsResult
    mjcf: str
    checkpoints: PhysicsCheckpoints


def _digest(*parts: np.ndarray) -> np.uint64:
    h = hashlib.blake2b(digest_size=8)
    for p in parts:
        a = np.ascontiguousarray(p)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return np.uint64(int.from_bytes(h.digest(), "little"))


def input_digests(kp: Keypoints3D, bodyfit: BodyFit | None) -> np.ndarray:
    """(frames,) uint64: a hash of ``kp``'s joints and ``bodyfit``'s pose at each frame of
    ``kp`` (the body fit's frames matched by index; its shape is global, not per frame)."""
    rows: dict[int, int] = {}
    if bodyfit is not None:
        rows = {int(f): i for i, f in enumerate(bodyfit.frame_indices)}
    out = np.zeros(kp.n_frames, dtype=np.uint64)
    for t in range(kp.n_frames):
        parts = [kp.xyz_m[t], kp.valid[t], kp.confidence[t]]
        r = rows.get(int(kp.frame_indices[t]))
        if bodyfit is not None and r is not None:
            parts += [bodyfit.pose[r], bodyfit.root_translation_m[r], bodyfit.valid[r]]
        out[t] = _digest(*parts)
    return out


SPLINE_REACH_FRAMES = 20
"""Frames over which a change of the reference reaches the servo schedule: its cubic
spline (not-a-knot) is global, but the influence of one knot decays by 2 - sqrt(3) = 0.27
per frame, to 4e-12 of the change after 20 frames (below 1e-12 m or rad for any motion);
a window that reads frames closer than this to a change is re-planned."""


def reference_digests(ref: Reference, targets: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(frames,) uint64: a hash of the per-frame reference the optimiser tracks: the tracked
    ``targets`` and ``weight``, and every per-frame array of ``ref`` except what comes from
    its servo schedule (the schedule is a spline through the frames, see ``reference_reach``)."""
    F = ref.qpos.shape[0]
    from_schedule = {"qvel", "ctrl", "root_torque_ff"} if ref.schedule is not None else set()
    arrays: list[np.ndarray] = [targets, weight]
    for f in dataclasses.fields(ref):
        v = getattr(ref, f.name)
        if (
            isinstance(v, np.ndarray)
            and v.ndim >= 1
            and v.shape[0] == F
            and f.name not in from_schedule | {"site_ids"}
        ):
            arrays.append(v)
    return np.array([_digest(*(a[t] for a in arrays)) for t in range(F)], dtype=np.uint64)


def reference_reach(with_schedule: bool, smooth_frames: float) -> int:
    """Frames before a changed reference frame that the reference's derived parts (the servo
    schedule, its smoothing of ``smooth_frames`` (Gaussian sigma)) change too: 0 without a
    schedule (per-frame velocities and feed-forward; theirs are in ``reference_digests``)."""
    if not with_schedule:
        return 0
    return SPLINE_REACH_FRAMES + (int(4.0 * smooth_frames + 0.5) if smooth_frames > 0 else 0)


REFERENCE_TOL_BW = 0.005
"""Change of a reference force (N, per person) that counts as none in ``reference_values``,
as a fraction of that person's body weight (torques: the same number in N·m, i.e. over a
1 m lever); 0.005 BW is about 3.5 N for a 70 kg athlete."""


def reference_values(
    ref: Reference,
    targets: np.ndarray,
    weight: np.ndarray,
    linear_qpos: np.ndarray,
    linear_qvel: np.ndarray,
    angle_ctrl: np.ndarray,
    weight_n: np.ndarray,
    fps: float,
    tol_m: float,
    tol_rad: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Every per-frame value of the reference the optimiser reads, as ``(values (F, K)
    float32, tol (K,) float32)``: a frame is unchanged when each column moved by at most its
    ``tol`` (``first_beyond``).

    Columns and their tolerance: the tracked ``targets`` and the reference's sites (m:
    ``tol_m``); ``weight``, the site weights and the planted feet (0: equal in float32);
    ``qpos`` (``linear_qpos`` (nq,) True for a length: ``tol_m``, else ``tol_rad``); ``qvel``
    (``linear_qvel`` (nv,): ``tol_m * fps`` m/s, else ``tol_rad * fps`` rad/s: the same
    change over one frame); ``ctrl`` (``angle_ctrl`` (nu,) True for a joint servo:
    ``tol_rad``, else (residual root servos) ``min(tol_m, tol_rad)``); the residual root
    torque feed-forward and the servo schedule's forces and torques (``REFERENCE_TOL_BW``
    of each person's weight ``weight_n`` (P,), N); the schedule's per-substep ``qpos``,
    ``qvel`` and ``ctrl`` as the per-frame ones. The schedule is compared by value, so its
    spline's reach back from a change needs no allowance.
    """
    F = ref.qpos.shape[0]
    vals: list[np.ndarray] = []
    tols: list[np.ndarray] = []

    def add(a: np.ndarray, tol: np.ndarray | float) -> None:
        a = np.asarray(a, dtype=float).reshape(F, -1)
        t = np.broadcast_to(np.asarray(tol, dtype=float), a.shape[1:] if np.ndim(tol) else (a.shape[1],))
        vals.append(a)
        tols.append(np.asarray(t).reshape(-1))

    q_tol = np.where(linear_qpos, tol_m, tol_rad)
    v_tol = np.where(linear_qvel, tol_m * fps, tol_rad * fps)
    u_tol = np.where(angle_ctrl, tol_rad, min(tol_m, tol_rad))
    f_tol = REFERENCE_TOL_BW * np.asarray(weight_n, dtype=float)[:, None] * np.ones(3)  # (P, 3)
    add(targets, tol_m)
    add(weight, 0.0)
    add(ref.site_local_m, tol_m)
    add(ref.site_world_m, tol_m)
    add(ref.site_weight, 0.0)
    add(ref.qpos, q_tol)
    add(ref.qvel, v_tol)
    add(ref.ctrl, u_tol)
    if ref.root_torque_ff is not None:
        add(ref.root_torque_ff, f_tol.reshape(-1))
    if ref.foot_contact is not None:
        add(ref.foot_contact, 0.0)
    sc = ref.schedule
    if sc is not None:
        k = sc.substeps
        add(sc.qpos, np.tile(q_tol, k))
        add(sc.qvel, np.tile(v_tol, k))
        add(sc.ctrl, np.tile(u_tol, k))
        add(sc.root_torque, np.tile(f_tol.reshape(-1), k))
        add(sc.root_force, np.tile(f_tol.reshape(-1), k))
    return np.concatenate(vals, axis=1).astype(np.float32), np.concatenate(tols).astype(np.float32)


def first_beyond(old: np.ndarray, new: np.ndarray, tol: np.ndarray) -> int:
    """First frame (row) where a column of ``new`` differs from ``old`` by more than its
    ``tol`` (or is NaN in one of them only); the number of rows if none. ``old`` and ``new``
    (F, K) must have the same shape."""
    d = np.abs(old.astype(np.float64) - new.astype(np.float64))
    nan_a, nan_b = np.isnan(old), np.isnan(new)
    changed = ((d > tol[None, :]) & ~(nan_a | nan_b)) | (nan_a != nan_b)
    rows = np.flatnonzero(changed.any(axis=1))
    return int(rows[0]) if rows.size else int(new.shape[0])


def body_digest(kind: str, pids: list[int], bodyfit: BodyFit | None) -> str:
    """Hash of what the humanoids of persons ``pids`` are built from, apart from the
    per-frame motion: the skeleton kind and, for ``"bodyfit"``, the body model, its rig and
    each person's shape."""
    parts: list[np.ndarray] = [np.asarray(pids, dtype=np.int64), np.frombuffer(kind.encode(), dtype=np.uint8)]
    if kind == "bodyfit" and bodyfit is not None:
        ids = [int(i) for i in bodyfit.person_ids]
        parts += [np.frombuffer(f"{bodyfit.body_model}/{bodyfit.rig}".encode(), dtype=np.uint8)]
        parts += [bodyfit.shape[ids.index(p)] for p in pids if p in ids]
    return f"{int(_digest(*parts)):016x}"


def skeletons_to_json(skels: list[Skeleton]) -> str:
    """The skeletons as JSON text (floats round-trip exactly)."""
    return json.dumps([dataclasses.asdict(sk) for sk in skels], default=float)


def skeletons_from_json(text: str) -> list[Skeleton]:
    """Inverse of ``skeletons_to_json``; ``ValueError`` on malformed text."""
    from pipeline.backends.mujoco.skeleton import BodyDef, GeomDef, JointDef, Skeleton

    def tup(v: Any) -> Any:
        return tuple(tup(x) for x in v) if isinstance(v, list) else v

    try:
        out = []
        for sk in json.loads(text):
            bodies = tuple(
                BodyDef(
                    name=b["name"],
                    parent=b["parent"],
                    origin_m=tup(b["origin_m"]),
                    joints=tuple(JointDef(**{k: tup(v) for k, v in j.items()}) for j in b["joints"]),
                    geoms=tuple(GeomDef(**{k: tup(v) for k, v in g.items()}) for g in b["geoms"]),
                    sites=tup(b["sites"]),
                )
                for b in sk["bodies"]
            )
            out.append(
                Skeleton(
                    bodies=bodies,
                    lengths_m=dict(sk["lengths_m"]),
                    pelvis_height_m=float(sk["pelvis_height_m"]),
                )
            )
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        raise ValueError(f"physics checkpoints: malformed skeletons: {e}") from e
    return out


def layout_mismatch(prev: PhysicsPrevious, kp: Keypoints3D, pids: list[int], mode: str) -> str:
    """Why ``prev`` cannot be reused for these inputs ("" when it can, as far as the frame
    and person layout go)."""
    ck = prev.checkpoints
    if mode != "multi":
        return f"mode {mode!r} (incremental re-runs support mode 'multi')"
    if not np.array_equal(ck.frame_indices, kp.frame_indices):
        return f"frames changed ({ck.frame_indices.size} -> {kp.n_frames})"
    if [int(p) for p in ck.person_ids] != pids:
        return f"persons changed ({[int(p) for p in ck.person_ids]} -> {pids})"
    if (
        not np.array_equal(prev.result.frame_indices, kp.frame_indices)
        or prev.result.qpos.shape[0] != kp.n_frames
    ):
        return "the previous result does not cover these frames"
    return ""


def first_changed(old: np.ndarray, new: np.ndarray) -> int:
    """First index where two digest arrays of equal length differ (their length if none)."""
    diff = np.flatnonzero(old != new)
    return int(diff[0]) if diff.size else int(new.shape[0])


def replan_window(starts: list[int], n_frames: int, window: int, first_changed_frame: int) -> int:
    """Index of the first window that reads a frame at or after ``first_changed_frame``: a
    window starting at s reads frames s .. s + min(window, n_frames - 1 - s)."""
    for k, s in enumerate(starts):
        if s + min(window, n_frames - 1 - s) >= first_changed_frame:
            return k
    return len(starts)


def checkpoints_of(
    kp: Keypoints3D,
    pids: list[int],
    in_digest: np.ndarray,
    ref_digest: np.ndarray,
    body: str,
    skels: list[Skeleton],
    sole_m: np.ndarray,
    sol: BoutSolution,
    foot_mm: float,
    ref_values: tuple[np.ndarray, np.ndarray] | None = None,
    ik: ReferenceIK | None = None,
) -> PhysicsCheckpoints:
    """The checkpoints of a finished run (``sol``: the multi-person bout solution;
    ``ref_values``: ``reference_values`` of its reference; ``ik``: its inverse kinematics)."""
    recs = sol.records
    nq, nv, nu = sol.qpos.shape[1], sol.qvel.shape[1], sol.ctrl.shape[1]
    L = max((r.carry.shape[0] for r in recs), default=0)
    carry = np.zeros((len(recs), L, nu))
    for w, r in enumerate(recs):
        carry[w, : r.carry.shape[0]] = r.carry

    def col(name: str, dtype: Any) -> np.ndarray:
        return np.array([getattr(r, name) for r in recs], dtype=dtype)

    return PhysicsCheckpoints(
        person_ids=np.asarray(pids, dtype=np.int64),
        frame_indices=kp.frame_indices.astype(np.int64),
        input_digest=in_digest,
        reference_digest=ref_digest,
        body_digest=body,
        skeletons_json=skeletons_to_json(skels),
        sole_m=np.asarray(sole_m, dtype=float),
        window_start=col("start", np.int64),
        window_qpos=np.array([r.qpos for r in recs]).reshape(len(recs), nq),
        window_qvel=np.array([r.qvel for r in recs]).reshape(len(recs), nv),
        window_warm=np.array([r.warm for r in recs]).reshape(len(recs), nv),
        window_carry=carry,
        window_carry_len=np.array([r.carry.shape[0] for r in recs], dtype=np.int64),
        window_residual=col("residual", bool),
        window_iterations=col("iterations", np.int64),
        window_reset=col("reset", bool),
        window_kinematic=col("kinematic", np.int64),
        window_cost_first=col("cost_first", float),
        window_cost_final=col("cost_final", float),
        foot_site_offset_mm_mean=float(foot_mm),
        reference_values=None if ref_values is None else ref_values[0],
        reference_tol=None if ref_values is None else ref_values[1],
        ik_qpos=None if ik is None else ik.qpos,
        ik_input_digest=None if ik is None else ik.input_digest,
        ik_model_digest="" if ik is None else ik.model_digest,
    )
