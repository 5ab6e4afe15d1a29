"""The viewer: a viser app showing one session, with review and (for annotators) editing.

``python -m webui.app --session-dir DIR --api-url URL --token T --role R --port P``
(the token may instead come from ``CORNERMAN_VIEWER_TOKEN``, which keeps it out of ``ps``).
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

from webui.analysis import FrameProblems, compute_problems, compute_series
from webui.api_client import ApiClient, ApiError
from webui.colors import IdentityPalette
from webui.editing import (
    EditHistory,
    Selection,
    assign_edit,
    describe_selection,
    invalid_edit,
    split_edit,
    swap_edit,
)
from webui.events import EventsView
from webui.frames import FrameProvider, draw_overlay, overlay_for
from webui.jobs import JobWatcher, job_fraction, job_summary
from webui.panels.annotate import NO_TRACK, AnnotateHandles, make_annotate, parse_track_label, track_label
from webui.panels.display import label_to_source, make_display, source_options
from webui.panels.events import follow_frame, make_event_rows, make_events, set_events, wire_events
from webui.panels.export import make_export, wire_export
from webui.panels.plots import make_plots, update_plots
from webui.panels.timeline import make_timeline, set_problems
from webui.panels.views import make_views
from webui.scene.body import BodyMeshCache
from webui.scene.persons import DisplayOptions, PersonsScene
from webui.scene.physics_geoms import load_physics_geoms
from webui.scene.session_data import STAGES_READ, SessionData, artifacts_stamp, load_session_data
from webui.scene.world import add_world, align_client_camera

log = logging.getLogger(__name__)

EDIT_ROLES = ("annotator", "admin")


class ViewerApp:
    """State and wiring of one viewer (one session, one role)."""

    def __init__(
        self,
        server: viser.ViserServer,
        session_dir: Path,
        api: ApiClient | None = None,
        session_id: str | None = None,
        role: str = "coach",
        max_image_width: int = 400,
        data: SessionData | None = None,
    ) -> None:
        self.server, self.api, self.session_id, self.role = server, api, session_id, role
        self.session_dir = Path(session_dir)
        self.max_image_width = max_image_width
        self.frame = 0
        self.reloads = 0
        self._stop = threading.Event()
        self._render_wanted = threading.Event()
        self._reload_lock = threading.Lock()
        self._watchers: list[JobWatcher] = []
        self.history = EditHistory(api, session_id) if (api is not None and session_id is not None) else None

        self.data: SessionData = data if data is not None else load_session_data(self.session_dir)
        self.palette = self._load_palette()
        self.provider = FrameProvider(self.data, max_width=max_image_width)
        self.problems: FrameProblems = compute_problems(self.data)
        server.gui.configure_theme(control_width="large", dark_mode=False)
        self.world = add_world(server, self.data.rig)
        # Start from the red corner's side, above the ropes, looking at where the athletes are.
        c = self._action_centre()
        server.initial_camera.position = (c[0] - 4.0, c[1] - 3.2, 2.8)
        server.initial_camera.look_at = (c[0], c[1], 1.0)
        server.initial_camera.up = (0.0, 0.0, 1.0)

        server.gui.add_markdown(f"**{self.data.config.name}** — {self._legend()}")
        self.timeline = make_timeline(server, self.data.n_frames)
        everyone = [(p, self.palette.name(p)) for p in (self.data.person_ids or [0, 1])]
        event_rows = make_event_rows(server, everyone, self.data.n_frames)
        tabs = server.gui.add_tab_group()
        with tabs.add_tab("Cameras"):
            sizes = []
            for v in range(self.data.rig.n_views):
                s = self.provider.scale(v)
                w, h = (int(x) for x in self.data.rig.image_size_wh[v])
                sizes.append((max(1, round(w * s)), max(1, round(h * s))))
            self.views = make_views(server, self.data.camera_names, sizes)
        self.annotate: AnnotateHandles | None = None
        if self.can_edit:
            with tabs.add_tab("Edit"):
                athletes = [(p, self.palette.name(p)) for p in (self.data.person_ids or [0, 1])[:2]]
                self.annotate = make_annotate(server, self.data.camera_names, athletes)
        with tabs.add_tab("Plots"):
            self.plots = make_plots(server, compute_series(self.data, self._default_source()), self.palette)
        with tabs.add_tab("Events"):
            self.events = make_events(server, [n for _, n in everyone], event_rows)
        with tabs.add_tab("Display"):
            self.display = make_display(server, list(self.data.keypoints))
        with tabs.add_tab("Export"):
            self.export = make_export(server)
        self.opts = DisplayOptions(source=label_to_source(self.display.source.value))
        self.persons = PersonsScene(server, self.data, self.palette)
        self._attach_heavy()
        self.persons.build()
        set_problems(self.timeline, self.problems, self.data.n_frames)
        set_events(self.events, self.events_view(), self.data.n_frames)
        self._wire()
        self._threads = [
            threading.Thread(target=self._render_loop, name="render", daemon=True),
            threading.Thread(target=self._play_loop, name="play", daemon=True),
            threading.Thread(target=self._watch_loop, name="watch", daemon=True),
        ]
        for t in self._threads:
            t.start()
        self.request_render()

    # ------------------------------------------------------------------ state
    @property
    def can_edit(self) -> bool:
        return self.role in EDIT_ROLES and self.history is not None

    def _legend(self) -> str:
        ids = self.data.person_ids or [0, 1]
        idents = [i for i in (self.palette.get(p) for p in ids) if i is not None]
        return ", ".join(f"{i.name} = {i.color_hex}" for i in idents)

    def _load_palette(self) -> IdentityPalette:
        if self.api is not None and self.session_id is not None:
            try:
                return IdentityPalette.from_api(self.api.identities(self.session_id), self.data.config.athletes)
            except (ApiError, ValueError) as e:
                log.warning("identities from the API unavailable (%s): default colours", e)
        return IdentityPalette(None, self.data.config.athletes)

    def _action_centre(self) -> tuple[float, float]:
        """Median ground position of every valid 3D keypoint (the ring centre when there is none)."""
        for kp in self.data.keypoints.values():
            if kp.valid.any():
                xy = np.median(kp.xyz_m[kp.valid][:, :2], axis=0)
                return float(xy[0]), float(xy[1])
        return 0.0, 0.0

    def events_view(self) -> EventsView:
        names = {p: self.palette.name(p) for p in self.data.person_ids}
        return EventsView(self.data.events, self.data.series, names)

    def _default_source(self) -> str:
        for s in ("physics", "fit", "filtered"):
            if s in self.data.keypoints:
                return s
        return "filtered"

    def _attach_heavy(self, previous: SessionData | None = None) -> None:
        """Body meshes (torch, background thread) and physics geoms (mujoco), when present.

        After a reload, what the fit / physics stages did not rewrite is kept (posing every
        frame's mesh again would take seconds for nothing).
        """
        fit_same = previous is not None and _stage_stamp(previous, "fit") == _stage_stamp(self.data, "fit")
        phys_same = previous is not None and _stage_stamp(previous, "physics") == _stage_stamp(self.data, "physics")
        if not fit_same:
            if self.persons.body_cache is not None:
                self.persons.body_cache.stop()
            self.persons.body_cache = None
            bf = self.data.bodyfit
            smpl_path = str(self.data.config.stage_config.get("fit", {}).get("body_model_path", ""))
            if bf is not None and (bf.body_model == "anny" or smpl_path):
                cache = BodyMeshCache(bf, on_chunk=self.request_render, body_model_path=smpl_path)
                cache.start()
                self.persons.body_cache = cache
            elif bf is not None:
                log.info("%s fit: body meshes need the model files (fit.body_model_path); skeletons only", bf.body_model)
        if not phys_same:
            self.persons.physics_geoms = load_physics_geoms(self.data.physics_xml, self.data.physics)

    def selection(self) -> Selection:
        if self.annotate is None:
            return Selection(self.data.camera_names[0], None, self.frame)
        return Selection(self.annotate.view.value, parse_track_label(self.annotate.track.value), self.frame)

    # ------------------------------------------------------------------ rendering
    def request_render(self) -> None:
        self._render_wanted.set()

    def _render_loop(self) -> None:
        # Latest-wins: while one frame renders, further requests collapse into one.
        while not self._stop.is_set():
            if not self._render_wanted.wait(0.25):
                continue
            self._render_wanted.clear()
            try:
                self.render(self.frame)
            except Exception:  # keep the viewer alive; the traceback goes to the log
                log.exception("rendering frame %d failed", self.frame)

    def render(self, frame: int) -> None:
        """Draw ``frame`` everywhere: 3D persons, camera images, selection and info."""
        with self._reload_lock:
            data = self.data
            self.persons.update(frame, self.opts)
            sel_track = None
            if self.annotate is not None:
                self._refresh_track_options(frame)
                sel = self.selection()
                sel_track = sel.track
                names = {p: self.palette.name(p) for p in data.person_ids}
                self.annotate.selection.content = describe_selection(data, sel, names)
            images = self.provider.frames(frame)
            for v, name in enumerate(data.camera_names):
                img = images[v]
                ov = overlay_for(data, v, frame, self.opts.source)
                st = sel_track if (self.annotate is not None and self.annotate.view.value == name) else None
                draw_overlay(img, ov, self.provider.scale(v), self.palette, st)
                self.views.images[name].image = img
            kinds = self.problems.kinds_at(frame) if frame < self.problems.n_frames else []
            t = frame / data.fps
            flag = f" — ⚠ {', '.join(kinds)}" if kinds else ""
            self.timeline.info.content = f"frame {frame} / {data.n_frames - 1} ({t:.2f} s){flag}"

    def _refresh_track_options(self, frame: int) -> None:
        assert self.annotate is not None
        data = self.data
        v = data.rig.index(self.annotate.view.value)
        rows = data.det_rows(v, frame)
        opts = [NO_TRACK]
        if data.tracks is not None:
            for r, p in zip(rows, data.person_of_rows(rows), strict=True):
                tid = int(data.tracks.track_id[r])
                if tid >= 0:
                    opts.append(track_label(tid, self.palette.name(int(p))))
        current = parse_track_label(self.annotate.track.value)
        keep = next((o for o in opts[1:] if parse_track_label(o) == current), None) if current is not None else None
        if tuple(opts) != tuple(self.annotate.track.options):
            self.annotate.track.options = tuple(opts)
        # Keep the selected track while it is visible; otherwise select the first one.
        want = keep or (opts[1] if len(opts) > 1 else NO_TRACK)
        if self.annotate.track.value != want:
            self.annotate.track.value = want  # type: ignore[misc]

    # ------------------------------------------------------------------ loops
    def _play_loop(self) -> None:
        last = time.monotonic()
        acc = 0.0
        while not self._stop.is_set():
            time.sleep(0.02)
            now = time.monotonic()
            dt, last = now - last, now
            if not self.timeline.play.value:
                acc = 0.0
                continue
            acc += dt * self.data.fps * self.timeline.speed_factor
            step = int(acc)
            if step >= 1:
                acc -= step
                self.timeline.frame.value = (self.frame + step) % self.data.n_frames  # type: ignore[misc]

    def _watch_loop(self) -> None:
        """Reload when the artifacts change (a re-run started elsewhere, or a finished job)."""
        stamp = self.data.stamp
        while not self._stop.wait(2.0):
            try:
                now = artifacts_stamp(self.session_dir)
            except ValueError as e:
                log.warning("cannot read the artifacts: %s", e)
                continue
            if now != stamp:
                time.sleep(1.0)  # a multi-stage re-run writes several stages in a row
                stamp = artifacts_stamp(self.session_dir)
                if stamp != self.data.stamp:
                    self.reload()

    # ------------------------------------------------------------------ reload
    def reload(self) -> None:
        """Re-read the artifacts and rebuild what depends on them (keeps the frame and selection)."""
        try:
            data = load_session_data(self.session_dir)
        except ValueError as e:
            log.warning("reload failed: %s", e)
            return
        with self._reload_lock, self.server.atomic():
            previous, self.data = self.data, data
            self.problems = compute_problems(data)
            self.persons.data = data
            self._attach_heavy(previous)
            self.persons.build()
            self.display.source.options = source_options(list(data.keypoints))
            set_problems(self.timeline, self.problems, data.n_frames)
            set_events(self.events, self.events_view(), data.n_frames)
            update_plots(self.plots, compute_series(data, self.opts.source), self.palette)
            self.reloads += 1
        self.request_render()
        log.info("reloaded the results (%d)", self.reloads)

    # ------------------------------------------------------------------ callbacks
    def _wire(self) -> None:
        tl, disp = self.timeline, self.display

        @tl.frame.on_update
        def _(_: Any) -> None:
            self.frame = int(tl.frame.value)
            follow_frame(self.events, self.frame)
            self.request_render()

        def set_frame(f: int) -> None:
            tl.frame.value = f  # type: ignore[misc]

        wire_events(self.events, self.events_view, lambda: self.frame, set_frame, lambda: self.data.n_frames)
        wire_export(self.export, self.server, self.session_dir,
                    lambda: {p: self.palette.name(p) for p in self.data.person_ids}, lambda: self.opts.source)

        @tl.next_problem.on_click
        def _(_: Any) -> None:
            nxt = self.problems.next_after(self.frame, tl.kind)
            if nxt is not None:
                tl.frame.value = nxt  # type: ignore[misc]

        @disp.source.on_update
        def _(_: Any) -> None:
            self.opts.source = label_to_source(disp.source.value)
            update_plots(self.plots, compute_series(self.data, self.opts.source), self.palette)
            self.request_render()

        for cb in (disp.skeleton, disp.body, disp.physics):
            cb.on_update(lambda _: self._set_layers())

        @disp.reload.on_click
        def _(_: Any) -> None:
            self.reload()

        for v, name in enumerate(self.data.camera_names):
            self.views.align[name].on_click(self._aligner(v))
            self.world.cams[name].on_click(self._aligner(v))
        if self.annotate is not None:
            self._wire_annotate(self.annotate)

    def _set_layers(self) -> None:
        self.opts.show_skeleton = self.display.skeleton.value
        self.opts.show_body = self.display.body.value
        self.opts.show_physics = self.display.physics.value
        self.request_render()

    def _aligner(self, view: int) -> Any:
        def cb(event: Any) -> None:
            self._align(event.client, view)

        return cb

    def _align(self, client: viser.ClientHandle | None, view: int) -> None:
        targets = [client] if client is not None else list(self.server.get_clients().values())
        for c in targets:
            align_client_camera(c, self.data.rig, view)

    def _wire_annotate(self, a: AnnotateHandles) -> None:
        a.view.on_update(lambda _: self.request_render())
        a.track.on_update(lambda _: self.request_render())
        def assigner(pid: int) -> Any:
            def cb(_: Any) -> None:
                self._submit(lambda: assign_edit(self.data, self.selection(), pid, a.from_here.value))

            return cb

        for pid, button in a.assign.items():
            button.on_click(assigner(pid))
        ids = list(a.assign)

        def do_swap() -> Any:
            if len(ids) < 2:
                raise ValueError("a swap needs two athletes")
            return swap_edit(self.selection(), ids[0], ids[1], a.swap_scope.value == "all views")

        a.swap.on_click(lambda _: self._submit(do_swap))
        a.split.on_click(lambda _: self._submit(lambda: split_edit(self.selection())))
        a.invalid.on_click(lambda _: self._submit(lambda: invalid_edit(self.selection())))
        a.undo.on_click(lambda _: self._history_call("undo"))
        a.redo.on_click(lambda _: self._history_call("redo"))

    def _submit(self, make_edit: Any) -> None:
        assert self.history is not None and self.annotate is not None
        try:
            edit = make_edit()
            res = self.history.submit(edit)
        except (ApiError, ValueError) as e:
            self.annotate.status.content = f"Edit refused: {e}"
            return
        self._after_change(f"Saved {edit.kind} (annotation {res['annotation']['id']})", res)

    def _history_call(self, which: str) -> None:
        assert self.history is not None and self.annotate is not None
        try:
            res = self.history.undo() if which == "undo" else self.history.redo()
        except ApiError as e:
            self.annotate.status.content = f"{which} failed: {e}"
            return
        if res is None:
            self.annotate.status.content = f"Nothing to {which}."
            return
        self._after_change(f"{which.capitalize()} of annotation {res['annotation']['id']}", res)

    def _after_change(self, msg: str, res: dict) -> None:
        assert self.annotate is not None and self.api is not None
        a = self.annotate
        job = res.get("job")
        stale = res.get("stale_from")
        a.status.content = f"{msg}; stale from **{stale}**." + (" Re-run queued." if job else "")
        if not job:
            return
        a.progress.visible = True
        a.progress.value = 0.0  # type: ignore[misc]

        def on_update(j: dict) -> None:
            a.progress.value = 100.0 * job_fraction(j)  # type: ignore[misc]
            a.status.content = f"{msg}. {job_summary(j)}"

        def on_end(j: dict) -> None:
            a.progress.value = 100.0  # type: ignore[misc]
            if j.get("status") == "done":
                self.reload()
                a.status.content = f"{msg}. {job_summary(j)} — results reloaded."
            else:
                a.status.content = f"{msg}. {job_summary(j)}"

        self._watchers.append(JobWatcher(self.api, job["id"], on_update, on_end).start())

    def close(self) -> None:
        self._stop.set()
        for w in self._watchers:
            w.stop()
        if self.persons.body_cache is not None:
            self.persons.body_cache.stop()
        self.provider.close()


def run_viewer(
    session_dir: Path,
    api_url: str,
    token: str,
    role: str,
    port: int,
    host: str = "127.0.0.1",
    session_id: str | None = None,
    parent_pid: int | None = None,
) -> None:
    """Serve the viewer of ``session_dir`` until interrupted (or until ``parent_pid`` exits).

    The role is re-checked with ``GET /api/me`` (the token decides, not the caller);
    the session id is looked up by folder when not given.
    """
    api = ApiClient(api_url, token) if api_url else None
    if api is not None:
        try:
            role = str(api.me().get("role", role))
            if session_id is None:
                session_id = api.find_session_id(session_dir)
        except (ApiError, ValueError) as e:
            log.warning("API at %s unusable (%s): read-only viewer", api_url, e)
            role = "coach"
    # Read the session before listening: the launcher takes "port open" as "viewer ready".
    data = load_session_data(Path(session_dir))
    server = viser.ViserServer(host=host, port=port, verbose=False)
    app = ViewerApp(server, Path(session_dir), api=api, session_id=session_id, role=role, data=data)
    log.info("viewer of %s for role %s on http://%s:%d/", session_dir, role, host, port)
    try:
        # A viewer started by the server must not outlive it (even when the server is killed).
        while parent_pid is None or _alive(parent_pid):
            time.sleep(1.0)
        log.info("parent process %d is gone: stopping the viewer", parent_pid)
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
    p.add_argument("--token", default=os.environ.get("CORNERMAN_VIEWER_TOKEN", ""), help="bearer token (or CORNERMAN_VIEWER_TOKEN)")
    p.add_argument("--role", default="coach", choices=["coach", "annotator", "admin"])
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--session-id", default=None)
    p.add_argument("--parent-pid", type=int, default=None, help="exit when this process (the launcher) exits")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    run_viewer(args.session_dir, args.api_url, args.token, args.role, args.port, args.host, args.session_id, args.parent_pid)


if __name__ == "__main__":
    main()
