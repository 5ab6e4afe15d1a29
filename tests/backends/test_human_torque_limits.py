"""``HumanoidConfig.torque_limits = "human"``: no joint of the humanoid can exceed the human
peak torque the effort metrics judge it by (``pipeline.evaluate.effort``)."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from pipeline.backends.mujoco.config import HumanoidConfig  # noqa: E402
from pipeline.backends.mujoco.forces import actuator_names, body_masses_kg  # noqa: E402
from pipeline.backends.mujoco.humanoid import build_scene_mjcf, load_model  # noqa: E402
from pipeline.backends.mujoco.skeleton import skeleton_from_keypoints  # noqa: E402
from pipeline.evaluate.effort import joint_torque_ratios  # noqa: E402
from tests.backends.test_humanoid import _rest_keypoints  # noqa: E402


def _saturated_ratios(cfg: HumanoidConfig) -> tuple[np.ndarray, list[tuple[int, str]], np.ndarray]:
    """Torque/human-limit ratio of every joint when each of its hinges pushes at its servo limit."""
    sk = skeleton_from_keypoints(_rest_keypoints(1.0), 0)
    xml = build_scene_mjcf([sk], [0], 50.0, cfg)
    m = load_model(xml)
    names = actuator_names(xml)
    at_limit = m.actuator_forcerange[:, 1][None, :].copy()
    ratios, cols = joint_torque_ratios(at_limit, names, [0], body_masses_kg(xml, [0]))
    return ratios[0], cols, m.actuator_forcerange[:, 1]


def test_human_limits_bound_every_joint_and_servo_limits_do_not() -> None:
    human, cols, lim_h = _saturated_ratios(HumanoidConfig(torque_limits="human"))
    servo, cols_s, lim_s = _saturated_ratios(HumanoidConfig())
    assert cols == cols_s and len(cols) > 10
    assert human.max() <= 1.0
    assert servo.max() > 1.0  # the option is what bounds them: the servo limits alone exceed a human's
    assert np.all(lim_h <= lim_s + 1e-9) and np.any(lim_h < 0.99 * lim_s)
    by_joint = dict(zip([c[1] for c in cols], human, strict=True))
    assert by_joint["left_elbow"] > 0.99  # a single-hinge joint gets its whole human peak


def test_unknown_torque_limits_value_is_refused() -> None:
    with pytest.raises(ValueError, match="torque_limits"):
        HumanoidConfig(torque_limits="robot")  # type: ignore[arg-type]
