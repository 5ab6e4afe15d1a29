"""The names of the 3D results, one vocabulary for the CLI, the API, the evaluate stage,
the benches and the viewer.

``raw`` is the triangulation before filtering, ``filtered`` after it (with joints filled
from rigid neighbours), ``fit`` the body model's keypoints, ``physics`` the simulated
humanoids' sites.
"""

from __future__ import annotations

from typing import Literal

ResultSource = Literal["raw", "filtered", "fit", "physics"]

RESULT_ARTIFACTS: dict[str, tuple[str, str]] = {
    "raw": ("triangulate", "raw"),
    "filtered": ("triangulate", "keypoints3d"),
    "fit": ("fit", "keypoints3d"),
    "physics": ("physics", "keypoints3d"),
}
"""Result name -> (stage, artifact name) of its ``Keypoints3D``, in pipeline order."""

RESULT_LABELS: dict[str, str] = {"raw": "Raw", "filtered": "Filtered", "fit": "Fit", "physics": "Physics"}
"""How the viewer labels each result."""
