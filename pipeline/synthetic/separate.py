"""Make the synthetic boxers physically plausible: no body passes through the other.

The choreography places arms and trunks by script (clinch grips, punches that land), so
left alone its bodies overlap by up to ~16 cm in clinches (``CapsuleProxy``: an average
adult's volumes, in boxing gloves). Ground truth that
interpenetrates would make the physics stage's inter-person term fight the very motion it
is scored against. ``separate_persons`` removes the overlap with position-based dynamics:

- contact: every pair of capsules of two different persons (``CapsuleProxy``, the same
  proxy the penetration metric uses, plus ``clearance_m``) is pushed apart along the
  line between their closest points, half per person, distributed over the segment's
  end joints by the closest point's position on the segment (minimum-norm correction;
  an end that is a midpoint or a fraction of two joints moves both, by the minimum-norm
  split of its weights);
- shape: the trunk (hips, shoulders), the head (nose, eyes, ears) and each foot (ankle,
  heel, toes) are projected back onto rigid copies of themselves (Kabsch), the limbs
  and the neck onto their lengths;
- planted feet (``pinned``) never move, so separation adds no foot skating;
- the correction field is smoothed over time between rounds (which aim ``smooth_margin_m``
  further out) so that the motion stays smooth, and a final round without smoothing
  leaves no overlap;
- in the smoothed rounds a pair of limb capsules (arms, gloves, legs) keeps its side of
  the other from frame to frame (``_consistent_normals``): where the choreography passes
  one arm through the other, the arm is held over (or under) it instead of being pushed
  each frame to whichever side is nearer, which zig-zagged elbows by up to 20 cm in a frame
  (accelerations of up to 200 mm/frame² that no physics could follow). Limbs still get
  past trunks and heads (the clinch grip takes a hand behind the opponent's back).

The ground truth's mean acceleration grows from 5.29 to 5.39 mm/frame² on the default bout
(seed 0; it grew from 5.26 to 5.89 with per-frame sides, before the clinch grip's detour
passed the arms on their own sides), and separation raises 5 joint accelerations by more
than 40 mm/frame² (at most 100). 150-frame bouts 0-3: 5.43-7.20 mm/frame² (5.36-7.02
before separation), 1-10 such joint accelerations per bout (38-46 with per-frame sides).

Pure numpy; ``make_bout`` applies it to the two boxers after their arms are placed.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from pipeline.evaluate.physics_metrics import CapsuleProxy
from pipeline.geometry.segments import point_weights, segment_closest_params, segment_distance
from pipeline.schema.joints import COCO17_FEET, PCP_LIMBS

_RIGID_GROUPS: tuple[tuple[str, ...], ...] = (
    ("left_hip", "right_hip", "left_shoulder", "right_shoulder"),
    ("nose", "left_eye", "right_eye", "left_ear", "right_ear"),
    ("left_ankle", "left_heel", "left_big_toe", "left_small_toe"),
    ("right_ankle", "right_heel", "right_big_toe", "right_small_toe"),
)
_LIMBS: tuple[tuple[str, str], ...] = tuple(b for b in PCP_LIMBS if b[0].split("_")[0] == b[1].split("_")[0])
"""Upper/lower arms and legs (the PCP limbs without the shoulder and hip lines)."""


def _end_joints(name: str, names: tuple[str, ...]) -> tuple[list[int], np.ndarray]:
    """Joints and weights of a capsule end (``geometry.segments.point_weights``)."""
    idx, w = point_weights(name, names)
    return idx, np.asarray(w, dtype=float)


def _end_points(x: np.ndarray, end: tuple[list[int], np.ndarray]) -> np.ndarray:
    idx, w = end
    return np.einsum("fjk,j->fk", x[:, idx], w)


def _kabsch_project(cur: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(F, n, 3): the rigid copy of ``ref`` closest to ``cur`` (per frame)."""
    mc, mr = cur.mean(axis=1, keepdims=True), ref.mean(axis=1, keepdims=True)
    H = np.einsum("fni,fnj->fij", ref - mr, cur - mc)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("fij,fjk->fik", U, Vt)))
    D = np.zeros_like(H)
    D[:, 0, 0], D[:, 1, 1], D[:, 2, 2] = 1.0, 1.0, d
    R = np.einsum("fji,fjk,fkl->fil", Vt, D, np.transpose(U, (0, 2, 1)))  # V D U^T
    return np.einsum("fij,fnj->fni", R, ref - mr) + mc


End = tuple[list[int], np.ndarray]


def _capsule_ends(x: np.ndarray, segs: list[tuple[End, End, float]]) -> tuple[np.ndarray, np.ndarray]:
    """(F, S, 3) first and second end points of every capsule of one person."""
    return (
        np.stack([_end_points(x, ia) for ia, _, _ in segs], axis=1),
        np.stack([_end_points(x, ib) for _, ib, _ in segs], axis=1),
    )


def _contact_round(
    x: np.ndarray, free: np.ndarray, proxy: CapsuleProxy, clearance_m: float, names: tuple[str, ...], consistent: bool = True
) -> float:
    """One Jacobi round of contact corrections in place (all capsule pairs at once);
    returns the deepest overlap including ``clearance_m`` (m; 0 = every pair clear)."""
    F, P, J = x.shape[:3]
    segs = [(_end_joints(a, names), _end_joints(b, names), r) for a, b, r in proxy.segments]
    S = len(segs)
    radii = np.array([r for _, _, r in segs])
    limb = np.array([any(j in a + b for j in _LIMB_JOINTS) for a, b, _ in proxy.segments])
    limb_pair = limb[:, None] & limb[None, :]
    # (S, J) share of a capsule end's displacement that joint j takes: the minimum-norm
    # joint displacements that move the end point (sum_j w_j x_j) by a given vector, w_j /
    # sum(w^2) each (a midpoint end moves both its joints by the full vector).
    e0 = np.zeros((S, J))
    e1 = np.zeros((S, J))
    for k, ((ia, wa), (ib, wb), _) in enumerate(segs):
        np.add.at(e0[k], ia, wa / np.sum(wa**2))
        np.add.at(e1[k], ib, wb / np.sum(wb**2))
    corr = np.zeros_like(x)
    cnt = np.zeros(x.shape[:3])
    deepest = 0.0
    for p in range(P):
        for q in range(p + 1, P):
            a0, a1 = _capsule_ends(x[:, p], segs)
            b0, b1 = _capsule_ends(x[:, q], segs)
            A0, A1 = a0[:, :, None], a1[:, :, None]  # (F, S, 1, 3)
            B0, B1 = b0[:, None], b1[:, None]  # (F, 1, S, 3)
            s, t = segment_closest_params(A0, A1, B0, B1)  # (F, S, S)
            diff = (A0 + (A1 - A0) * s[..., None]) - (B0 + (B1 - B0) * t[..., None])
            dist = np.linalg.norm(diff, axis=-1)
            reach = radii[:, None] + radii[None, :] + clearance_m
            pen = reach - dist
            if not (pen > 0).any():
                continue
            fallback = (a0[:, 0] - b0[:, 0])[:, None, None, :]
            n = np.where((dist > 1e-9)[..., None], diff, fallback)
            n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-9)
            if consistent:  # a pair held on its side travels its distance back plus the overlap
                pen = np.where(_consistent_normals(n, dist, reach, limb_pair), reach + dist, pen)
            hit = pen > 0
            deepest = max(deepest, float(pen[hit].max()))
            push = np.where(hit[..., None], 0.5 * pen[..., None] * n, 0.0)  # (F, S, S, 3) for p; -push for q
            for who, delta, par, axis in ((p, push, s, 2), (q, -push, t, 1)):
                w0, w1 = 1.0 - par, par
                norm = np.maximum(w0**2 + w1**2, 1e-9)
                # per capsule of ``who``: sum over the other person's capsules
                d0 = (delta * (w0 / norm)[..., None] * hit[..., None]).sum(axis=axis)  # (F, S, 3)
                d1 = (delta * (w1 / norm)[..., None] * hit[..., None]).sum(axis=axis)
                h = hit.sum(axis=axis).astype(float)  # (F, S)
                corr[:, who] += np.einsum("fsk,sj->fjk", d0, e0) + np.einsum("fsk,sj->fjk", d1, e1)
                cnt[:, who] += h @ (e0 != 0).astype(float) + h @ (e1 != 0).astype(float)
    step = np.where(cnt[..., None] > 0, corr / np.maximum(cnt, 1)[..., None], 0.0)
    x += np.where(free[..., None], step, 0.0)
    return deepest


SIDE_BAND_M = 0.05
"""Capsule pairs closer than this beyond touching keep their side into the next frame."""
SIDE_HOLD_M = 0.15
"""How far (beyond touching) a pair is held on its side after the input crossed over."""


_LIMB_JOINTS: tuple[str, ...] = ("elbow", "wrist", "knee", "ankle")
"""A capsule with an end at one of these joints is a limb (arms, gloves, legs)."""


def _consistent_normals(n: np.ndarray, dist: np.ndarray, reach: np.ndarray, limb_pair: np.ndarray) -> np.ndarray:
    """Keep each capsule pair's push direction (F, S, S, 3) on one side from frame to
    frame, in place. Where a pair was near (within ``SIDE_BAND_M`` of touching, on its
    side) in the frame before and its closest-point direction reversed (two crossing
    segments: the line between their closest points flips as one passes the other), it
    keeps the previous frame's side, up to ``SIDE_HOLD_M`` beyond touching. Pushing each
    frame towards its own nearer side sends a limb over the other arm in one frame and
    under it in the next: a zig-zag of up to 20 cm per frame that no body can follow.
    Only pairs of two limbs (``limb_pair`` (S, S)) keep their side: a hand that the
    choreography takes around the other boxer's back (the clinch grip) must get past his
    trunk. ``dist`` (F, S, S) are the pairs' distances, ``reach`` (S, S) their radii sums
    (plus clearance). Returns the (F, S, S) mask of reversed directions."""
    flipped = np.zeros(dist.shape, dtype=bool)
    side_dist = dist[0].copy()  # signed: negative on the far side of the other segment
    for f in range(1, n.shape[0]):
        was_near = side_dist < reach + SIDE_BAND_M
        flipped[f] = limb_pair & was_near & (np.sum(n[f] * n[f - 1], axis=-1) < 0.0) & (dist[f] < reach + SIDE_HOLD_M)
        n[f][flipped[f]] *= -1.0
        side_dist = np.where(flipped[f], -dist[f], dist[f])
    return flipped


def _shape_round(x: np.ndarray, x0: np.ndarray, free: np.ndarray, names: tuple[str, ...]) -> None:
    """Project rigid groups and limb lengths back onto the input's shapes, in place."""
    for group in _RIGID_GROUPS:
        idx = [names.index(n) for n in group if n in names]
        for p in range(x.shape[1]):
            target = _kabsch_project(x[:, p, idx], x0[:, p, idx])
            movable = np.asarray(free[:, p, idx].all(axis=1))  # a planted foot stays where it is
            x[:, p, idx] = np.where(movable[:, None, None], target, x[:, p, idx])
    for a, b in _LIMBS:
        ia, ib = names.index(a), names.index(b)
        length = np.linalg.norm(x0[:, :, ib] - x0[:, :, ia], axis=-1)
        d = x[:, :, ib] - x[:, :, ia]
        cur = np.maximum(np.linalg.norm(d, axis=-1), 1e-9)
        wa, wb = free[:, :, ia].astype(float), free[:, :, ib].astype(float)
        tot = np.maximum(wa + wb, 1e-9)
        err = ((cur - length) / cur)[..., None] * d
        x[:, :, ia] += (wa / tot)[..., None] * err
        x[:, :, ib] -= (wb / tot)[..., None] * err
    # Neck: head centre (mid-ears) at its distance from the mid-shoulder point.
    ears = [names.index("left_ear"), names.index("right_ear")]
    sh = [names.index("left_shoulder"), names.index("right_shoulder")]
    head = [names.index(n) for n in _RIGID_GROUPS[1]]
    length = np.linalg.norm(x0[:, :, ears].mean(2) - x0[:, :, sh].mean(2), axis=-1)
    d = x[:, :, ears].mean(2) - x[:, :, sh].mean(2)
    cur = np.maximum(np.linalg.norm(d, axis=-1), 1e-9)
    err = ((cur - length) / cur)[..., None] * d
    x[:, :, head] -= 0.5 * err[:, :, None]
    x[:, :, sh] += 0.5 * err[:, :, None]


def separate_persons(
    xyz: np.ndarray,
    pinned: np.ndarray,
    joint_names: tuple[str, ...] = COCO17_FEET,
    proxy: CapsuleProxy = CapsuleProxy(),
    clearance_m: float = 0.002,
    rounds: int = 4,
    iters: int = 25,
    smooth_frames: float = 4.0,
    smooth_margin_m: float = 0.02,
) -> np.ndarray:
    """(F, P, J, 3) joints with no capsule overlap between persons (see module docstring).

    ``pinned`` (F, P, J) bool marks joints that must not move (planted feet). Raises
    ``ValueError`` on inconsistent shapes.
    """
    if xyz.ndim != 4 or xyz.shape[2] != len(joint_names) or pinned.shape != xyz.shape[:3]:
        raise ValueError(
            f"separate_persons: xyz {xyz.shape} / pinned {pinned.shape} / {len(joint_names)} joints"
        )
    out = xyz.astype(np.float64).copy()
    near = _near_frames(out, joint_names, proxy, clearance_m)
    if smooth_frames > 0:  # let the smoothed correction fade in and out
        near = gaussian_filter1d(near.astype(float), 2 * smooth_frames, mode="constant") > 1e-3
    if not near.any():
        return out
    x0 = out[near]
    x = x0.copy()
    free = ~pinned[near]
    for r in range(rounds + 1):
        # Smoothed rounds aim further out, so that smoothing leaves little for the last,
        # unsmoothed round to fix (its corrections are the only non-smooth ones).
        aim = clearance_m + (smooth_margin_m if r < rounds else 0.0)
        for _ in range(iters):
            deepest = _contact_round(x, free, proxy, aim, joint_names, consistent=r < rounds)
            _shape_round(x, x0, free, joint_names)
            if deepest <= 0.0:
                break
        if r < rounds and smooth_frames > 0:
            disp = gaussian_filter1d(x - x0, smooth_frames, axis=0, mode="nearest")
            x = x0 + np.where(free[..., None], disp, 0.0)
            _shape_round(x, x0, free, joint_names)
    _exact_shape(x, x0, pinned[near], joint_names)
    out[near] = x
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _exact_shape(x: np.ndarray, x0: np.ndarray, pinned: np.ndarray, names: tuple[str, ...]) -> None:
    """Final projection making every rigid group and limb exactly its input shape, in place:
    rigid groups by Kabsch, the head at its neck length, arms from the shoulders outwards,
    free legs from the hips down (the foot follows its ankle), planted legs by two-bone IK
    (the knee moves, the foot stays)."""
    ix = {n: names.index(n) for n in names}
    for group in _RIGID_GROUPS:
        idx = [ix[n] for n in group]
        for p in range(x.shape[1]):
            movable = np.asarray(~pinned[:, p, idx].any(axis=1))
            x[:, p, idx] = np.where(
                movable[:, None, None], _kabsch_project(x[:, p, idx], x0[:, p, idx]), x[:, p, idx]
            )
    ears, sh = [ix["left_ear"], ix["right_ear"]], [ix["left_shoulder"], ix["right_shoulder"]]
    head = [ix[n] for n in _RIGID_GROUPS[1]]
    length = np.linalg.norm(x0[:, :, ears].mean(2) - x0[:, :, sh].mean(2), axis=-1)
    d = x[:, :, ears].mean(2) - x[:, :, sh].mean(2)
    x[:, :, head] += (_unit(d) * length[..., None] - d)[:, :, None]

    def place(a: int, b: int, carry: list[int]) -> None:
        length = np.linalg.norm(x0[:, :, b] - x0[:, :, a], axis=-1)[..., None]
        new = x[:, :, a] + _unit(x[:, :, b] - x[:, :, a]) * length
        delta = new - x[:, :, b]
        x[:, :, [b, *carry]] += delta[:, :, None]

    for side in ("left", "right"):
        place(ix[f"{side}_shoulder"], ix[f"{side}_elbow"], [ix[f"{side}_wrist"]])
        place(ix[f"{side}_elbow"], ix[f"{side}_wrist"], [])
        hip, knee, ankle = ix[f"{side}_hip"], ix[f"{side}_knee"], ix[f"{side}_ankle"]
        foot = [ix[f"{side}_{n}"] for n in ("heel", "big_toe", "small_toe")]
        planted = pinned[:, :, ankle]
        before = x.copy()
        place(hip, knee, [ankle, *foot])
        place(knee, ankle, foot)
        # Planted: keep the ankle, put the knee where both lengths hold (two-bone IK).
        l1 = np.linalg.norm(x0[:, :, knee] - x0[:, :, hip], axis=-1)
        l2 = np.linalg.norm(x0[:, :, ankle] - x0[:, :, knee], axis=-1)
        h, a_, k = before[:, :, hip], before[:, :, ankle], before[:, :, knee]
        axis = a_ - h
        dist = np.clip(np.linalg.norm(axis, axis=-1), 1e-9, l1 + l2 - 1e-9)
        u = _unit(axis)
        along = (dist**2 + l1**2 - l2**2) / (2 * dist)
        rad = np.sqrt(np.maximum(l1**2 - along**2, 0.0))
        perp = _unit((k - h) - np.sum((k - h) * u, axis=-1, keepdims=True) * u)
        knee_ik = h + u * along[..., None] + perp * rad[..., None]
        keep = planted[..., None]
        x[:, :, knee] = np.where(keep, knee_ik, x[:, :, knee])
        for j in (ankle, *foot):
            x[:, :, j] = np.where(keep, before[:, :, j], x[:, :, j])


def _near_frames(
    x: np.ndarray, names: tuple[str, ...], proxy: CapsuleProxy, clearance_m: float, reach_m: float = 0.15
) -> np.ndarray:
    """(F,) frames where two persons' capsules come within ``reach_m`` of touching."""
    segs = [(_end_joints(a, names), _end_joints(b, names), r) for a, b, r in proxy.segments]
    near = np.zeros(x.shape[0], dtype=bool)
    for p in range(x.shape[1]):
        for q in range(p + 1, x.shape[1]):
            for ia, ib, ri in segs:
                for ja, jb, rj in segs:
                    d = segment_distance(
                        _end_points(x[:, p], ia),
                        _end_points(x[:, p], ib),
                        _end_points(x[:, q], ja),
                        _end_points(x[:, q], jb),
                    )
                    near |= d < ri + rj + clearance_m + reach_m
    return near
