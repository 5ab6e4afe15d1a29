"""From 3D fragments to athlete identities: stitch fragments over gaps, keep the best supported.

A fragment ends when a person is lost by every camera for longer than
``max_missing_s``; when the person comes back a new fragment starts. Fragments are
stitched when the later one starts where the earlier one could have walked to in the
gap, or when they share a per-view track. The ``n_persons`` identities with the most
multi-view support over the whole sequence are the athletes; every other identity (a
referee, a bystander, a ghost from a wrong pairing) is "nobody" (``-1``).
"""

from __future__ import annotations

import numpy as np

from pipeline.stages.association.config import AssociateConfig
from pipeline.stages.association.tracker import Fragments


def stitch_fragments(frags: Fragments, tracklet: np.ndarray, fps: float, cfg: AssociateConfig) -> np.ndarray:
    """(frags,) identity index of each fragment (a union of time-disjoint fragments)."""
    n = frags.n_fragments
    ident = np.arange(n)
    if n <= 1:
        return ident
    # Fragment x tracklet co-occurrence (which per-view tracks each fragment used).
    sel = (frags.label >= 0) & (tracklet >= 0)
    share: dict[int, set[int]] = {}
    for k in range(n):
        share[k] = set(np.unique(tracklet[sel & (frags.label == k)]).tolist())
    order = np.argsort(frags.first_frame, kind="stable")
    tail = {int(k): int(k) for k in order}  # identity -> its latest fragment
    max_gap = cfg.merge_max_gap_s * fps
    for b in order[1:]:
        best, best_key = -1, (np.inf, np.inf)
        for root, a in tail.items():
            if root == ident[b] or frags.last_frame[a] >= frags.first_frame[b]:
                continue
            gap = frags.first_frame[b] - frags.last_frame[a]
            if gap > max_gap:
                continue
            dist = float(np.linalg.norm(frags.first_centroid_m[b] - frags.last_centroid_m[a]))
            shared = len(share[int(a)] & share[int(b)])
            reach = cfg.merge_slack_m + cfg.merge_speed_mps * gap / fps
            if shared == 0 and dist > reach:
                continue
            key = (-shared, dist)
            if key < best_key:
                best, best_key = root, key
        if best >= 0:
            ident[b] = best
            tail.pop(int(b), None)
            tail[best] = int(b)
    return ident


def rig_focus_m(centers_m: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """The point closest (least squares) to every camera's optical axis: where the rig looks.

    centers_m: (views, 3) camera centres; axes: (views, 3) unit viewing directions.
    """
    M = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    A = M.sum(axis=0)
    b = np.einsum("vij,vj->i", M, centers_m)
    if np.linalg.cond(A) > 1e8:  # parallel axes (one camera, or a stereo pair): no focus point
        return centers_m.mean(axis=0) + axes.mean(axis=0)
    return np.linalg.solve(A, b)


def select_athletes(
    frags: Fragments,
    ident: np.ndarray,
    n_persons: int,
    min_support_frames: int,
    focus_m: np.ndarray,
    support_tolerance: float,
) -> np.ndarray:
    """(frags,) athlete id ``0..n_persons-1`` of each fragment, or -1.

    Support = frames seen in >= 2 views, summed over an identity's fragments. Identities
    within ``support_tolerance`` (relative) of the best support are ranked by their mean
    horizontal distance to the rig's focus point (athletes are what the cameras frame; a
    referee circles around them); the rest by support. Athletes are then numbered by
    first appearance (ties: larger support first).
    """
    out = np.full(frags.n_fragments, -1, np.int64)
    if frags.n_fragments == 0:
        return out
    roots = np.unique(ident)
    support = np.array([frags.multiview_frames[ident == r].sum() for r in roots])
    first = np.array([frags.first_frame[ident == r].min() for r in roots])
    mean_c = np.array(
        [
            (frags.mean_centroid_m[ident == r] * frags.multiview_frames[ident == r, None]).sum(0)
            / max(1, frags.multiview_frames[ident == r].sum())
            for r in roots
        ]
    )
    dist = np.linalg.norm((mean_c - focus_m)[:, :2], axis=1)
    top_tier = support >= (1.0 - support_tolerance) * support.max()
    ranked = np.lexsort((dist, -np.where(top_tier, support.max(), support)))
    chosen = [int(i) for i in ranked[:n_persons] if support[i] >= min_support_frames]
    chosen.sort(key=lambda i: (first[i], -support[i]))
    for pid, i in enumerate(chosen):
        out[ident == roots[i]] = pid
    return out
