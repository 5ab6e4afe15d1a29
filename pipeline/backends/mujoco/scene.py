"""The physics stage's scene: the athletes' humanoids compiled into one MuJoCo model,
with index maps, and the same scene with every contact between the athletes (the probe
the separation and the overlap scores use)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import mujoco
import numpy as np

from pipeline.backends.mujoco.config import HumanoidConfig, ResidualConfig
from pipeline.backends.mujoco.humanoid import (
    SceneLayout,
    build_scene_mjcf,
    load_model,
    scene_layout,
)
from pipeline.backends.mujoco.skeleton import Skeleton


@dataclass(frozen=True)
class Scene:
    """A compiled scene: ``mjcf`` (what is simulated), its model and index maps, and
    ``probe_mjcf``: the same scene with every contact between the athletes enabled
    (``mjcf`` may leave arm-arm and foot-foot contacts out), for separating and scoring overlap."""

    mjcf: str
    model: mujoco.MjModel
    layout: SceneLayout
    person_ids: tuple[int, ...]
    site_names: tuple[str, ...]
    site_ids: np.ndarray  # (persons, sites)
    probe_mjcf: str = ""
    substeps: int = 1
    """MuJoCo steps per video frame (``HumanoidConfig.substeps``)."""

    def probe_model(self) -> mujoco.MjModel:
        """The model of ``probe_mjcf`` (same layout as ``model``)."""
        return self.model if self.probe_mjcf == self.mjcf else load_model(self.probe_mjcf)

    def collision_probe(self) -> mujoco.MjModel | None:
        """The probe for the iLQR's collision term (``TrackingCost(probe=...)``): its
        model when it collides more pairs than ``model``, else None (``model``'s own)."""
        return self.probe_model() if self.probe_mjcf not in ("", self.mjcf) else None


def build_scene(
    skeletons: list[Skeleton],
    person_ids: list[int],
    fps: float,
    joint_names: tuple[str, ...],
    cfg: HumanoidConfig,
    residual: ResidualConfig | None = ResidualConfig(),
) -> Scene:
    """Compile the scene (with ``residual``'s root actuators; none for None) and map
    ``joint_names`` to sites of every person."""
    mjcf = build_scene_mjcf(skeletons, person_ids, fps, cfg, residual)
    every = replace(cfg, arm_contacts="simulate", foot_contacts="simulate")
    probe = mjcf if every == cfg else build_scene_mjcf(skeletons, person_ids, fps, every, residual)
    model = load_model(mjcf)
    layout = scene_layout(model, person_ids)
    names = tuple(n for n in joint_names if n in layout.persons[0].site_ids)
    ids = np.array([[p.site_ids[n] for n in names] for p in layout.persons], dtype=np.int64)
    return Scene(mjcf, model, layout, tuple(person_ids), names, ids, probe, cfg.substeps)
