"""From 3D fragments to athlete identities: stitch fragments over gaps, keep the best supported.

A fragment ends when a person is lost by every camera for longer than
``max_missing_s``; when the person comes back a new fragment starts. Fragments are
stitched when the later one starts where the earlier one could have walked to in the
gap, or when they share a per-view track. The identities with the most multi-view
support over the whole sequence are the persons (as many as the session asks for, or in
"auto" mode all that are seen long enough inside the capture volume); every other
identity (a referee, a bystander, a ghost from a wrong pairing) is "nobody" (``-1``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry.projection import project
from pipeline.schema.camera import CameraRig
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


def in_view_fraction(rig: CameraRig, points_m: np.ndarray) -> np.ndarray:
    """(n,) fraction of the rig's cameras in whose image each world point (n, 3) lands
    (in front of the camera, inside the image), in [0, 1]."""
    if points_m.shape[0] == 0:
        return np.zeros(0)
    uv, depth = project(rig, points_m, distort=False)
    wh = rig.image_size_wh[:, None, :].astype(np.float64)
    inside = (depth > 0) & np.all((uv >= 0) & (uv <= wh), axis=-1)
    return inside.mean(axis=0)


@dataclass(frozen=True)
class IdentityChoice:
    """Which stitched identities are persons.

    Fields:
        athlete: (frags,) person id ``0..n-1`` of each fragment, or -1.
        n_persons: number of persons chosen.
        bystanders: identities with enough support but outside the capture volume.
    """

    athlete: np.ndarray
    n_persons: int
    bystanders: int


def select_athletes(
    frags: Fragments,
    ident: np.ndarray,
    n_persons: int | None,
    rig: CameraRig,
    n_frames: int,
    cfg: AssociateConfig,
) -> IdentityChoice:
    """Choose the persons among the stitched identities.

    Support = frames seen in >= 2 views, summed over an identity's fragments. An identity
    whose mean position is in the field of view of fewer than ``cfg.bystander_view_frac``
    of the cameras is a bystander. With ``n_persons`` given, the ``n_persons`` best
    identities are chosen: bystanders last, then by support, and identities within
    ``support_tolerance`` (relative) of the best support by their mean horizontal distance
    to where the cameras look (athletes are what the cameras frame; a referee circles
    around them). With ``n_persons=None`` ("auto"), every non-bystander identity with
    support >= ``min(auto_min_support_s, auto_min_support_frac x bout)`` is chosen.
    Persons are numbered by first appearance (ties: larger support first).
    """
    out = np.full(frags.n_fragments, -1, np.int64)
    if frags.n_fragments == 0:
        return IdentityChoice(out, 0, 0)
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
    focus = rig_focus_m(rig.centers_world_m, rig.T_world_cam[:, :3, 2])
    dist = np.linalg.norm((mean_c - focus)[:, :2], axis=1)
    bystander = in_view_fraction(rig, mean_c) < cfg.bystander_view_frac
    eligible = support >= cfg.min_support_frames
    if n_persons is None:
        need = min(cfg.auto_min_support_s * rig.fps, cfg.auto_min_support_frac * n_frames)
        chosen = [int(i) for i in np.flatnonzero(eligible & ~bystander & (support >= need))]
        n_bystanders = int(np.sum(eligible & bystander & (support >= need)))
    else:
        top_tier = support >= (1.0 - cfg.support_tolerance) * support.max()
        ranked = np.lexsort((dist, -np.where(top_tier, support.max(), support), bystander))
        chosen = [int(i) for i in ranked[:n_persons] if eligible[i]]
        n_bystanders = int(np.sum(eligible & bystander)) - int(np.sum(bystander[chosen]))
    chosen.sort(key=lambda i: (first[i], -support[i]))
    for pid, i in enumerate(chosen):
        out[ident == roots[i]] = pid
    return IdentityChoice(out, len(chosen), n_bystanders)
