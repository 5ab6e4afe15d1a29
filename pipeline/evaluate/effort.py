"""How hard the physics humanoids work: joint torques against human limits, ground
reaction force against body weight, and the residual root force split into its parts.

The limits are peak voluntary joint torques of trained adults, per kg of body mass
(rationale and sources in ``docs/design/physics-effort.md``). A joint's torque is the
norm over its hinge actuators (a ball joint is three hinges), compared with its group's
limit; twist hinges (forearm pronation, tibial rotation) have their own small limits.
"""

from __future__ import annotations

import re

import numpy as np

GRAVITY = 9.81

HUMAN_PEAK_TORQUE_NM_PER_KG: dict[str, float] = {
    "spine": 3.5,
    "neck": 0.8,
    "shoulder": 1.6,
    "elbow": 1.1,
    "forearm_twist": 0.15,
    "wrist": 0.3,
    "hip": 3.8,
    "knee": 3.4,
    "shin_twist": 0.45,
    "ankle": 2.6,
}
"""Peak voluntary torque per joint group, N·m per kg of body mass (valid > 0)."""

_GROUP_OF_JOINT: tuple[tuple[str, str], ...] = (
    (r"(spine|chest)", "spine"),
    (r"(neck|head)", "neck"),
    (r"(clavicle|shoulder)", "shoulder"),
    (r"elbow_twist", "forearm_twist"),
    (r"elbow", "elbow"),
    (r"wrist", "wrist"),
    (r"hip", "hip"),
    (r"knee_twist", "shin_twist"),
    (r"knee", "knee"),
    (r"ankle", "ankle"),
)


def joint_of_actuator(name: str) -> str:
    """The joint an actuator drives, without person prefix or axis suffix
    (``p0_left_hip_x`` -> ``left_hip``; ``p1_left_elbow_twist`` -> ``left_elbow_twist``)."""
    base = re.sub(r"^p\d+_", "", name)
    return re.sub(r"_(x|y|z|flex|dev)$", "", base)


def group_of_joint(joint: str) -> str:
    """The limit group of a joint name (``left_hip`` -> ``hip``); ``ValueError`` for an unknown joint."""
    for pattern, group in _GROUP_OF_JOINT:
        if re.search(pattern, joint):
            return group
    raise ValueError(
        f"joint {joint!r} has no torque-limit group; known groups: {sorted(HUMAN_PEAK_TORQUE_NM_PER_KG)}"
    )


def joint_torque_ratios(
    torque_nm: np.ndarray, actuator_names: list[str] | tuple[str, ...], person_ids: list[int], mass_kg: np.ndarray
) -> tuple[np.ndarray, list[tuple[int, str]]]:
    """(frames, joints) torque over its human limit for every joint of every athlete (>= 0;
    above 1 = over the limit), and the (person id, joint name) of each column.

    ``torque_nm``: (frames, actuators) applied actuator forces, N·m; ``actuator_names`` their
    MuJoCo names (``p{pid}_…``; residual ``_res_`` actuators are ignored); ``mass_kg``:
    (persons,) body masses, kg, in the order of ``person_ids``. ``ValueError`` when the
    shapes disagree, a mass is not positive or a joint has no limit group.
    """
    torque_nm = np.asarray(torque_nm, dtype=float)
    if torque_nm.ndim != 2 or torque_nm.shape[1] != len(actuator_names):
        raise ValueError(f"torques {torque_nm.shape} do not match {len(actuator_names)} actuator names")
    mass_kg = np.asarray(mass_kg, dtype=float)
    if mass_kg.shape != (len(person_ids),) or np.any(mass_kg <= 0):
        raise ValueError(f"need one positive mass per athlete, got {mass_kg.tolist()} for {list(person_ids)}")
    cols: list[np.ndarray] = []
    keys: list[tuple[int, str]] = []
    for i, pid in enumerate(person_ids):
        joints: dict[str, list[int]] = {}
        for a, name in enumerate(actuator_names):
            if name.startswith(f"p{pid}_") and "_res_" not in name:
                joints.setdefault(joint_of_actuator(name), []).append(a)
        for joint, acts in joints.items():
            limit = HUMAN_PEAK_TORQUE_NM_PER_KG[group_of_joint(joint)] * float(mass_kg[i])
            cols.append(np.linalg.norm(torque_nm[:, acts], axis=1) / limit)
            keys.append((int(pid), joint))
    ratios = np.stack(cols, axis=1) if cols else np.zeros((torque_nm.shape[0], 0))
    return ratios, keys


def torque_ratio_per_frame(
    torque_nm: np.ndarray,
    actuator_names: list[str] | tuple[str, ...],
    person_ids: list[int],
    mass_kg: np.ndarray,
    observed: np.ndarray | None = None,
) -> np.ndarray:
    """(frames,) largest joint torque over its human limit, worst athlete seen in the frame
    and joint (>= 0; 0 without joint actuators or athletes seen). Arguments as in
    ``joint_torque_ratios``; ``observed`` (frames, persons) as in ``torque_limit_report``."""
    ratios, keys = joint_torque_ratios(torque_nm, actuator_names, person_ids, mass_kg)
    seen = _observed(observed, ratios.shape[0], len(person_ids))
    cols = [list(person_ids).index(pid) for pid, _ in keys]
    return np.where(seen[:, cols], ratios, 0.0).max(axis=1, initial=0.0)


def _observed(observed: np.ndarray | None, n_frames: int, n_persons: int) -> np.ndarray:
    """(frames, persons) bool sample mask: ``observed``, or all True when None; ``ValueError`` on another shape."""
    if observed is None:
        return np.ones((n_frames, n_persons), dtype=bool)
    observed = np.asarray(observed, dtype=bool)
    if observed.shape != (n_frames, n_persons):
        raise ValueError(f"observed mask {observed.shape} needs (frames, persons) = {(n_frames, n_persons)}")
    return observed


def torque_limit_report(
    torque_nm: np.ndarray,
    actuator_names: list[str],
    person_ids: list[int],
    mass_kg: np.ndarray,
    observed: np.ndarray | None = None,
) -> dict[str, float]:
    """Share of (frame, athlete) samples whose joint torque exceeds the human limit, in %.

    Arguments as in ``joint_torque_ratios``; ``observed`` (frames, persons) restricts the
    samples to those where the athlete was seen (``PhysicsResult.observed_mask``; all when
    None). Returns ``torque_over_pct_<group>`` per group, ``torque_over_pct_any`` (samples
    where any joint of an athlete is over) and ``torque_peak_ratio_max`` (largest torque / limit).
    """
    ratios, keys = joint_torque_ratios(torque_nm, actuator_names, person_ids, mass_kg)
    seen = _observed(observed, ratios.shape[0], len(person_ids))
    over = ratios > 1.0
    over_any = np.zeros((ratios.shape[0], len(person_ids)), dtype=bool)
    over_group: dict[str, list[np.ndarray]] = {g: [] for g in HUMAN_PEAK_TORQUE_NM_PER_KG}
    peak = 0.0
    for c, (pid, joint) in enumerate(keys):
        i = list(person_ids).index(pid)
        over_group[group_of_joint(joint)].append(over[seen[:, i], c])
        over_any[:, i] |= over[:, c]
        peak = max(peak, float(ratios[seen[:, i], c].max(initial=0.0)))
    out = {
        f"torque_over_pct_{g}": 100.0 * float(np.mean(np.concatenate(v)))
        for g, v in over_group.items()
        if v and np.concatenate(v).size
    }
    out["torque_over_pct_any"] = 100.0 * float(over_any[seen].mean()) if seen.any() else 0.0
    out["torque_peak_ratio_max"] = peak
    return out


def residual_frac_bw(residual_wrench: np.ndarray, mass_kg: np.ndarray) -> np.ndarray:
    """(frames, persons) magnitude of the residual root force in body weights (>= 0).

    ``residual_wrench``: (frames, persons, 6) residual root force (N, first three) and torque;
    ``mass_kg``: (persons,) body masses, kg (> 0). ``ValueError`` on mismatched shapes.
    """
    residual_wrench = np.asarray(residual_wrench, dtype=float)
    mass_kg = np.asarray(mass_kg, dtype=float)
    if residual_wrench.ndim != 3 or residual_wrench.shape[1:] != (mass_kg.shape[0], 6) or np.any(mass_kg <= 0):
        raise ValueError(
            f"residual wrench {residual_wrench.shape} needs (frames, {mass_kg.shape[0]}, 6) and positive masses, "
            f"got masses {mass_kg.tolist()}"
        )
    return np.linalg.norm(residual_wrench[..., :3], axis=-1) / (mass_kg[None, :] * GRAVITY)


def residual_per_frame(
    residual_wrench: np.ndarray, mass_kg: np.ndarray, observed: np.ndarray | None = None
) -> np.ndarray:
    """(frames,) residual root force of the worst athlete seen in the frame (``observed``,
    (frames, persons); all when None), in body weights (``residual_frac_bw``; 0 when none is seen)."""
    r = residual_frac_bw(residual_wrench, mass_kg)
    return np.where(_observed(observed, *r.shape), r, 0.0).max(axis=1, initial=0.0)


def force_balance_report(
    grf_n: np.ndarray, residual_wrench: np.ndarray, mass_kg: np.ndarray, observed: np.ndarray | None = None
) -> dict[str, float]:
    """Who carries the athletes: the floor or the residual, in body weights (BW).

    ``grf_n``: (frames, persons, 3) floor force on each athlete (N, world z-up);
    ``residual_wrench``: (frames, persons, 6) residual root force (N) and torque;
    ``mass_kg``: (persons,); ``observed``: (frames, persons) the samples to count (all when
    None). A humanoid standing on its own has ``grf_z_mean_frac_bw`` near 1 over a bout and
    residual near 0. Every value is 0 without a sample.
    """
    res_bw = residual_frac_bw(residual_wrench, mass_kg)
    seen = _observed(observed, res_bw.shape[0], res_bw.shape[1])
    if not seen.any():
        keys = ("grf_z_mean", "grf_z_max", "residual_z_mean", "residual_xy_mean", "residual_mean", "residual_max")
        return {f"{k}_frac_bw": 0.0 for k in keys} | {"grf_airborne_pct": 0.0}
    bw = np.broadcast_to(np.asarray(mass_kg, dtype=float)[None, :] * GRAVITY, seen.shape)[seen]
    grf_z = grf_n[..., 2][seen] / bw
    res = residual_wrench[..., :3][seen]
    return {
        "grf_z_mean_frac_bw": float(np.mean(grf_z)),
        "grf_z_max_frac_bw": float(np.max(grf_z)),
        "grf_airborne_pct": 100.0 * float(np.mean(grf_z < 0.05)),
        "residual_z_mean_frac_bw": float(np.mean(res[:, 2] / bw)),
        "residual_xy_mean_frac_bw": float(np.mean(np.linalg.norm(res[:, :2], axis=-1) / bw)),
        "residual_mean_frac_bw": float(np.mean(res_bw[seen])),
        "residual_max_frac_bw": float(np.max(res_bw[seen])),
    }
