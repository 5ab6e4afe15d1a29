"""What a bench ran on: the versions that move its numbers, and the machine.

The dependencies are not pinned (``pyproject.toml``), and a new release of one of them can
move a bench: opencv 5 moved the Pose2Sim sample's 2D, and one machine's MuJoCo stepped at
half another's speed. ``cornerman bench NAME --json rows.json`` therefore also writes
``rows.env.json`` (``sidecar_path``) with ``environment()``, and the README's tables say
what they were measured with (``describe``).
"""

from __future__ import annotations

import json
import os
import platform
from importlib import metadata
from pathlib import Path
from typing import Any

PACKAGES = (
    "cornerman",
    "numpy",
    "scipy",
    "torch",
    "mujoco",
    "onnxruntime",
    "opencv-python-headless",
    "anny",
)
"""Distributions whose versions a bench records (a missing one reads "not installed")."""

THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")
"""Environment variables that set how many threads the numeric libraries use."""


def environment() -> dict[str, Any]:
    """The versions of ``PACKAGES``, Python's, the platform, the usable CPUs and the thread
    variables that are set (a JSON object)."""
    versions: dict[str, str] = {}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "threads": {k: os.environ[k] for k in THREAD_VARIABLES if k in os.environ},
        "packages": versions,
    }


def sidecar_path(json_path: str | Path) -> Path:
    """Where the environment of a bench's ``--json`` file goes: ``rows.json`` -> ``rows.env.json``."""
    p = Path(json_path)
    return p.with_name(p.stem + ".env.json")


def describe(env: dict[str, Any]) -> str:
    """One line for a results table: "Measured with Python 3.11.2, numpy 2.3.1, …; 2 CPUs."
    ``ValueError`` when ``env`` is not what ``environment()`` writes."""
    try:
        pkgs = ", ".join(f"{k} {v}" for k, v in env["packages"].items() if v != "not installed")
        return f"Measured with Python {env['python']}, {pkgs}; {int(env['cpus'])} CPUs."
    except (KeyError, TypeError, AttributeError, ValueError) as e:
        raise ValueError(f"not a bench environment ({type(e).__name__}: {e})") from e


def load(json_path: str | Path) -> dict[str, Any] | None:
    """The environment beside a bench's ``--json`` file, or None when there is none (a file
    written before environments were recorded). ``ValueError`` naming the sidecar when it
    cannot be read or is not what ``environment()`` writes."""
    side = sidecar_path(json_path)
    if not side.is_file():
        return None
    try:
        env = json.loads(side.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{side}: cannot read the bench environment: {e}") from e
    if not isinstance(env, dict):
        raise ValueError(f"{side}: expected a JSON object, got {type(env).__name__}")
    try:
        describe(env)
    except ValueError as e:
        raise ValueError(f"{side}: {e}") from e
    return env
