"""Importing the server must not pull in torch, mujoco or onnxruntime."""

from __future__ import annotations

import subprocess
import sys


def test_import_server_is_light() -> None:
    code = (
        "import sys, server.app, server.cli, server.jobs, server.loadtest, server.crud\n"
        "heavy = [m for m in ('torch', 'mujoco', 'onnxruntime', 'ray') if m in sys.modules]\n"
        "print(','.join(heavy))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.strip() == "", f"heavy modules imported by `import server.app`: {out.stdout.strip()}"
