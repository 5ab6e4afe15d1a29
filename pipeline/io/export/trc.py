"""TRC export of 3D keypoints (OpenSim / Pose2Sim marker files).

- Markers: one per (athlete, joint); the marker name is the joint name, prefixed ``{athlete}_``
  when several athletes are exported (``Red_left_wrist``).
- Units: metres by default (``Units`` header field, ``m``; or ``mm``), 5 (m) or 2 (mm) decimals,
  i.e. rounded to 0.01 mm.
- Axes: converted to OpenSim's y-up by default: ``(X, Y, Z) = (x, z, -y)`` of our z-up world
  (a -90 deg rotation about x; up is +Y, right-handed). ``up="z"`` keeps the world frame. TRC
  has no comment field, so the file itself cannot say which; the README and this docstring do.
- Rate: ``DataRate`` = ``CameraRate`` = the session's frame rate; ``Frame#`` is the 1-based
  video frame number (video frame index + 1), ``Time`` the video frame index / fps, in seconds.
- Layout as OpenSim's own writer: five header lines, one blank line, then one tab-separated
  row per frame with every cell followed by a tab; a joint without an estimate is three
  empty cells (OpenSim reads them as NaN).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

from pipeline.io.export.markers import marker_arrays, marker_labels, zup_to_yup
from pipeline.schema.keypoints3d import Keypoints3D

if TYPE_CHECKING:
    from pipeline.io.export.selection import ExportSelection

_DECIMALS = {"m": 5, "mm": 2}
_SCALE = {"m": 1.0, "mm": 1000.0}


def keypoints3d_to_trc(
    kp: Keypoints3D,
    names: dict[int, str],
    file_name: str = "markers.trc",
    units: Literal["m", "mm"] = "m",
    up: Literal["y", "z"] = "y",
) -> str:
    """The TRC text of ``kp`` (see the module docstring); ``names`` maps person id -> athlete name."""
    if units not in _DECIMALS:
        raise ValueError(f"TRC units must be 'm' or 'mm', got {units!r}")
    if up not in ("y", "z"):
        raise ValueError(f"TRC up axis must be 'y' or 'z', got {up!r}")
    labels = marker_labels(kp, names)
    xyz, valid = marker_arrays(kp)
    xyz = (zup_to_yup(xyz) if up == "y" else xyz) * _SCALE[units]
    n_frames, n_markers = valid.shape
    rate = f"{kp.fps:g}"
    first = int(kp.frame_indices[0]) + 1 if n_frames else 1
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{file_name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{rate}\t{rate}\t{n_frames}\t{n_markers}\t{units}\t{rate}\t{first}\t{n_frames}",
        "Frame#\tTime\t" + "".join(f"{m}\t\t\t" for m in labels),
        "\t\t" + "".join(f"X{i}\tY{i}\tZ{i}\t" for i in range(1, n_markers + 1)),
        "",
    ]
    fmt = f"{{:.{_DECIMALS[units]}f}}"
    for fi, frame in enumerate(kp.frame_indices.tolist()):
        cells = [str(frame + 1), f"{frame / kp.fps:.6f}"]
        for m in range(n_markers):
            cells.extend([fmt.format(v) for v in xyz[fi, m]] if valid[fi, m] else ["", "", ""])
        lines.append("".join(c + "\t" for c in cells))
    return "\n".join(lines) + "\n"


def build_trc(sel: ExportSelection) -> dict[str, bytes]:
    """The registry's ``trc`` format: the selected keypoints as one TRC (metres, y-up)."""
    kp, chosen = sel.keypoints()
    names = {int(p): sel.name_of(int(p)) for p in kp.person_ids}
    name = f"keypoints3d_{chosen}.trc"
    return {name: keypoints3d_to_trc(kp, names, file_name=name).encode()}
