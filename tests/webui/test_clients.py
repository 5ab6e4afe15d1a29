"""One viewer process, several clients (real viser server, websocket clients as viser's browser client
connects): each client has its own frame and playback, its own role from the token in its handshake,
its playback stops when it leaves, and the viewer measures how long it has been without clients."""

from __future__ import annotations

import time
from collections.abc import Iterator
from functools import partial

import pytest
import viser

from server.viewer_bench import WsClient, open_client
from tests.webui.fixtures import build_session, wait_for
from webui.api_client import ApiClient
from webui.app import NOT_SIGNED_IN, ViewerApp
from webui.client_view import ClientView
from webui.clients import TOKEN_HEADER, ClientUser
from webui.launcher import free_port

USERS = {"tok-coach": ("carla", "coach"), "tok-ann": ("anna", "annotator")}


def identify(token: str) -> ClientUser:
    if token not in USERS:
        raise ValueError(f"unknown token {token[:4]}…")
    name, role = USERS[token]
    # never called here: edits are not made in this test, only the controls are checked
    return ClientUser(name, role, ApiClient("http://127.0.0.1:9/api", token))


@pytest.fixture(scope="module")
def viewer(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[ViewerApp, int]]:
    sdir = build_session(tmp_path_factory.mktemp("clients"), n_frames=40)
    port = free_port()
    server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    app = ViewerApp(server, sdir, session_id="1", max_image_width=160, identify=identify)
    app.serve_clients()
    try:
        yield app, port
    finally:
        app.close()
        server.stop()


def _join(app: ViewerApp, port: int, token: str | None) -> tuple[WsClient, ClientView | None]:
    before = set(app.clients)
    c = open_client(f"ws://127.0.0.1:{port}/", {TOKEN_HEADER: token} if token else {})
    t_end = time.monotonic() + 20
    while time.monotonic() < t_end:
        new = set(app.clients) - before
        if new:
            return c, app.clients[new.pop()]
        time.sleep(0.05)
    return c, None


_wait = partial(wait_for, timeout_s=10.0)


def test_each_client_has_its_own_frame_play_and_role(viewer: tuple[ViewerApp, int]) -> None:
    app, port = viewer
    ca, a = _join(app, port, "tok-coach")
    cb, b = _join(app, port, "tok-ann")
    try:
        assert a is not None and b is not None and a is not b
        assert (a.user.name, a.user.role, b.user.name, b.user.role) == ("carla", "coach", "anna", "annotator")
        assert a.annotate is None and b.annotate is not None  # Edit tab for the annotator only
        # own frames: moving one leaves the other where it is, and each draws its own
        a.set_frame(7)
        b.set_frame(20)
        assert _wait(lambda: a.timeline.info.content.startswith("frame 7 /") and b.timeline.info.content.startswith("frame 20 /"))
        assert (a.frame, b.frame) == (7, 20)
        # Play in one does not move the other
        a.timeline.play.value = True  # type: ignore[misc]
        assert _wait(lambda: a.frame >= 15)
        assert b.frame == 20 and not b.playing
        assert app.idle_for() == 0.0
        # the playing client leaves: its view is closed and its loop thread ends
        ca.close()
        assert _wait(lambda: a not in app.clients.values() and not a.alive)
        played = a.frame
        time.sleep(0.3)
        assert a.frame == played and b.frame == 20 and b.alive
        assert app.idle_for() == 0.0  # one client is still there
    finally:
        ca.close()
        cb.close()
    assert _wait(lambda: not app.clients and not b.alive)
    time.sleep(0.3)
    assert app.idle_for() >= 0.25


def test_a_client_without_a_valid_token_gets_no_view(viewer: tuple[ViewerApp, int]) -> None:
    app, port = viewer
    for token in (None, "tok-forged"):
        refused = app.refused
        c = open_client(f"ws://127.0.0.1:{port}/", {TOKEN_HEADER: token} if token else {})
        try:
            assert _wait(lambda: app.refused == refused + 1)  # noqa: B023
            assert app.clients == {}
        finally:
            c.close()
    assert "sign in" in NOT_SIGNED_IN


def test_views_follow_a_reload_and_share_the_data(viewer: tuple[ViewerApp, int]) -> None:
    app, port = viewer
    c1, v1 = _join(app, port, "tok-coach")
    c2, v2 = _join(app, port, "tok-coach")
    try:
        assert v1 is not None and v2 is not None
        assert v1.persons.data is app.data and v2.persons.data is app.data  # loaded once
        v1.set_frame(5)
        before = app.reloads
        app.reload()
        assert app.reloads == before + 1
        assert v1.persons.data is app.data and v2.persons.data is app.data
        assert v1.frame == 5 and v2.frame == 0  # frames kept per client
    finally:
        c1.close()
        c2.close()


def test_over_the_wire_each_client_sees_only_its_own_frames(viewer: tuple[ViewerApp, int]) -> None:
    """What the clients receive: Play pressed by one (a GUI update message, as a browser sends it)
    moves the frame line that client gets; the other client's line stays at its frame."""
    app, port = viewer
    ca, a = _join(app, port, "tok-ann")
    cb, b = _join(app, port, "tok-coach")
    try:
        assert a is not None and b is not None
        assert _wait(lambda: ca.frame() == 0 and cb.frame() == 0 and "Play" in ca.uuids)
        b_updates = cb.frame_updates  # its own first frame line
        ca.set_value("Play", True)
        assert _wait(lambda: (ca.frame() or 0) >= 10)
        assert a.playing and not b.playing
        assert cb.frame() == 0 and b.frame == 0
        assert ca.frame_updates >= 5 and cb.frame_updates == b_updates  # nothing of a's playback reached b
    finally:
        ca.close()
        cb.close()
    assert _wait(lambda: not app.clients)
