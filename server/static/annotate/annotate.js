"use strict";
// The annotate page (server/api/routes/annotate.py): one camera image with its detections, click
// to select, hotkeys, and every track/identity edit through the annotations API (same origin, the
// login cookie). No framework and no build step. Coordinates: detections come in pixels of the
// full camera image; the canvas holds the served JPEG, S.scale = canvas px per image px.
(() => {
  const root = document.getElementById("annotate");
  const SID = Number(root.dataset.session);
  const CAN_EDIT = root.dataset.canEdit === "1";
  const $ = (id) => document.getElementById(id);
  const canvas = $("view");
  const ctx = canvas.getContext("2d");
  const TERMINAL = ["done", "failed", "cancelled"];
  const S = {
    info: null, view: "", frame: 0, dets: [], img: null, scale: 1, seq: 0,
    sel: null, selSpan: null, selB: null, playing: false, redo: [], drag: null, armed: null,
    history: [], job: null, fromDirty: false, contactDirty: false,
  };

  class ApiError extends Error {
    constructor(status, detail) { super(detail); this.status = status; }
  }
  function detailOf(body, status) {
    if (body && typeof body.detail === "string") return body.detail;
    if (body && Array.isArray(body.detail)) {
      return body.detail.map((d) => `${(d.loc || []).slice(1).join(".")}: ${d.msg}`).join("; ");
    }
    return `HTTP ${status}`;
  }
  async function fetchOk(path, opts = {}) {
    const r = await fetch("/api" + path, {
      credentials: "same-origin", ...opts, headers: { "Content-Type": "application/json", ...(opts.headers || {}) },
    });
    if (!r.ok) {
      let body = null;
      try { body = await r.json(); } catch (e) { body = null; }
      throw new ApiError(r.status, detailOf(body, r.status));
    }
    return r;
  }
  const api = async (path, opts) => (await fetchOk(path, opts)).json();
  const post = (path, body) => api(path, { method: "POST", body: JSON.stringify(body) });
  const sleep = (ms) => new Promise((ok) => setTimeout(ok, ms));
  function showError(msg) { const e = $("error"); e.textContent = msg; e.hidden = !msg; }
  function status(msg) { $("status").textContent = msg; }
  const camera = () => S.info.cameras.find((c) => c.name === S.view);
  const el = (tag, props = {}, text = "") => {
    const e = Object.assign(document.createElement(tag), props);
    if (text) e.textContent = text;
    return e;
  };

  // ---------------------------------------------------------------- frame + detections
  // The width to ask for: what the stage shows (a portrait camera is bounded by the window's height),
  // in steps of 160 px so that scrubbing hits the server's cache.
  function displayWidth() {
    const cam = camera();
    const fitHeight = (window.innerHeight - 128) * cam.width_px / cam.height_px;
    const w = Math.min($("stage").clientWidth, fitHeight) * (window.devicePixelRatio || 1);
    return Math.max(320, Math.min(cam.width_px, Math.ceil(w / 160) * 160));
  }

  async function show(frame) {
    frame = Math.max(0, Math.min(S.info.n_frames - 1, Math.round(frame)));
    const seq = ++S.seq;
    S.frame = frame;
    $("frame").value = frame;
    $("frame-num").textContent = frame;
    followFrame();
    const base = `/sessions/${SID}`;
    const v = encodeURIComponent(S.view);
    try {
      const [blob, dets] = await Promise.all([
        fetchOk(`${base}/frames/${v}/${frame}.jpg?max_width=${displayWidth()}`).then((r) => r.blob()),
        api(`${base}/detections?view=${v}&frame=${frame}`),
      ]);
      const img = await createImageBitmap(blob);
      if (seq !== S.seq) { img.close(); return; }
      if (S.img) S.img.close();
      S.img = img;
      S.dets = dets.detections;
      S.scale = img.width / camera().width_px;
      draw();
      describe();
      history.replaceState(null, "", `#${encodeURIComponent(S.view)}/${frame}`);
      root.dataset.view = S.view;  // what the canvas shows (tests wait on these)
      root.dataset.frame = String(frame);
    } catch (e) {
      if (seq === S.seq) showError(e.message);
    }
  }

  function keypointsOf(d) {
    const kp = d.keypoints_px.slice();
    if (S.drag && S.drag.moved && d.track === S.sel) kp[S.drag.joint] = [S.drag.x / S.scale, S.drag.y / S.scale];
    return kp;
  }

  function draw() {
    if (!S.img) return;
    canvas.width = S.img.width;
    canvas.height = S.img.height;
    ctx.drawImage(S.img, 0, 0);
    const s = S.scale;
    const lw = Math.max(1, canvas.width / 800);
    ctx.font = `${Math.round(12 * lw)}px system-ui, sans-serif`;
    for (const d of S.dets) {
      const sel = S.sel !== null && d.track === S.sel;
      const selB = S.selB !== null && d.track === S.selB;
      const [x0, y0, x1, y1] = d.box_xyxy_px.map((c) => c * s);
      ctx.strokeStyle = d.color;
      ctx.lineWidth = (sel ? 3.5 : 1.5) * lw;
      ctx.setLineDash(selB ? [8 * lw, 5 * lw] : []);
      ctx.strokeRect(x0, y0, x1 - x0, y1 - y0);
      ctx.setLineDash([]);
      if (sel) {
        ctx.strokeStyle = "#fff";
        ctx.lineWidth = lw;
        ctx.strokeRect(x0 - 4 * lw, y0 - 4 * lw, x1 - x0 + 8 * lw, y1 - y0 + 8 * lw);
      }
      const kp = keypointsOf(d);
      ctx.strokeStyle = d.color;
      ctx.lineWidth = 2 * lw;
      for (const [a, b] of S.info.bones) {
        if (!kp[a] || !kp[b]) continue;
        ctx.beginPath();
        ctx.moveTo(kp[a][0] * s, kp[a][1] * s);
        ctx.lineTo(kp[b][0] * s, kp[b][1] * s);
        ctx.stroke();
      }
      kp.forEach((p, j) => {
        if (!p) return;
        ctx.beginPath();
        ctx.arc(p[0] * s, p[1] * s, (sel ? 4 : 2.5) * lw, 0, 2 * Math.PI);
        ctx.fillStyle = sel && S.armed === j ? "#fff" : d.color;
        ctx.fill();
      });
      const label = d.track >= 0 ? `#${d.track} ${d.name}` : "untracked";
      const tw = ctx.measureText(label).width;
      ctx.fillStyle = "rgba(0,0,0,.6)";
      ctx.fillRect(x0, y0 - 16 * lw, tw + 6 * lw, 16 * lw);
      ctx.fillStyle = d.color === "#969696" ? "#ddd" : d.color;
      ctx.fillText(label, x0 + 3 * lw, y0 - 4 * lw);
    }
  }

  function describe() {
    const box = $("selection");
    box.replaceChildren();
    if (S.sel === null) {
      box.textContent = "Click a detection to select it (shift+click: a second track, for a merge).";
    } else {
      const d = S.dets.find((x) => x.track === S.sel);
      if (!d) {
        box.textContent = `track #${S.sel} — not in this frame`;
      } else {
        const dot = el("span", { className: "dot" });
        dot.style.background = d.color;
        const conf = d.confidence === null ? "n/a" : d.confidence.toFixed(2);
        const who = d.person >= 0 ? `${d.name} (person ${d.person})` : "nobody / unassigned";
        box.append(dot, el("b", { id: "sel-track" }, `track #${d.track}`), ` · `, el("span", { id: "sel-person" }, who),
          ` · confidence `, el("span", { id: "sel-conf" }, conf), ` · frames ${d.track_frames[0]}–${d.track_frames[1]}`);
      }
    }
    $("selection-b").textContent = S.selB === null ? "" : `second track (merge): #${S.selB}`;
    if (CAN_EDIT) {
      $("merge-a").value = S.sel === null ? "" : S.sel;
      $("merge-b").value = S.selB === null ? "" : S.selB;
    }
  }

  // ---------------------------------------------------------------- mouse
  function toCanvas(ev) {
    const r = canvas.getBoundingClientRect();
    return [(ev.clientX - r.left) * canvas.width / r.width, (ev.clientY - r.top) * canvas.height / r.height];
  }
  function hitDetection(x, y) {
    let best = null;
    let area = Infinity;
    for (const d of S.dets) {
      const [x0, y0, x1, y1] = d.box_xyxy_px.map((c) => c * S.scale);
      const a = (x1 - x0) * (y1 - y0);
      if (x >= x0 && x <= x1 && y >= y0 && y <= y1 && a < area) { best = d; area = a; }
    }
    return best;
  }
  function hitJoint(x, y) {
    const d = S.dets.find((q) => q.track === S.sel);
    if (!d) return null;
    const r = 10 * Math.max(1, canvas.width / 800);
    let best = null;
    let dist = r;
    d.keypoints_px.forEach((p, j) => {
      if (!p) return;
      const e = Math.hypot(p[0] * S.scale - x, p[1] * S.scale - y);
      if (e < dist) { best = j; dist = e; }
    });
    return best;
  }
  function select(track, span) {
    S.sel = track;
    S.selSpan = span;
    S.armed = null;
    draw();
    describe();
  }

  canvas.addEventListener("mousedown", (ev) => {
    if (!CAN_EDIT || S.sel === null || ev.shiftKey || S.armed !== null) return;  // armed: this click places it
    const [x, y] = toCanvas(ev);
    const j = hitJoint(x, y);
    if (j !== null) S.drag = { joint: j, x, y, x0: x, y0: y, moved: false };
  });
  canvas.addEventListener("mousemove", (ev) => {
    if (!S.drag) return;
    [S.drag.x, S.drag.y] = toCanvas(ev);
    S.drag.moved = S.drag.moved || Math.hypot(S.drag.x - S.drag.x0, S.drag.y - S.drag.y0) > 3;
    if (S.drag.moved) draw();
  });
  canvas.addEventListener("mouseup", (ev) => {
    const [x, y] = toCanvas(ev);
    if (S.drag) {
      const { joint, moved } = S.drag;
      S.drag = null;
      if (moved) { fixKeypoint(joint, x, y); return; }
      arm(joint);
      return;
    }
    if (CAN_EDIT && S.armed !== null) { fixKeypoint(S.armed, x, y); return; }
    const d = hitDetection(x, y);
    if (ev.shiftKey) {
      S.selB = d ? d.track : null;
      draw();
      describe();
    } else {
      select(d ? d.track : null, d ? d.track_frames : null);
    }
  });

  // ---------------------------------------------------------------- edits
  async function submit(annotation) {
    showError("");
    try {
      const res = await post(`/sessions/${SID}/annotations`, { annotation, rerun: true });
      S.redo = [];
      status(`saved edit #${res.annotation.id} (${annotation.kind})${jobText(res)}`);
      afterChange(res);
      return res;
    } catch (e) {
      showError(e.message);
      return null;
    }
  }
  function jobText(res) {
    return res.job ? `; job #${res.job.id} re-runs from ${res.stale_from}` : res.stale_from ? `; stale from ${res.stale_from}` : "";
  }
  function afterChange(res) {
    refreshHistory();
    if (res.job) follow(res.job.id);
  }
  function needSel() {
    if (S.sel !== null) return true;
    showError("select a detection first (click it in the image)");
    return false;
  }
  const num = (id) => ($(id).value.trim() === "" ? null : Number($(id).value));

  function assign() {
    if (!needSel()) return;
    const span = S.selSpan || [S.frame, S.frame];
    const start = $("assign-from-here").checked ? Math.max(span[0], S.frame) : span[0];
    submit({ kind: "assign_identity", view: S.view, track: S.sel, frame_start: start, frame_end: span[1],
      person: Number($("person").value) });
  }
  async function swap() {
    const a = { kind: "swap_identities", frame: num("swap-from"), person_a: Number($("swap-a").value),
      person_b: Number($("swap-b").value), view: $("swap-view").value === "this" ? S.view : "" };
    const to = num("swap-to");
    if (to !== null) a.frame_end = to;
    if (await submit(a)) { S.fromDirty = false; followFrame(); }
  }
  const split = () => needSel() && submit({ kind: "split_track", view: S.view, track: S.sel, frame: S.frame });
  const invalid = () => needSel() && submit({ kind: "mark_invalid", view: S.view, frame: S.frame, track: S.sel });
  function merge() {
    const a = num("merge-a");
    const b = num("merge-b");
    if (a === null || b === null) { showError("merge needs two tracks: select one, shift+click the other"); return; }
    submit({ kind: "merge_tracks", view: S.view, track_a: a, track_b: b });
  }
  function arm(joint) {
    S.armed = joint;
    $("joint").value = String(joint);
    status(`joint ${S.info.joint_names[joint]} picked: click its new position (esc cancels)`);
    draw();
  }
  function fixKeypoint(joint, x, y) {
    S.armed = null;
    $("joint").value = "";
    if (!needSel()) return;
    const r2 = (v) => Math.round(v / S.scale * 100) / 100;
    submit({ kind: "fix_keypoint", view: S.view, frame: S.frame, track: S.sel, joint: S.info.joint_names[joint],
      x_px: r2(x), y_px: r2(y) });
    draw();
  }
  function contact() {
    submit({ kind: "label_contact", frame_start: num("contact-from"), frame_end: num("contact-to"),
      person_a: Number($("contact-a").value), part_a: $("contact-part-a").value.trim(),
      person_b: Number($("contact-b").value), part_b: $("contact-part-b").value.trim() });
  }
  function followFrame() {
    if (!CAN_EDIT) return;
    if (!S.fromDirty) $("swap-from").value = S.frame;
    if (!S.contactDirty) { $("contact-from").value = S.frame; $("contact-to").value = S.frame; }
  }

  // ---------------------------------------------------------------- history, undo, redo, jobs
  function frameOf(p) { return p.frame ?? p.frame_start ?? null; }
  async function refreshHistory() {
    try { S.history = await api(`/sessions/${SID}/annotations/history`); } catch (e) { showError(e.message); return; }
    const ol = $("history");
    ol.replaceChildren();
    for (const h of S.history) {
      const li = el("li", { id: `h${h.id}`, className: h.state });
      li.dataset.state = h.state;
      const summary = el("span", { className: "summary" }, `#${h.id} ${h.summary}`);
      const f = frameOf(h.payload);
      if (f !== null) {
        summary.classList.add("jump");
        summary.title = `go to frame ${f}`;
        summary.addEventListener("click", () => jump(h.payload));
      }
      const when = String(h.created_at).slice(0, 19).replace("T", " ");
      const state = h.state === "undone" && h.undone_by ? `undone by ${h.undone_by}` : h.state;
      li.append(summary, el("span", { className: "small" }, ` — ${h.author}, ${when} · `),
        el("span", { className: `state ${h.state}` }, state));
      if (CAN_EDIT && h.state === "active") {
        const b = el("button", { className: "link undo-btn" }, "undo");
        b.addEventListener("click", () => undoEntry(h.id));
        li.append(" ", b);
      } else if (CAN_EDIT && h.state === "undone") {
        const b = el("button", { className: "link redo-btn" }, "redo");
        b.addEventListener("click", () => redoEntry(h.id));
        li.append(" ", b);
      }
      ol.append(li);
    }
    if (!S.history.length) ol.append(el("li", { className: "small" }, "no edits yet"));
  }
  function jump(p) {
    if (p.view && p.view !== S.view && S.info.cameras.some((c) => c.name === p.view)) {
      S.view = p.view;
      $("camera").value = p.view;
      select(null, null);
    }
    show(frameOf(p));
  }
  async function undoEntry(id) {
    showError("");
    try {
      const res = await post(`/annotations/${id}/undo`, { rerun: true });
      S.redo = S.redo.filter((x) => x !== id).concat([id]);
      status(`undid edit #${id}${jobText(res)}`);
      afterChange(res);
    } catch (e) { showError(e.message); }
  }
  async function redoEntry(id) {
    showError("");
    try {
      const res = await post(`/annotations/${id}/redo`, { rerun: true });
      S.redo = S.redo.filter((x) => x !== id);
      status(`redid edit #${id} as #${res.annotation.id}${jobText(res)}`);
      afterChange(res);
    } catch (e) { showError(e.message); }
  }
  function undoNewest() {
    const h = S.history.find((x) => x.state === "active");
    if (h) undoEntry(h.id); else status("nothing to undo");
  }
  function redoLast() {
    const id = S.redo[S.redo.length - 1];
    if (id !== undefined) redoEntry(id); else status("nothing to redo (only edits undone on this page)");
  }
  async function follow(id) {
    S.job = id;
    while (S.job === id) {
      let j;
      try { j = await api(`/jobs/${id}`); } catch (e) { $("job").textContent = `job #${id}: ${e.message}`; return; }
      const err = j.error ? `: ${j.error.split("\n")[0]}` : "";
      $("job").textContent = `job #${id} ${j.status}${j.current_stage ? ` (${j.current_stage})` : ""}${err}`;
      if (TERMINAL.includes(j.status)) {
        if (j.status === "done") { await loadInfo(); await show(S.frame); refreshHistory(); }
        return;
      }
      await sleep(1000);
    }
  }

  // ---------------------------------------------------------------- playback, keys, setup
  function setPlaying(on) {
    S.playing = on;
    $("play").textContent = on ? "❚❚ pause" : "▶ play";
    if (on) playLoop();
  }
  async function playLoop() {
    while (S.playing) {
      const t0 = performance.now();
      if (S.frame >= S.info.n_frames - 1) { setPlaying(false); return; }
      await show(S.frame + 1);
      const wait = 1000 / S.info.fps - (performance.now() - t0);
      if (wait > 0) await sleep(wait);
    }
  }
  function step(n) { setPlaying(false); show(S.frame + n); }
  function choosePerson(digit) {
    const p = digit === 0 ? -1 : (S.info.persons[digit - 1] || {}).id;
    if (p === undefined) { status(`no person ${digit}`); return; }
    $("person").value = String(p);
    status(`person: ${$("person").selectedOptions[0].textContent}`);
  }

  document.addEventListener("keydown", (ev) => {
    const t = ev.target;
    const typing = t instanceof HTMLSelectElement || t instanceof HTMLTextAreaElement
      || (t instanceof HTMLInputElement && t.type !== "range" && t.type !== "checkbox");
    if (typing) { if (ev.key === "Escape") t.blur(); return; }
    const k = ev.key;
    const ctrl = ev.ctrlKey || ev.metaKey;
    if (k === "ArrowLeft" || k === "ArrowRight") step((k === "ArrowLeft" ? -1 : 1) * (ev.shiftKey ? 10 : 1));
    else if (k === " ") setPlaying(!S.playing);
    else if (k === "Escape") { S.selB = null; S.armed = null; $("status").textContent = ""; select(null, null); }
    else if (!CAN_EDIT) return;
    else if (ctrl && k.toLowerCase() === "z") { if (ev.shiftKey) redoLast(); else undoNewest(); }
    else if (ctrl && k.toLowerCase() === "y") redoLast();
    else if (ctrl || ev.altKey) return;
    else if (/^[0-9]$/.test(k)) choosePerson(Number(k));
    else if (k === "a") assign();
    else if (k === "s") swap();
    else if (k === "u") undoNewest();
    else if (k === "x") invalid();
    else if (k === "k") split();
    else if (k === "m") merge();
    else return;
    ev.preventDefault();
  });
  // a clicked button keeps no focus, so that space and the arrows stay hotkeys
  document.addEventListener("click", (ev) => { if (ev.target instanceof HTMLButtonElement) ev.target.blur(); });

  function options(select, persons, withNobody) {
    const keep = select.value;
    select.replaceChildren();
    persons.forEach((p, i) => select.append(el("option", { value: String(p.id) }, `${i < 9 ? `${i + 1}: ` : ""}${p.name}`)));
    if (withNobody) select.append(el("option", { value: "-1" }, "0: nobody"));
    if ([...select.options].some((o) => o.value === keep)) select.value = keep;
  }
  async function loadInfo() {
    S.info = await api(`/sessions/${SID}/frames`);
    const cams = $("camera");
    if (cams.options.length !== S.info.cameras.length) {
      cams.replaceChildren(...S.info.cameras.map((c) => el("option", { value: c.name }, c.name)));
    }
    $("frame").max = S.info.n_frames - 1;
    $("frame-count").textContent = S.info.n_frames - 1;
    if (!CAN_EDIT) return;
    const persons = S.info.persons;
    options($("person"), persons, true);
    for (const id of ["swap-a", "swap-b", "contact-a", "contact-b"]) options($(id), persons, false);
    if (persons.length > 1 && $("swap-a").value === $("swap-b").value) {
      $("swap-b").value = String(persons[1].id);
      $("contact-b").value = String(persons[1].id);
    }
    if ($("joint").options.length !== S.info.joint_names.length + 1) {
      $("joint").replaceChildren(el("option", { value: "" }, "joint…"),
        ...S.info.joint_names.map((n, j) => el("option", { value: String(j) }, n)));
      $("parts").replaceChildren(...["head", "torso", "left_glove", "right_glove", ...S.info.joint_names]
        .map((n) => el("option", { value: n })));
    }
  }
  function setCamera(name) {
    S.view = name;
    $("camera").value = name;
    const cam = camera();
    $("source").textContent = cam.video ? "video frames" : "no video: rendered stand-in";
  }

  async function init() {
    try { await loadInfo(); } catch (e) { showError(e.message); return; }
    const [hv, hf] = decodeURIComponent(location.hash.slice(1)).split("/");
    setCamera(S.info.cameras.some((c) => c.name === hv) ? hv : S.info.cameras[0].name);
    if (!S.info.tracks) status("no detections yet: run the track stage (and associate for identities)");
    $("camera").addEventListener("change", () => {
      setCamera($("camera").value);
      $("camera").blur();  // the arrows step frames again, not cameras
      S.selB = null;
      select(null, null);
      show(S.frame);
    });
    $("frame").addEventListener("input", () => { setPlaying(false); show(Number($("frame").value)); });
    $("prev").addEventListener("click", () => step(-1));
    $("next").addEventListener("click", () => step(1));
    $("play").addEventListener("click", () => setPlaying(!S.playing));
    let resize = null;
    window.addEventListener("resize", () => { clearTimeout(resize); resize = setTimeout(() => show(S.frame), 300); });
    if (CAN_EDIT) {
      const on = { assign, split, invalid, merge, swap, contact };
      for (const [id, fn] of Object.entries(on)) $(id).addEventListener("click", fn);
      $("swap-from").addEventListener("input", () => { S.fromDirty = true; });
      $("swap-from-here").addEventListener("click", () => { $("swap-from").value = S.frame; });
      $("swap-to-here").addEventListener("click", () => { $("swap-to").value = S.frame; });
      for (const id of ["contact-from", "contact-to"]) $(id).addEventListener("input", () => { S.contactDirty = true; });
      $("joint").addEventListener("change", () => {
        if ($("joint").value === "") return;
        if (needSel()) arm(Number($("joint").value)); else $("joint").value = "";
      });
      $("fix-cancel").addEventListener("click", () => { S.armed = null; $("joint").value = ""; status(""); draw(); });
    }
    await show(Number(hf) || 0);
    await refreshHistory();
    setInterval(() => { if (!document.hidden) refreshHistory(); }, 15000);  // edits made by others
  }
  init();
})();
