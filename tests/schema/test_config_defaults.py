"""One source of truth for every default: within a stage's configuration (nested objects
included) each setting is defined once, and the physics stage nests the very classes its
backends take instead of copying their fields."""

from __future__ import annotations

import dataclasses
import typing

from pipeline.runner.registry import get_specs

GENERIC = {"enabled", "mode"}
"""Names that mean "this part on/off" or "which variant" in each sub-config, not one setting."""


def _leaves(cls: type, out: dict[str, list[str]], seen: set[type]) -> None:
    if cls in seen:
        return
    seen.add(cls)
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        hint = hints.get(f.name)
        if dataclasses.is_dataclass(hint) and isinstance(hint, type):
            _leaves(hint, out, seen)
        else:
            out.setdefault(f.name, []).append(cls.__name__)


def test_no_setting_is_defined_twice_in_a_stage_configuration() -> None:
    for name, spec in get_specs().items():
        leaves: dict[str, list[str]] = {}
        _leaves(spec.config_cls, leaves, set())
        twice = {k: v for k, v in leaves.items() if len(v) > 1 and k not in GENERIC}
        assert not twice, f"stage {name}: settings defined in more than one class: {twice}"


def test_the_physics_stage_nests_the_backend_classes_themselves() -> None:
    from pipeline.backends.mujoco import config as mc
    from pipeline.stages.physics import PhysicsConfig

    hints = typing.get_type_hints(PhysicsConfig)
    assert hints["humanoid"] is mc.HumanoidConfig and hints["residual"] is mc.ResidualConfig
    assert hints["reference"] is mc.ReferenceConfig and hints["solver"] is mc.SolverConfig
    solver = typing.get_type_hints(mc.SolverConfig)
    assert solver["ilqr"] is mc.ILQRConfig and solver["weights"] is mc.CostWeights
    # The defaults are the backends' own: nothing to keep in sync.
    cfg = PhysicsConfig()
    assert cfg.humanoid == mc.HumanoidConfig() and cfg.solver == mc.SolverConfig()
