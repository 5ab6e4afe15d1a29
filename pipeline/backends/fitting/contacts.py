"""Overlap between athletes as a term of the kinematic fit (torch).

The athletes' volumes are the fit's own capsule proxy, ``FIT_BODY_CAPSULES``, around
their keypoints (an average adult in boxing gloves). In clinches and exchanges the 2D
evidence of an arm hidden behind the other athlete is weak, and the fit let arms pass
through each other and through the other's trunk (the synthetic bench: up to 10 cm). The
term is the squared depth of every overlap between capsules of two different persons,
summed over frames where both are present.

The evaluation scores penetration with its own proxy
(``pipeline.evaluate.physics_metrics.CapsuleProxy``, the same radii today); the fit does
not import it, so changing the scored volumes does not change what the fit optimises.
Both take the segment geometry from ``pipeline.geometry.segments``.
"""

from __future__ import annotations

import torch

from pipeline.geometry.segments import point_weights, segment_closest_params
from pipeline.schema.joints import COCO17_FEET

FIT_BODY_CAPSULES: tuple[tuple[str, str, float], ...] = (
    ("frac:right_hip,left_hip,0.8", "frac:right_shoulder,left_shoulder,0.7", 0.11),
    ("frac:left_hip,right_hip,0.8", "frac:left_shoulder,right_shoulder,0.7", 0.11),
    ("left_hip", "right_hip", 0.11),
    ("mid:left_ear+right_ear", "mid:left_ear+right_ear", 0.10),
    ("left_shoulder", "left_elbow", 0.055),
    ("right_shoulder", "right_elbow", 0.055),
    ("left_elbow", "left_wrist", 0.045),
    ("right_elbow", "right_wrist", 0.045),
    ("frac:left_elbow,left_wrist,1.25", "frac:left_elbow,left_wrist,1.25", 0.065),
    ("frac:right_elbow,right_wrist,1.25", "frac:right_elbow,right_wrist,1.25", 0.065),
    ("left_hip", "left_knee", 0.085),
    ("right_hip", "right_knee", 0.085),
    ("left_knee", "left_ankle", 0.055),
    ("right_knee", "right_ankle", 0.055),
)
"""The fit's body proxy: capsules ``(a, b, radius_m)`` between named points of
``COCO17_FEET`` (``a == b``: a sphere; point names as ``geometry.segments.point_weights``).
An average adult in boxing gloves (athletes of 1.70-1.85 m): the trunk as two vertical
capsules side by side (r 11 cm), one across the hips, the head (r 10 cm), upper arms
5.5 cm, forearms 4.5 cm, gloves (a 6.5 cm sphere ~6.5 cm past the wrist), thighs 8.5 cm
and shins 5.5 cm."""


def _segment_distance(p0: torch.Tensor, p1: torch.Tensor, q0: torch.Tensor, q1: torch.Tensor) -> torch.Tensor:
    """Closest distance between segments [p0, p1] and [q0, q1] (broadcast over leading
    dims). The closest points' parameters come from
    ``geometry.segments.segment_closest_params`` on detached values: the distance is a
    minimum over them, so its gradient is the one at fixed parameters."""
    s_np, t_np = segment_closest_params(*(x.detach().cpu().numpy() for x in (p0, p1, q0, q1)))
    s = torch.as_tensor(s_np, dtype=p0.dtype, device=p0.device)
    t = torch.as_tensor(t_np, dtype=p0.dtype, device=p0.device)
    cp = p0 + (p1 - p0) * s[..., None]
    cq = q0 + (q1 - q0) * t[..., None]
    return (cp - cq).square().sum(-1).clamp(min=1e-18).sqrt()


class ProxyOverlap:
    """``ProxyOverlap(capsules)(kp, present)``: the summed squared overlap (m²) between the
    capsules of different persons. kp: (persons, frames, COCO17_FEET joints, 3);
    present: (persons, frames) bool."""

    def __init__(self, capsules: tuple[tuple[str, str, float], ...] = FIT_BODY_CAPSULES) -> None:
        nj = len(COCO17_FEET)
        ends = []
        for a, b, _ in capsules:
            rows = []
            for name in (a, b):
                idx, w = point_weights(name, COCO17_FEET)
                row = torch.zeros(nj, dtype=torch.float64)
                row[idx] = torch.tensor(w, dtype=torch.float64)
                rows.append(row)
            ends.append(torch.stack(rows))
        self.ends = torch.stack(ends)  # (S, 2, J): capsule end points as joint weights
        self.radii = torch.tensor([r for _, _, r in capsules], dtype=torch.float64)

    def __call__(self, kp: torch.Tensor, present: torch.Tensor) -> torch.Tensor:
        P = kp.shape[0]
        if P < 2:
            return kp.sum() * 0.0
        ends = self.ends.to(kp.dtype)
        radii = self.radii.to(kp.dtype)
        seg = torch.einsum("sej,pfjk->pfsek", ends, kp)  # (P, F, S, 2, 3)
        total = kp.sum() * 0.0
        for i in range(P):
            for j in range(i + 1, P):
                both = (present[i] & present[j]).to(kp.dtype)  # (F,)
                a0, a1 = seg[i, :, :, None, 0], seg[i, :, :, None, 1]  # (F, S, 1, 3)
                b0, b1 = seg[j, :, None, :, 0], seg[j, :, None, :, 1]  # (F, 1, S, 3)
                dist = _segment_distance(a0, a1, b0, b1)  # (F, S, S)
                depth = torch.relu(radii[:, None] + radii[None, :] - dist)
                total = total + (depth.square().sum(dim=(1, 2)) * both).sum()
        return total
