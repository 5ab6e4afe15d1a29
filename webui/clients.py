"""Who a viewer client is: the user behind one websocket connection, and the API client it acts with.

One viewer process serves every browser of a session (``docs/design/viewer-sessions.md``).
The app's proxy (``server.api.routes.viewer_proxy``) opens the websocket to viser for a
signed-in browser and puts a token minted for that user, for that connection only, in the
``TOKEN_HEADER`` header of the handshake; it revokes the token when the connection ends.
The viewer reads the header, asks ``GET /api/me`` who it belongs to, and makes that
client's edits with it, so the server checks every edit against the user's own role.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import viser

from webui.api_client import ApiClient, ApiError

log = logging.getLogger(__name__)

TOKEN_HEADER = "x-cornerman-viewer-token"
"""Websocket handshake header carrying the connection's API token (loopback only, never in a URL)."""
EDIT_ROLES = ("annotator", "admin")
"""Roles whose clients get the Edit tab (the server checks the role again on every edit)."""


@dataclass(frozen=True)
class ClientUser:
    """A client's user: ``name`` (empty when anonymous), ``role`` (coach / annotator / admin) and
    ``api``, the API client acting with the user's token (None: read-only, no edits)."""

    name: str
    role: str
    api: ApiClient | None = None

    @property
    def can_edit(self) -> bool:
        return self.api is not None and self.role in EDIT_ROLES

    @classmethod
    def anonymous(cls) -> ClientUser:
        """A read-only client of a viewer started without an API (``python -m webui.app`` alone)."""
        return cls("", "coach", None)


Identify = Callable[[str], ClientUser]
"""token -> the user it belongs to; raises ``ValueError`` (``ApiError``) for an unknown token."""


def identify_with_api(api_url: str) -> Identify:
    """An ``Identify`` asking ``GET {api_url}/me`` with the token."""

    def identify(token: str) -> ClientUser:
        api = ApiClient(api_url, token)
        try:
            me = api.me()
        except ApiError:
            api.close()
            raise
        return ClientUser(str(me.get("name", "")), str(me.get("role", "coach")), api)

    return identify


def handshake_headers(server: viser.ViserServer, client: viser.ClientHandle) -> Mapping[str, str]:
    """HTTP headers of the websocket handshake that opened ``client`` (empty when unknown).

    viser 1.1 keeps each live ``websockets`` connection by client id but has no public accessor;
    ``tests/webui/test_clients.py`` fails if that changes.
    """
    conns = getattr(getattr(server, "_websock_server", None), "_live_connections", None)
    conn = conns.get(client.client_id) if isinstance(conns, dict) else None
    request = getattr(conn, "request", None)
    return request.headers if request is not None else {}


def token_of(server: viser.ViserServer, client: viser.ClientHandle) -> str:
    """The connection's API token from ``TOKEN_HEADER`` ("" when absent)."""
    return str(handshake_headers(server, client).get(TOKEN_HEADER, "")).strip()
