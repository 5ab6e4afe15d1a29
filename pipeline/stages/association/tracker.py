"""Frame-by-frame multi-view 3D tracking of every person (athletes and bystanders alike).

Frames are taken in short chunks (``assign_chunk_s``, a few frames). For each frame:

1. every live 3D person is predicted (constant centroid velocity) and projected into
   the views; the cost of a detection for a person is the confidence-weighted mean of the
   per-joint distances (clipped, relative to the box size);
2. one global assignment (``linear_sum_assignment``) over detections x (person, view)
   slots: at most one detection per person and view, costs above ``gate`` forbidden, and
   a small bonus for the person the detection's per-view track had before (a tie-breaker:
   when a per-view tracker swaps ids, geometry overrides it from the frame of the swap);
3. persons with two or more views are re-triangulated (weighted DLT); persons seen in a
   single view are moved in that view's image plane at their predicted depth;
4. unassigned detections propose new persons: every cross-view pair with a small pose
   epipolar distance is triangulated, each proposal is scored by how many views have a
   detection consistent with it, and the best ones are accepted greedily (one detection
   per view and person). This is the cycle-consistent step: a person is a set of
   detections that agree in 3D across all the views at once, not a chain of pairs.

The per-frame work is one small assignment; costs and triangulations are batched per
chunk (the loops are over frames and chunks, never over joints or detections); the result is a fragment label per detection plus per
fragment statistics for ``identities.select_identities``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from pipeline.geometry.dlt import triangulate_weighted
from pipeline.geometry.epipolar import fundamental_matrices, pose_epipolar_distance
from pipeline.schema.camera import CameraRig
from pipeline.stages.association.config import AssociateConfig
from pipeline.stages.association.prep import PreparedDets

_BIG = 1e6


@dataclass(frozen=True)
class Fragments:
    """Output of the tracker.

    Fields (``frags`` = number of 3D fragments):
        label: (dets,) fragment of each detection, -1 = unassigned.
        cost: (dets,) relative cost of the detection for its fragment (NaN if unassigned).
        cost_other: (dets,) best cost for any other live fragment (inf if none).
        first_frame, last_frame: (frags,) first/last frame with a detection.
        first_centroid_m, last_centroid_m: (frags, 3) world centroid there.
        multiview_frames: (frags,) frames in which the fragment was seen in >= 2 views.
        mean_centroid_m: (frags, 3) mean world centroid over those frames.
    """

    label: np.ndarray
    cost: np.ndarray
    cost_other: np.ndarray
    first_frame: np.ndarray
    last_frame: np.ndarray
    first_centroid_m: np.ndarray
    last_centroid_m: np.ndarray
    multiview_frames: np.ndarray
    mean_centroid_m: np.ndarray

    @property
    def n_fragments(self) -> int:
        return int(self.first_frame.shape[0])


class _State:
    """Growable arrays of the 3D persons (fragments)."""

    def __init__(self, n_joints: int) -> None:
        self.n = 0
        cap = 8
        self.X = np.zeros((cap, n_joints, 3))
        self.ok = np.zeros((cap, n_joints), bool)
        self.vel = np.zeros((cap, 3))
        self.last = np.zeros(cap, np.int64)
        self.alive = np.zeros(cap, bool)
        self.first = np.zeros(cap, np.int64)
        self.first_c = np.zeros((cap, 3))
        self.last_c = np.zeros((cap, 3))
        self.mv = np.zeros(cap, np.int64)
        self.sum_c = np.zeros((cap, 3))

    def add(self, X: np.ndarray, ok: np.ndarray, frame: int) -> int:
        if self.n == self.X.shape[0]:
            for name in ("X", "ok", "vel", "last", "alive", "first", "first_c", "last_c", "mv", "sum_c"):
                a = getattr(self, name)
                setattr(self, name, np.concatenate([a, np.zeros_like(a)]))
        k = self.n
        self.n += 1
        c = _centroid(X[None], ok[None])[0]
        self.X[k], self.ok[k], self.vel[k] = X, ok, 0.0
        self.last[k], self.alive[k], self.first[k] = frame, True, frame
        self.first_c[k] = c
        self.last_c[k] = c
        self.mv[k] = 1
        self.sum_c[k] = c
        return k


def _centroid(X: np.ndarray, ok: np.ndarray) -> np.ndarray:
    n = ok.sum(axis=-1, keepdims=True)
    return (X * ok[..., None]).sum(axis=-2) / np.maximum(n, 1)


def pose_costs(
    X: np.ndarray, ok: np.ndarray, rows: np.ndarray, prep: PreparedDets, cap: float, min_joints: int
) -> np.ndarray:
    """Relative reprojection cost (dets, persons) of 3D poses for detection rows.

    X: (persons, joints, 3) shared by all rows, or (dets, persons, joints, 3) per row.

    Cost = sum_j w_j min(d_j, cap) / sum_j w_j over joints present in both, with ``d_j``
    the image distance divided by the box size; ``inf`` with fewer than ``min_joints``.
    """
    Pd = prep.P[prep.view[rows]]  # (D, 3, 4)
    Xd = X if X.ndim == 4 else X[None]
    h = Xd @ np.swapaxes(Pd[:, None, :, :3], -1, -2) + Pd[:, None, None, :, 3]  # (D, A, J, 3)
    depth = h[..., 2]
    front = depth > 1e-6
    proj = h[..., :2] / np.where(front, depth, 1e-6)[..., None]
    d = np.linalg.norm(proj - prep.xn[rows][:, None], axis=-1) * prep.inv_scale[rows][:, None, None]
    wj = prep.w[rows][:, None, :] * (ok[None] & front)
    cnt = (wj > 0).sum(axis=-1)
    cost = (wj * np.minimum(d, cap)).sum(axis=-1) / np.maximum(wj.sum(axis=-1), 1e-12)
    return np.where(cnt >= min_joints, cost, np.inf)


def _triangulate_sets(prep: PreparedDets, sets_rows: np.ndarray, sets_ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate poses from sets of detections: sets_rows (S, views) rows (any where not ok)."""
    r = np.where(sets_ok, sets_rows, 0)
    uv = np.moveaxis(prep.xn[r], 1, 2)  # (S, J, V, 2)
    w = np.moveaxis(np.where(sets_ok[..., None], prep.w[r], 0.0), 1, 2)  # (S, J, V)
    return triangulate_weighted(prep.P, uv, w)


def track_fragments(prep: PreparedDets, rig: CameraRig, n_frames: int, cfg: AssociateConfig) -> Fragments:
    """Run the 3D multi-person tracker over all frames (see the module docstring).

    Frames are processed in short chunks (``cfg.assign_chunk_s``): the costs of every
    detection of the chunk against the persons predicted to its own frame are computed in
    one batch, the assignment is solved frame by frame, and the 3D states are refreshed
    once per chunk. A birth ends the chunk at its frame, so a new person takes part in the
    assignment from the next frame on.
    """
    n_dets, n_joints = prep.w.shape
    V = rig.n_views
    F = fundamental_matrices(rig)
    max_missing = max(1, int(round(cfg.max_missing_s * rig.fps)))
    max_step = cfg.max_speed_mps / rig.fps
    chunk = max(1, int(round(cfg.assign_chunk_s * rig.fps)))
    st = _State(n_joints)
    label = np.full(n_dets, -1, np.int64)
    cost_out = np.full(n_dets, np.nan)
    other_out = np.full(n_dets, np.inf)
    mem = np.full(max(prep.n_tracklets, 1), -1, np.int64)  # tracklet -> fragment it had last
    f0 = 0
    while f0 < n_frames:
        f1 = min(n_frames, f0 + chunk)
        st.alive[: st.n] &= (f0 - st.last[: st.n]) <= max_missing
        act = np.flatnonzero(st.alive[: st.n])
        A = act.size
        base = prep.starts[f0]
        rows_c = prep.order[base : prep.starts[f1]]
        if A and rows_c.size:
            dt = (prep.frame[rows_c][:, None] - st.last[act][None, :]).astype(float)  # (Dc, A)
            pred = st.X[act][None] + (dt[:, :, None] * st.vel[act][None])[:, :, None, :]
            cost_c = pose_costs(pred, st.ok[act], rows_c, prep, cfg.joint_cap, cfg.min_joints)
        done: list[tuple[np.ndarray, np.ndarray, int]] = []
        end = f1
        for f in range(f0, f1):
            lo, hi = prep.starts[f] - base, prep.starts[f + 1] - base
            if hi == lo:
                continue
            rows = rows_c[lo:hi]
            D = rows.size
            dv = prep.view[rows]
            assigned = np.full(D, -1, np.int64)
            if A:
                cost = cost_c[lo:hi]
                tl = prep.tracklet[rows]
                prev = np.where(tl >= 0, mem[np.maximum(tl, 0)], -1)
                adj = cost - cfg.track_bonus * (prev[:, None] == act[None, :])
                C = np.full((D, A * V), _BIG)
                C[np.arange(D)[:, None], np.arange(A)[None, :] * V + dv[:, None]] = np.where(cost <= cfg.gate, adj, _BIG)
                r, c = linear_sum_assignment(C)
                keep = C[r, c] < _BIG
                r, a = r[keep], c[keep] // V
                assigned[r] = act[a]
                cost_out[rows[r]] = cost[r, a]
                masked = cost.copy()
                masked[r, a] = np.inf
                other_out[rows] = masked.min(axis=1)
                done.append((rows[r], a, f))
            un = np.flatnonzero(assigned < 0)
            born = False
            if un.size >= cfg.birth_min_views and np.unique(dv[un]).size >= cfg.birth_min_views:
                for k, members in _births(st, prep, rows[un], F, f, cfg):
                    assigned[un[members]] = k
                    cost_out[rows[un[members]]] = 0.0
                    born = True
            label[rows] = assigned
            ok_t = (assigned >= 0) & (prep.tracklet[rows] >= 0)
            mem[prep.tracklet[rows][ok_t]] = assigned[ok_t]
            if born:
                end = f + 1
                break
        if done:
            _update(st, prep, done, act, max_step, V)
        f0 = end
    return Fragments(
        label=label,
        cost=cost_out,
        cost_other=other_out,
        first_frame=st.first[: st.n].copy(),
        last_frame=st.last[: st.n].copy(),
        first_centroid_m=st.first_c[: st.n] + prep.offset_m,
        last_centroid_m=st.last_c[: st.n] + prep.offset_m,
        multiview_frames=st.mv[: st.n].copy(),
        mean_centroid_m=st.sum_c[: st.n] / np.maximum(st.mv[: st.n], 1)[:, None] + prep.offset_m,
    )


def _update(
    st: _State,
    prep: PreparedDets,
    done: list[tuple[np.ndarray, np.ndarray, int]],
    act: np.ndarray,
    max_step: float,
    V: int,
) -> None:
    """Refresh the persons assigned in a chunk: ``done`` = [(rows, person index in act, frame)].

    Every (frame, person) with >= 2 views is triangulated in one batch; a person's state
    becomes its latest triangulation (velocity from the previous state's centroid). A person
    seen only in single views is moved in that view's image plane at its predicted depth.
    """
    A = act.size
    frames = np.array([f for _, _, f in done])
    K = frames.size
    sets_rows = np.zeros((K, A, V), np.int64)
    sets_ok = np.zeros((K, A, V), bool)
    for i, (rows, a, _) in enumerate(done):
        sets_rows[i, a, prep.view[rows]] = rows
        sets_ok[i, a, prep.view[rows]] = True
    nv = sets_ok.sum(axis=2)  # (K, A)
    ki, ai = np.nonzero(nv >= 2)  # sorted by frame, then person
    if ki.size:
        Xn, okn = _triangulate_sets(prep, sets_rows[ki, ai], sets_ok[ki, ai])
        cen = _centroid(Xn, okn)
        np.add.at(st.mv, act[ai], 1)
        np.add.at(st.sum_c, act[ai], cen)
        # Latest multi-view frame of each person (last occurrence in the frame-sorted list).
        uniq, rev = np.unique(ai[::-1], return_index=True)
        last = ki.size - 1 - rev
        k = act[uniq]
        f_last = frames[ki[last]]
        dt = np.maximum(f_last - st.last[k], 1)[:, None]
        c_old = _centroid(st.X[k], st.ok[k] & okn[last])
        v_new = (cen[last] - c_old) / dt
        speed = np.linalg.norm(v_new, axis=1, keepdims=True)
        v_new = v_new * np.minimum(1.0, max_step / np.maximum(speed, 1e-12))
        pred = st.X[k] + (st.vel[k] * dt)[:, None, :]
        st.vel[k] = 0.5 * st.vel[k] + 0.5 * v_new
        st.X[k] = np.where(okn[last][..., None], Xn[last], pred)
        st.ok[k] |= okn[last]
        st.last[k] = f_last
        st.last_c[k] = cen[last]
    multi_any = (nv >= 2).any(axis=0)
    ks, as_ = np.nonzero((nv == 1) & ~multi_any[None, :])
    if ks.size:
        uniq, rev = np.unique(as_[::-1], return_index=True)
        last = ks.size - 1 - rev
        fi, ai1 = ks[last], uniq
        k = act[ai1]
        v = np.argmax(sets_ok[fi, ai1], axis=1)
        row = sets_rows[fi, ai1, v]
        f_last = frames[fi]
        X = st.X[k] + (st.vel[k] * (f_last - st.last[k])[:, None])[:, None, :]
        P = prep.P[v]  # (S, 3, 4)
        depth = np.einsum("sk,sjk->sj", P[:, 2, :3], X) + P[:, 2, 3][:, None]
        ray = np.concatenate([prep.xn[row], np.ones(prep.xn[row].shape[:-1] + (1,))], axis=-1)
        Xc = ray * depth[..., None] - P[:, None, :, 3]
        Xw = np.einsum("sij,ski->skj", P[:, :, :3], Xc)  # R^T (x - t)
        use = (prep.w[row] > 0) & (depth > 1e-6) & st.ok[k]
        st.X[k] = np.where(use[..., None], Xw, X)
        st.last[k] = f_last
        st.last_c[k] = _centroid(st.X[k], st.ok[k])


def _births(
    st: _State, prep: PreparedDets, rows: np.ndarray, F: np.ndarray, f: int, cfg: AssociateConfig
) -> list[tuple[int, np.ndarray]]:
    """New persons from unassigned detections ``rows`` of frame ``f``: [(fragment, member indices)]."""
    dv = prep.view[rows]
    i, j = np.triu_indices(rows.size, k=1)
    cross = dv[i] != dv[j]
    i, j = i[cross], j[cross]
    if i.size == 0:
        return []
    ri, rj = rows[i], rows[j]
    d_px, _ = pose_epipolar_distance(
        prep.uv_px[ri], prep.uv_px[rj], prep.w[ri], prep.w[rj], F[dv[i], dv[j]], cfg.min_joints
    )
    inv_size = prep.inv_scale[rows] / prep.focal_px[dv]  # 1 / box size in pixels
    rel = d_px * 0.5 * (inv_size[i] + inv_size[j])
    good = rel <= cfg.birth_epipolar
    if not good.any():
        return []
    i, j = i[good], j[good]
    V = prep.P.shape[0]
    S = i.size
    pair_rows = np.zeros((S, V), np.int64)
    pair_ok = np.zeros((S, V), bool)
    pair_rows[np.arange(S), dv[i]] = rows[i]
    pair_rows[np.arange(S), dv[j]] = rows[j]
    pair_ok[np.arange(S), dv[i]] = True
    pair_ok[np.arange(S), dv[j]] = True
    Xp, okp = _triangulate_sets(prep, pair_rows, pair_ok)
    cost = pose_costs(Xp, okp, rows, prep, cfg.joint_cap, cfg.min_joints).T  # (S, D)
    # support: views with a consistent detection
    per_view = np.full((S, V), np.inf)
    for v in np.unique(dv):
        per_view[:, v] = cost[:, dv == v].min(axis=1)
    support = (per_view <= cfg.gate).sum(axis=1)
    score = np.where(np.isfinite(per_view) & (per_view <= cfg.gate), per_view, 0).sum(axis=1)
    order = np.lexsort((score / np.maximum(support, 1), -support))
    claimed = np.zeros(rows.size, bool)
    out: list[tuple[int, np.ndarray]] = []
    live = np.flatnonzero(st.alive[: st.n])
    live_c = _centroid(st.X[live], st.ok[live]) if live.size else np.zeros((0, 3))
    for s in order:
        if support[s] < cfg.birth_min_views or claimed[i[s]] or claimed[j[s]]:
            continue
        c = np.where(claimed[None, :] | (cost[s] > cfg.gate)[None, :], np.inf, cost[s][None, :])[0]
        members = [i[s], j[s]]
        for v in np.unique(dv):
            if v in (dv[i[s]], dv[j[s]]):
                continue
            cand = np.flatnonzero((dv == v) & np.isfinite(c))
            if cand.size:
                members.append(cand[np.argmin(c[cand])])
        if len(members) < cfg.birth_min_views:
            continue
        m = np.array(members)
        sr = np.zeros((1, V), np.int64)
        so = np.zeros((1, V), bool)
        sr[0, dv[m]] = rows[m]
        so[0, dv[m]] = True
        X, ok = _triangulate_sets(prep, sr, so)
        if ok[0].sum() < cfg.min_joints:
            continue
        cen = _centroid(X, ok)[0]
        if live_c.shape[0] and np.min(np.linalg.norm(live_c - cen, axis=1)) < cfg.duplicate_dist_m:
            continue
        claimed[m] = True
        k = st.add(X[0], ok[0], f)
        live_c = np.vstack([live_c, cen])
        out.append((k, m))
    return out
