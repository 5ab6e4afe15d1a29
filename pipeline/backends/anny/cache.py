"""Where anny caches its built model data, and whether that cache exists (no torch import).

The first build of anny fills ``anny_cache_dir()`` with ~0.8 GB and takes a minute or two;
later builds load it in about a second. The CLI and the runner ask ``anny_cache_built`` to
tell the user about the wait before it starts.
"""

from __future__ import annotations

import os
from pathlib import Path

CACHE_SIZE_GB = 0.8
"""Approximate size of anny's cache once built (GB), for messages."""


def anny_cache_dir() -> Path:
    """Where anny's built model data is cached (``$ANNY_CACHE_DIR`` wins when set, else
    ``$CORNERMAN_CACHE_DIR/anny``, ``CORNERMAN_CACHE_DIR`` defaulting to ``~/.cache/cornerman``)."""
    if os.environ.get("ANNY_CACHE_DIR"):
        return Path(os.environ["ANNY_CACHE_DIR"])
    base = os.environ.get("CORNERMAN_CACHE_DIR") or str(Path.home() / ".cache" / "cornerman")
    return Path(base) / "anny"


def anny_cache_built() -> bool:
    """Whether anny's model data is cached (its ``v<version>/load_data_*.safetensors`` file);
    False means the next build of anny takes a minute or two and writes ~0.8 GB."""
    return any(anny_cache_dir().glob("v*/load_data_*.safetensors"))
