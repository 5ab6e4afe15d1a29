"""Summary numbers of a synthetic bout (for reports and a ``cornerman bench`` table)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from pipeline.synthetic.bout import SyntheticBout, make_bout
from pipeline.synthetic.config import SyntheticConfig
from pipeline.synthetic.skeleton import J

CLINCH_TORSO_DISTANCE_M = 0.36
"""Frames whose torso centres (mean of shoulders and hips) are closer count as clinch.
Bodies never overlap (``pipeline.synthetic.separate``): two 0.115 m torso capsules with
arms wrapped between them keep the centres ~0.33-0.36 m apart in a clinch."""


def torso_distance_m(bout: SyntheticBout) -> np.ndarray:
    """(frames,) distance between the two boxers' torso centres."""
    idx = [J["left_shoulder"], J["right_shoulder"], J["left_hip"], J["right_hip"]]
    tc = bout.gt.xyz_m[:, :, idx].mean(axis=2)
    return np.linalg.norm(tc[:, 0] - tc[:, 1], axis=1)


def bout_stats(bout: SyntheticBout) -> dict[str, Any]:
    """Plain-number summary: detections, punch speeds, clinch frames, swaps, occlusion."""
    tr = bout.tracks
    d = torso_distance_m(bout)
    contact = bout.foot_contact
    steps = int(np.sum(contact[:-1] & ~contact[1:]))
    speeds = bout.punch_peak_speed_mps
    kinds = [p.kind for p in bout.choreography.punches]
    who = bout.gt_person_of_det
    return {
        "frames": int(bout.gt.n_frames),
        "cameras": int(bout.rig.n_views),
        "detections": int(tr.n_dets),
        "punches": len(kinds),
        "jabs/crosses/hooks": f"{kinds.count('jab')}/{kinds.count('cross')}/{kinds.count('lead_hook')}",
        "fist_peak_min_mps": float(speeds.min()) if speeds.size else float("nan"),
        "fist_peak_max_mps": float(speeds.max()) if speeds.size else float("nan"),
        "clinch_frames": int(np.sum(d < CLINCH_TORSO_DISTANCE_M)),
        "min_torso_distance_m": float(d.min()),
        "steps": steps,
        "foot_contact_pct": 100.0 * float(contact.mean()),
        "swaps": int(len(bout.swap_frames)),
        "occluded_pct": 100.0 * float(bout.occluded.mean()),
        "valid_keypoints_pct": 100.0 * float(tr.keypoint_valid.mean()),
        "bystander_views": int(np.unique(tr.view[who == -1]).size),
    }


def run_bench(seeds: str = "0,1,2", n_frames: int = 300, n_cameras: int = 4) -> list[dict[str, Any]]:
    """One row per seed: generation time and ``bout_stats``."""
    rows = []
    for seed in (int(s) for s in seeds.split(",") if s.strip()):
        t0 = time.perf_counter()
        bout = make_bout(SyntheticConfig(seed=seed, n_frames=n_frames, n_cameras=n_cameras))
        rows.append({"seed": seed, "gen_time_s": time.perf_counter() - t0, **bout_stats(bout)})
    return rows


def print_table(rows: list[dict[str, Any]]) -> None:
    """Print ``run_bench`` rows with rich."""
    from rich.console import Console
    from rich.table import Table

    if not rows:
        return
    table = Table(title="synthetic bout")
    for key in rows[0]:
        table.add_column(key, justify="right")
    for r in rows:
        table.add_row(*(f"{v:.2f}" if isinstance(v, float) else str(v) for v in r.values()))
    Console().print(table)
