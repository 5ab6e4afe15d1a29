"""Heavy dependencies stay in ``pipeline.backends``: importing any other module of
``pipeline``, ``server`` or ``webui`` imports no torch, mujoco or onnxruntime.

Modules that run a backend (the stages, the runner steps, the benches, the viewer's
physics geoms) import it inside the functions that need it, so they are checked too: the
point is what importing a module costs, not what calling it does.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "mujoco", "onnxruntime")
PACKAGES = ("pipeline", "server", "webui")
SKIP = ("server.jobs.__main__",)
"""Entry points that run when imported."""


def _light_modules() -> list[str]:
    """Every module of ``PACKAGES`` outside ``pipeline.backends``, found on disk."""
    out = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            name = ".".join(parts)
            if name.startswith("pipeline.backends") or name in SKIP:
                continue
            out.append(name)
    return out


def test_light_modules_found() -> None:
    mods = _light_modules()
    assert {"pipeline.stages.fit", "pipeline.stages.physics", "server.app", "webui.scene.physics_geoms"} <= set(mods)
    assert not any(m.startswith("pipeline.backends") for m in mods)


def test_no_module_outside_backends_imports_heavy_dependencies() -> None:
    code = (
        "import importlib, json, sys\n"
        f"mods = {_light_modules()!r}\n"
        f"heavy = {HEAVY!r}\n"
        "culprits = {}\n"
        "for m in mods:\n"
        "    before = {h for h in heavy if h in sys.modules}\n"
        "    importlib.import_module(m)\n"
        "    new = sorted(h for h in heavy if h in sys.modules and h not in before)\n"
        "    if new:\n"
        "        culprits[m] = new\n"
        "print(json.dumps(culprits))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    culprits = json.loads(out.stdout.strip().splitlines()[-1])
    assert culprits == {}, f"modules importing heavy dependencies at import time (first importer listed): {culprits}"


def test_backend_packages_import_light() -> None:
    """The backend packages' ``__init__`` and their light modules (settings, pure numpy)
    import no heavy dependency: the stages' configs import them at module level."""
    light = [
        "pipeline.backends",
        "pipeline.backends.anny",
        "pipeline.backends.fitting",
        "pipeline.backends.mujoco",
        "pipeline.backends.onnx",
        "pipeline.backends.smpl",
        "pipeline.backends.mujoco.config",
        "pipeline.backends.mujoco.skeleton",
        "pipeline.backends.anny.cache",
        "pipeline.backends.fitting.config",
    ]
    code = (
        "import importlib, sys\n"
        f"for m in {light!r}:\n"
        "    importlib.import_module(m)\n"
        f"print(','.join(h for h in {HEAVY!r} if h in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip() == ""
