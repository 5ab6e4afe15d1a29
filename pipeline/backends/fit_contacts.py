"""Overlap between athletes as a term of the kinematic fit (torch).

The athletes' volumes are ``CapsuleProxy`` capsules around their keypoints (an average
adult in boxing gloves, the volumes the penetration metric scores). In clinches and
exchanges the 2D evidence of an arm hidden behind the other athlete is weak, and the fit
let arms pass through each other and through the other's trunk (the synthetic bench: up
to 10 cm). The term is the squared depth of every overlap between capsules of two
different persons, summed over frames where both are present.
"""

from __future__ import annotations

import torch

from pipeline.evaluate.physics_metrics import CapsuleProxy, point_weights, segment_closest_params
from pipeline.schema.joints import COCO17_FEET


def _segment_distance(p0: torch.Tensor, p1: torch.Tensor, q0: torch.Tensor, q1: torch.Tensor) -> torch.Tensor:
    """Closest distance between segments [p0, p1] and [q0, q1] (broadcast over leading
    dims). The closest points' parameters come from the metric's own
    ``physics_metrics.segment_closest_params`` on detached values: the distance is a
    minimum over them, so its gradient is the one at fixed parameters."""
    s_np, t_np = segment_closest_params(*(x.detach().cpu().numpy() for x in (p0, p1, q0, q1)))
    s = torch.as_tensor(s_np, dtype=p0.dtype, device=p0.device)
    t = torch.as_tensor(t_np, dtype=p0.dtype, device=p0.device)
    cp = p0 + (p1 - p0) * s[..., None]
    cq = q0 + (q1 - q0) * t[..., None]
    return (cp - cq).square().sum(-1).clamp(min=1e-18).sqrt()


class ProxyOverlap:
    """``ProxyOverlap(proxy)(kp, present)``: the summed squared overlap (m²) between the
    capsules of different persons. kp: (persons, frames, COCO17_FEET joints, 3);
    present: (persons, frames) bool."""

    def __init__(self, proxy: CapsuleProxy = CapsuleProxy()) -> None:
        nj = len(COCO17_FEET)
        ends = []
        for a, b, _ in proxy.segments:
            rows = []
            for name in (a, b):
                idx, w = point_weights(name, COCO17_FEET)
                row = torch.zeros(nj, dtype=torch.float64)
                row[idx] = torch.tensor(w, dtype=torch.float64)
                rows.append(row)
            ends.append(torch.stack(rows))
        self.ends = torch.stack(ends)  # (S, 2, J): capsule end points as joint weights
        self.radii = torch.tensor([r for _, _, r in proxy.segments], dtype=torch.float64)

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
