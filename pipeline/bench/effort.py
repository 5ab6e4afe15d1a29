"""The physics effort columns every bench prints: torques against human limits, ground
reaction force and the residual root force in body weights (``pipeline.evaluate.effort``)."""

from __future__ import annotations

from typing import Any

from pipeline.schema.results import PhysicsResult


def effort_columns(mjcf: str, result: PhysicsResult) -> dict[str, float]:
    """Torque-limit shares (%), floor force and residual (body weights) of one physics result,
    over the samples where each athlete was seen (``PhysicsResult.observed_mask``); ``mjcf``
    is the scene the result was simulated in (the stage's ``scene.xml``)."""
    from pipeline.backends.mujoco.forces import actuator_names, body_masses_kg, ground_reaction_forces
    from pipeline.evaluate.effort import force_balance_report, torque_limit_report

    pids = [int(p) for p in result.person_ids]
    mass = body_masses_kg(mjcf, pids)
    seen = result.observed_mask()
    out = torque_limit_report(result.joint_torque_nm, actuator_names(mjcf), pids, mass, seen)
    out.update(force_balance_report(ground_reaction_forces(mjcf, result), result.residual_root_force, mass, seen))
    return out


def session_effort_columns(store: Any) -> dict[str, float]:
    """``effort_columns`` of a session's physics stage (an ``ArtifactStore``); empty when it has not run."""
    if not store.has("physics", "result.npz"):
        return {}
    xml = (store.stage_dir("physics") / "scene.xml").read_text()
    return effort_columns(xml, store.load("physics", "result", PhysicsResult))


EFFORT_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("residual_xy_mean_frac_bw", "resid xy bw", "{:.2f}"),
    ("grf_z_mean_frac_bw", "floor Fz bw", "{:.2f}"),
    ("torque_over_pct_any", "τ>human %", "{:.1f}"),
    ("torque_peak_ratio_max", "τ/human max", "{:.1f}"),
)
"""(key, header, format) of the effort columns the real-footage benches print."""
