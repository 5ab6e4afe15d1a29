"""The viewer: one viser process per session serving every client, with review and (for annotators) editing.

``python -m webui.app --session-dir DIR --port P [--api-url URL] [--session-id ID] [--idle-s S]``.
Started by ``webui.launcher`` for the app's proxy, which passes each browser's user in the
websocket handshake (``webui.clients``); alone (no ``--api-url``) every client is read-only.
Session data, camera frames, body meshes and physics geoms are loaded once here; each
client gets its own frame, playback and layers (``webui.client_view.ClientView``).
"""

from __future__ import annotations

import argparse
import logging
import os
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import viser

from pipeline.artifacts import ArtifactStore
from pipeline.runner.core import enabled_stages
from pipeline.runner.registry import STAGE_ORDER
from webui.analysis import FrameProblems, compute_problems
from webui.api_client import TERMINAL_JOB_STATES, ApiClient, ApiError
from webui.client_view import ClientView
from webui.clients import ClientUser, Identify, identify_with_api, token_of
from webui.colors import IdentityPalette
from webui.events import EventsView
from webui.frames import FrameProvider
from webui.scene.body import BodyMeshCache
from webui.scene.body import cache_dir as mesh_cache_dir
from webui.scene.physics_geoms import load_physics_geoms
from webui.scene.session_data import STAGES_READ, SessionData, artifacts_stamp, load_session_data
from webui.scene.world import add_world, align_client_camera
from webui.staleness import StaleMark, layer_states, unix_time

log = logging.getLogger(__name__)

WATCH_S = 1.0
"""Period of the watch loop (s): artifacts' stamps, the session's identities and its re-run jobs."""

NOT_SIGNED_IN = "**Not signed in.** Open this viewer through the cornerman app: sign in at `/login`, then `/viewer/<session>/`."


class ViewerApp:
    """Shared state of one session's viewer (data, frames, meshes, the static scene) and its client views."""

    def __init__(
        self,
        server: viser.ViserServer,
        session_dir: Path,
        session_id: str | None = None,
        max_image_width: int = 400,
        data: SessionData | None = None,
        identify: Identify | None = None,
        default_user: ClientUser | None = None,
        role: str | None = None,
        api: ApiClient | None = None,
    ) -> None:
        """``identify`` turns a connection's token into its user (None: no API, clients are
        ``default_user`` or anonymous read-only); ``default_user`` serves clients without a token
        (None: such clients are refused when ``identify`` is set).

        ``role`` (with ``api`` for editing) builds ``shared``, one server-scoped view that every
        client sees, for tests and scripts without per-client views; its panels and state are
        then also reachable as attributes of the app (``app.timeline``, ``app.frame``, ...).
        """
        self.server, self.session_id = server, session_id
        self.session_dir = Path(session_dir)
        self.max_image_width = max_image_width
        self.identify, self.default_user = identify, default_user
        self.reloads = 0
        self.clients: dict[int, ClientView] = {}
        """Live per-client views by viser client id (``serve_clients``)."""
        self.refused = 0
        """Clients turned away so far (no token, or one the API does not know)."""
        self._views_lock = threading.Lock()
        self._idle_since: float | None = time.monotonic()
        self._stop = threading.Event()
        self._reload_lock = threading.Lock()
        self._palette_from_api = False
        self._identity_rows: list[dict] | None = None
        self.stale: StaleMark | None = None
        """The re-run the viewer waits for after an edit (None: every layer is up to date)."""
        self._stale_lock = threading.RLock()
        self._jobs_seen: set[int] = set()
        self.shared: ClientView | None = None
        """The view every client shares (``role``), else None; set before the mesh cache starts,
        whose first chunk (read from its disk cache at once) asks every view to render."""

        self.data: SessionData = data if data is not None else load_session_data(self.session_dir)
        self.palette = IdentityPalette(None, self.data.config.athletes)
        if default_user is not None and default_user.api is not None:
            self._load_palette(default_user.api)
        self.provider = FrameProvider(self.data, max_width=max_image_width)
        self.problems: FrameProblems = compute_problems(self.data)
        self.body_cache: BodyMeshCache | None = None
        self.physics_geoms: Any = None
        self._attach_heavy()
        server.gui.configure_theme(control_width="large", dark_mode=False)
        self.world = add_world(server, self.data.rig)
        # Start from the red corner's side, above the ropes, looking at where the athletes are.
        c = self._action_centre()
        server.initial_camera.position = (c[0] - 4.0, c[1] - 3.2, 2.8)
        server.initial_camera.look_at = (c[0], c[1], 1.0)
        server.initial_camera.up = (0.0, 0.0, 1.0)
        for v, name in enumerate(self.data.camera_names):
            self.world.cams[name].on_click(self.aligner(v))
        if role is not None:
            self.shared = self.add_view(server, ClientUser("", role, api))
        self._watch = threading.Thread(target=self._watch_loop, name="watch", daemon=True)
        self._watch.start()

    def __getattr__(self, name: str) -> Any:
        """Attributes of the ``shared`` view (``timeline``, ``frame``, ``render``, ...), when there is one."""
        shared = self.__dict__.get("shared")
        if shared is None or name.startswith("_"):
            raise AttributeError(f"{type(self).__name__!s} has no attribute {name!r}")
        return getattr(shared, name)

    # ------------------------------------------------------------------ clients
    def serve_clients(self) -> None:
        """Give every client that connects its own view, and close it when the client leaves."""
        self.server.on_client_connect(self.connect)
        self.server.on_client_disconnect(self.disconnect)

    def connect(self, client: viser.ClientHandle) -> None:
        """Identify ``client`` (its handshake token) and build its view; a client without a valid
        token gets a notice only, when the viewer has an API."""
        user = self._user_of(client)
        if user is None:
            client.gui.add_markdown(NOT_SIGNED_IN)
            self.refused += 1
            return
        view = self.add_view(client, user)
        with self._views_lock:
            gone = client.client_id not in self.server.get_clients()  # left while its view was built
            if not gone:
                self.clients[client.client_id] = view
                self._idle_since = None
            n = len(self.clients)
        if gone:
            view.close()
            return
        log.info("%s joined as %s (%d clients)", view.name, user.role, n)

    def disconnect(self, client: viser.ClientHandle) -> None:
        with self._views_lock:
            view = self.clients.pop(client.client_id, None)
            left = len(self.clients)
            if not self.clients:
                self._idle_since = time.monotonic()
        if view is None:
            return
        was_playing = view.playing
        view.close()
        if view.user.api is not None and view.user is not self.default_user:
            view.user.api.close()
        log.info("%s left%s (%d clients)", view.name, "; its playback stopped" if was_playing else "", left)

    def add_view(self, scope: viser.ViserServer | viser.ClientHandle, user: ClientUser) -> ClientView:
        """A view on ``scope`` (one client, or the server itself for a view every client shares)."""
        if user.api is not None and not self._palette_from_api:
            self._load_palette(user.api)
        return ClientView(self, scope, user)

    def _user_of(self, client: viser.ClientHandle) -> ClientUser | None:
        token = token_of(self.server, client)
        if token and self.identify is not None:
            try:
                return self.identify(token)
            except ValueError as e:  # ApiError: unknown or revoked token, API down
                log.warning("client %d: token refused (%s)", client.client_id, getattr(e, "status", e))
                return None
        if self.default_user is not None:
            return self.default_user
        return ClientUser.anonymous() if self.identify is None else None

    def idle_for(self) -> float:
        """Seconds since the last client left (or since the start when none came); 0 while any is connected."""
        since = self._idle_since
        return 0.0 if since is None else time.monotonic() - since

    # ------------------------------------------------------------------ shared state
    def legend(self) -> str:
        ids = self.data.person_ids or [0, 1]
        idents = [i for i in (self.palette.get(p) for p in ids) if i is not None]
        return ", ".join(f"{i.name} = {i.color_hex}" for i in idents)

    def _load_palette(self, api: ApiClient) -> None:
        if self.session_id is None:
            return
        try:
            rows = api.identities(self.session_id)
            self.palette = IdentityPalette.from_api(rows, self.data.config.athletes)
            self._identity_rows = rows
            self._palette_from_api = True
        except (ApiError, ValueError) as e:
            log.warning("identities from the API unavailable (%s): default colours", e)

    def _action_centre(self) -> tuple[float, float]:
        """Median ground position of every valid 3D keypoint (the ring centre when there is none)."""
        for kp in self.data.keypoints.values():
            if kp.valid.any():
                xy = np.median(kp.xyz_m[kp.valid][:, :2], axis=0)
                return float(xy[0]), float(xy[1])
        return 0.0, 0.0

    def image_sizes(self) -> list[tuple[int, int]]:
        """(w, h) of each camera's image in the GUI."""
        sizes = []
        for v in range(self.data.rig.n_views):
            s = self.provider.scale(v)
            w, h = (int(x) for x in self.data.rig.image_size_wh[v])
            sizes.append((max(1, round(w * s)), max(1, round(h * s))))
        return sizes

    def events_view(self) -> EventsView:
        names = {p: self.palette.name(p) for p in self.data.person_ids}
        return EventsView(self.data.events, self.data.series, names)

    def default_source(self) -> str:
        for s in ("physics", "fit", "filtered"):
            if s in self.data.keypoints:
                return s
        return "filtered"

    def all_views(self) -> list[ClientView]:
        """Every live view: the clients' and the shared one."""
        with self._views_lock:
            views = list(self.clients.values())
        return views + ([self.shared] if self.shared is not None else [])

    def request_render_all(self) -> None:
        for view in self.all_views():
            view.request_render()

    def _attach_heavy(self, previous: SessionData | None = None) -> None:
        """Body meshes (a child process) and physics geoms (mujoco), when present.

        After a reload, what the fit / physics stages did not rewrite is kept (posing every
        frame's mesh again would take seconds for nothing).
        """
        fit_same = previous is not None and _stage_stamp(previous, "fit") == _stage_stamp(self.data, "fit")
        phys_same = previous is not None and _stage_stamp(previous, "physics") == _stage_stamp(self.data, "physics")
        if not fit_same:
            if self.body_cache is not None:
                self.body_cache.stop()
            self.body_cache = None
            bf = self.data.bodyfit
            smpl_path = str(self.data.config.stage_config.get("fit", {}).get("body_model_path", ""))
            if bf is not None and (bf.body_model == "anny" or smpl_path):
                cache = BodyMeshCache(bf, on_chunk=self.request_render_all, body_model_path=smpl_path,
                                      cache=mesh_cache_dir())
                cache.start()
                self.body_cache = cache
            elif bf is not None:
                log.info("%s fit: body meshes need the model files (fit.body_model_path); skeletons only", bf.body_model)
        if not phys_same:
            self.physics_geoms = load_physics_geoms(self.data.physics_xml, self.data.physics)

    def aligner(self, view: int) -> Any:
        """A click callback putting the clicking client's 3D camera at camera ``view``."""

        def cb(event: Any) -> None:
            client = getattr(event, "client", None)
            targets = [client] if client is not None else list(self.server.get_clients().values())
            for c in targets:
                align_client_camera(c, self.data.rig, view)

        return cb

    # ------------------------------------------------------------------ reload
    def _watch_loop(self) -> None:
        """Every ``WATCH_S``: reload when the artifacts change (a re-run started elsewhere, or a
        finished job), apply renamed / recoloured identities, and follow the session's re-runs."""
        stamp = self.data.stamp
        while not self._stop.wait(WATCH_S):
            api = self._api()
            if api is not None and self.session_id is not None:
                self._poll_identities(api)
                self._poll_jobs(api)
            try:
                now = artifacts_stamp(self.session_dir)
            except ValueError as e:
                log.warning("cannot read the artifacts: %s", e)
                continue
            if now != stamp:
                # A multi-stage re-run writes several stages in a row: wait for a quiet moment,
                # but never longer than a few seconds (the re-triangulated 3D must show quickly).
                t_end = time.monotonic() + 3.0
                while not self._stop.wait(0.3) and time.monotonic() < t_end:
                    later = artifacts_stamp(self.session_dir)
                    if later == now:
                        break
                    now = later
                stamp = now
                if stamp != self.data.stamp:
                    self.reload()

    def _api(self) -> ApiClient | None:
        """An API client to watch the session with: the default user's, the shared view's or a
        connected client's (None without an API)."""
        if self.default_user is not None and self.default_user.api is not None:
            return self.default_user.api
        for view in self.all_views():
            if view.user.api is not None:
                return view.user.api
        return None

    def _poll_identities(self, api: ApiClient) -> None:
        assert self.session_id is not None
        try:
            rows = api.identities(self.session_id)
        except (ApiError, RuntimeError) as e:  # RuntimeError: that client was closed as it left
            log.debug("identities not polled: %s", e)
            return
        if rows != self._identity_rows:
            self.set_identities(rows)

    def set_identities(self, rows: list[dict]) -> None:
        """Apply ``GET /identities`` rows (names and colours) to every view: legend, buttons,
        camera labels, meshes and plots; a bad row is logged and the palette kept."""
        try:
            palette = IdentityPalette.from_api(rows, self.data.config.athletes)
        except ValueError as e:
            log.warning("%s", e)
            return
        first = self._identity_rows is None
        self.palette, self._identity_rows, self._palette_from_api = palette, rows, True
        if not first:
            log.info("identities changed: %s", self.legend())
        for view in self.all_views():
            view.on_palette()

    def _poll_jobs(self, api: ApiClient) -> None:
        """Mark the layers stale for a re-run queued by anyone (this viewer, the annotate page, a
        script), and follow the job being waited for."""
        assert self.session_id is not None
        try:
            jobs = api.jobs(self.session_id)
        except (ApiError, RuntimeError) as e:
            log.debug("jobs not polled: %s", e)
            return
        for job in sorted(jobs, key=lambda j: int(j["id"])):
            jid = int(job["id"])
            if job.get("status") in TERMINAL_JOB_STATES or not job.get("from_stage") or jid in self._jobs_seen:
                continue
            try:
                since = unix_time(job.get("created_at"))
            except ValueError as e:
                log.warning("job %s: %s", jid, e)
                continue
            self.mark_stale(str(job["from_stage"]), job, since)
            for view in self.all_views():  # an edit made elsewhere: show it in the history
                view.refresh_history()
        mark = self.stale
        if mark is not None and mark.job_id is not None:
            followed: dict | None = next((j for j in jobs if int(j["id"]) == mark.job_id), None)
            if followed is not None:
                self.on_job(followed)

    # ------------------------------------------------------------------ stale layers
    def enabled_stages(self) -> list[str]:
        """The session's stages in pipeline order (every stage when its config cannot be read)."""
        try:
            return enabled_stages(self.data.config)
        except ValueError:
            return list(STAGE_ORDER)

    def stage_stamps(self) -> dict[str, float]:
        """Stage -> creation time (Unix s) of the loaded manifest (0 when absent)."""
        return dict(zip(STAGES_READ, self.data.stamp, strict=False))

    def stage_durations(self) -> dict[str, float]:
        """Stage -> seconds its last run took (manifests' ``duration_s``): weights of the progress bar."""
        store = ArtifactStore(self.session_dir)
        out: dict[str, float] = {}
        for stage in self.enabled_stages():
            try:
                m = store.manifest(stage)
            except ValueError:
                m = None
            if m is not None and m.duration_s > 0:
                out[stage] = float(m.duration_s)
        return out

    def mark_stale(self, stale_from: str | None, job: dict | None, since_unix_s: float | None = None) -> None:
        """An edit made ``stale_from`` and every later stage stale; ``job`` re-runs them (None: no
        re-run queued). With an earlier mark still pending the earliest stage and the newest
        edit win (every stage after it must be rewritten after that edit)."""
        if stale_from is None:
            return
        since = time.time() if since_unix_s is None else since_unix_s
        jid = int(job["id"]) if job else None
        with self._stale_lock:
            if jid is not None:
                self._jobs_seen.add(jid)
            old = self.stale
            if old is not None and old.job_id == jid and old.since_unix_s >= since and jid is not None:
                return  # this viewer's own edit, seen again when polling the jobs
            if old is not None:
                first = min((old.stale_from, stale_from), key=STAGE_ORDER.index)
                self.stale = StaleMark(first, max(old.since_unix_s, since), jid if jid is not None else old.job_id,
                                       job or old.job)
            else:
                self.stale = StaleMark(stale_from, since, jid, job)
        self.refresh_layers()

    def on_job(self, job: dict) -> None:
        """A new state of the job the viewer waits for (its progress goes into the layer labels)."""
        with self._stale_lock:
            mark = self.stale
            if mark is None or mark.job_id != int(job["id"]) or mark.job == job:
                return
            mark.job = job
        self.refresh_layers()

    def layer_states(self) -> dict[str, str]:
        """Layer name -> "" when up to date, else why it is out of date (``webui.staleness``)."""
        with self._stale_lock:
            states = layer_states(self.enabled_stages(), self.stale, self.stage_stamps())
            if self.stale is not None and not any(states.values()):
                log.info("every layer is up to date again (re-run from %s)", self.stale.stale_from)
                self.stale = None
            return states

    def refresh_layers(self) -> None:
        """Push the layers' states to every view (labels, dimmed meshes and overlays)."""
        states = self.layer_states()
        for view in self.all_views():
            view.show_layers(states)

    def reload(self, views: list[ClientView] | None = None) -> None:
        """Re-read the artifacts and rebuild every view (or ``views``); frames and selections stay."""
        try:
            data = load_session_data(self.session_dir)
        except ValueError as e:
            log.warning("reload failed: %s", e)
            return
        with self._reload_lock:
            previous, self.data = self.data, data
            self.problems = compute_problems(data)
            self._attach_heavy(previous)
            self.reloads += 1
        states = self.layer_states()
        for view in views if views is not None else self.all_views():
            view.on_reload(states)
        log.info("reloaded the results (%d)", self.reloads)

    def close(self) -> None:
        self._stop.set()
        views = self.all_views()
        with self._views_lock:
            self.clients.clear()
        for view in views:
            view.close()
        if self.body_cache is not None:
            self.body_cache.stop()
        self.provider.close()


def run_viewer(
    session_dir: Path,
    api_url: str,
    port: int,
    host: str = "127.0.0.1",
    session_id: str | None = None,
    parent_pid: int | None = None,
    idle_s: float = 0.0,
    token: str = "",
) -> None:
    """Serve the viewer of ``session_dir`` until interrupted, until ``parent_pid`` exits, or (``idle_s`` > 0)
    until no client has been connected for ``idle_s`` seconds.

    With ``api_url``, clients are identified by the token their handshake carries
    (``webui.clients``); ``token`` (optional) is the user of clients that bring none.
    """
    identify = identify_with_api(api_url) if api_url else None
    default_user = None
    if identify is not None and token:
        try:
            default_user = identify(token)
        except ValueError as e:
            log.warning("--token refused by %s (%s): clients must bring their own", api_url, e)
    if identify is not None and session_id is None and default_user is not None and default_user.api is not None:
        session_id = default_user.api.find_session_id(session_dir)
    # Read the session before listening: the launcher takes "port open" as "viewer ready".
    data = load_session_data(Path(session_dir))
    server = viser.ViserServer(host=host, port=port, verbose=False)
    app = ViewerApp(server, Path(session_dir), session_id=session_id, data=data, identify=identify,
                    default_user=default_user)
    app.serve_clients()
    log.info("viewer of %s on http://%s:%d/ (idle stop after %s)", session_dir, host, port,
             f"{idle_s:g} s" if idle_s > 0 else "never")
    try:
        while True:
            time.sleep(1.0)
            # A viewer started by the server must not outlive it (even when the server is killed).
            if parent_pid is not None and not _alive(parent_pid):
                log.info("parent process %d is gone: stopping the viewer", parent_pid)
                break
            if idle_s > 0 and app.idle_for() > idle_s:
                log.info("no client for %.0f s: stopping the viewer", app.idle_for())
                break
    except KeyboardInterrupt:
        pass
    finally:
        app.close()
        server.stop()


def _stage_stamp(data: SessionData, stage: str) -> float:
    return data.stamp[STAGES_READ.index(stage)] if data.stamp else 0.0


def _alive(pid: int) -> bool:
    if os.getppid() != pid:  # re-parented: the launching process exited
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m webui.app", description="cornerman 3D review viewer (viser)")
    p.add_argument("--session-dir", type=Path, required=True)
    p.add_argument("--api-url", default="", help="base URL of the cornerman API (empty: read-only, no edits)")
    p.add_argument("--token", default=os.environ.get("CORNERMAN_VIEWER_TOKEN", ""),
                   help="bearer token for clients that bring none (or CORNERMAN_VIEWER_TOKEN); default: none, such clients are refused")
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--session-id", default=None)
    p.add_argument("--parent-pid", type=int, default=None, help="exit when this process (the launcher) exits")
    p.add_argument("--idle-s", type=float, default=0.0, help="exit after this many seconds without a client (0: never)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    run_viewer(args.session_dir, args.api_url, args.port, args.host, args.session_id, args.parent_pid, args.idle_s,
               args.token)


if __name__ == "__main__":
    main()
