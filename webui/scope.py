"""Where GUI elements and scene nodes go: the whole server (every client) or one client."""

from __future__ import annotations

from typing import TypeAlias

import viser

Scope: TypeAlias = viser.ViserServer | viser.ClientHandle
"""Both have ``.gui``, ``.scene``, ``.atomic()`` and ``.send_file_download``; a client's elements are its own."""
