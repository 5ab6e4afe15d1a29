"""A hand-made analysed bout for the report tests: two boxers drifting around the ring and
trading jabs and crosses (blocked on the guard, landed on a dropped guard, short at a longer
distance), analysed by the analyze stage in memory and written as a session folder (the
``fit`` keypoints and the analyze artifacts)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.artifacts import ArtifactStore, Manifest
from pipeline.schema import Keypoints3D, SessionConfig
from pipeline.stages.analyze import AnalyzeInputs, AnalyzeOutput, run
from tests.stages.analyze_fixtures import FPS, J, keypoints, profile, straight, throw, two_boxers

N_FRAMES = 600  # 12 s at 50 fps
PLAN: tuple[tuple[float, int, str, str], ...] = (
    (0.6, 0, "left", "short"), (1.5, 1, "left", "short"), (2.6, 0, "left", "head"), (3.6, 0, "right", "head"),
    (5.0, 1, "left", "head"), (5.9, 1, "right", "head"), (7.0, 0, "left", "short"), (8.0, 1, "right", "short"),
    (9.0, 0, "right", "short"), (10.0, 1, "left", "short"), (11.0, 0, "left", "short"),
)  # fmt: skip
"""(start s, athlete, hand, aim): ``head`` ends on the opponent's chin, ``short`` 0.32 m out."""
GUARD_DOWN: dict[int, tuple[float, float]] = {1: (2.1, 4.4), 0: (4.6, 6.6)}
"""Athlete -> seconds during which his gloves hang low (so punches at the head land)."""


def bout_keypoints() -> Keypoints3D:
    """The bout's ``fit`` keypoints: 1.0 m apart, then 1.6 m from 6.5 s; both drift in x/y."""
    xyz = two_boxers(N_FRAMES, distance_m=1.0)
    t = np.arange(N_FRAMES) / FPS
    xyz[t >= 6.5, 1] += np.array([0.6, 0.0, 0.0])
    for who, (a, b) in GUARD_DOWN.items():
        ramp = np.clip(np.minimum(t - a, b - t) / 0.3, 0, 1)
        mirror = np.array([1.0, 1.0, 1.0]) if who == 1 else np.array([-1.0, -1.0, 1.0])
        for hand, side in (("left", -1.0), ("right", 1.0)):
            for joint, drop in (("wrist", 0.35), ("elbow", 0.15)):
                xyz[:, who, J[f"{hand}_{joint}"]] += ramp[:, None] * (
                    np.array([0.1, 0.1 * side, -drop]) * mirror
                )
    for t0, person, hand, aim in PLAN:
        k = int(t0 * FPS)
        start = xyz[k, person, J[f"{hand}_wrist"]].copy()
        ahead = 1.0 if person == 0 else -1.0
        if aim == "head":
            chin = 0.5 * (xyz[k, 1 - person, J["left_ear"]] + xyz[k, 1 - person, J["right_ear"]])
            end = chin - ahead * np.array([0.215, 0.0, 0.0])
        else:
            end = start + np.array([ahead * 0.32, 0.0, 0.04])
        prof = profile(N_FRAMES, t0, 0.1)
        moved = xyz.copy()
        throw(moved, person, hand, prof, straight(start, end))
        out = prof > 1e-9  # throw() rewrites the whole track: keep only this punch's frames
        xyz[out] = moved[out]
    drift = np.stack([0.8 * np.sin(2 * np.pi * t / 12.0), 0.9 * np.sin(2 * np.pi * t / 9.0), 0 * t], axis=1)
    return keypoints(xyz + drift[:, None, None, :], source="fit")


def write_analysed_bout(folder: Path, write_session: bool = True) -> AnalyzeOutput:
    """A session folder with ``session.json`` (athletes Red and Blue; kept as it is when
    ``write_session`` is False), the fit's keypoints and the analyze stage's artifacts
    (source ``fit``); returns the analysis."""
    folder.mkdir(parents=True, exist_ok=True)
    if write_session:
        SessionConfig(name="sparring test", source="tracks", calibration="inputs/calibration.toml",
                      tracks="inputs/tracks2d.npz", athletes=("Red", "Blue")).save(folder)  # fmt: skip
    kp = bout_keypoints()
    out = run(AnalyzeInputs(keypoints=kp))
    store = ArtifactStore(folder)
    store.write(
        Manifest(stage="fit", code_version="test", config={}, config_hash="0", inputs={}), {"keypoints3d": kp}
    )
    m = Manifest(
        stage="analyze", code_version="test", config={}, config_hash="0", inputs={}, metrics={"source": "fit"}
    )
    store.write(m, {"events": out.events, "series": out.series})
    return out
