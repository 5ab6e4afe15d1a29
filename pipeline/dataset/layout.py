"""The folder layout of a dataset release (``cornerman.dataset/v1``) and its NPZ array layouts.

One release folder::

    release.json                    format, cornerman version, creation time, session list
    datasheet.md                    what was recorded, how it was labelled, licence, counts
    checksums.sha256                sha256sum lines over every other file
    schemas/<kind>.schema.json      JSON Schema (draft 2020-12) of each JSON file kind
    schemas/npz_layouts.json        array names, dtypes and shapes of each NPZ file kind
    sessions/<id>/meta.json         cameras, fps, frames, athletes, stage provenance, file list
    sessions/<id>/calibration.toml  the rig the 3D stages used (Pose2Sim/anipose TOML)
    sessions/<id>/calibration.json  the same rig as JSON
    sessions/<id>/videos.json       video (and 2D input) references with sha256
    sessions/<id>/tracks2d/<camera>.npz     per-view 2D tracks with final person ids
    sessions/<id>/keypoints3d/<source>.npz  3D keypoints: raw, filtered, fit, physics
    sessions/<id>/body/bodyfit.npz          body-model parameters (when the fit ran)
    sessions/<id>/physics/result.npz        MuJoCo trajectories (when physics ran)
    sessions/<id>/physics/scene.xml         the MJCF scene of result.npz
    sessions/<id>/events.json       boxing events (when the analyze stage ran)
    sessions/<id>/annotations.json  human edits with authors and times

The layout is fixed: every file's kind follows from its path (:func:`file_kind`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

FORMAT_ID = "cornerman.dataset/v1"
"""``release.json``'s ``format``; bumped when a file's layout changes incompatibly."""

RELEASE_JSON = "release.json"
DATASHEET = "datasheet.md"
CHECKSUMS = "checksums.sha256"
SCHEMAS_DIR = "schemas"
NPZ_LAYOUTS_JSON = "schemas/npz_layouts.json"
SESSIONS_DIR = "sessions"

SESSION_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
"""A session's folder name inside ``sessions/`` (letters, digits, ``.``, ``_``, ``-``)."""

JSON_KINDS: tuple[str, ...] = ("release", "meta", "calibration", "videos", "events", "annotations")
"""JSON file kinds; each has ``schemas/<kind>.schema.json``."""

NPZ_KINDS: tuple[str, ...] = ("tracks2d", "keypoints3d", "bodyfit", "physics")
"""NPZ file kinds; each has an entry in ``schemas/npz_layouts.json``."""

_SESSION_FILES: tuple[tuple[str, str], ...] = (
    (r"meta\.json", "meta"),
    (r"calibration\.json", "calibration"),
    (r"calibration\.toml", "calibration_toml"),
    (r"videos\.json", "videos"),
    (r"events\.json", "events"),
    (r"annotations\.json", "annotations"),
    (r"tracks2d/[^/]+\.npz", "tracks2d"),
    (r"keypoints3d/(raw|filtered|fit|physics)\.npz", "keypoints3d"),
    (r"body/bodyfit\.npz", "bodyfit"),
    (r"physics/result\.npz", "physics"),
    (r"physics/scene\.xml", "mjcf"),
)

KEYPOINT_SOURCES: tuple[str, ...] = ("raw", "filtered", "fit", "physics")
"""The 3D results a release carries, in pipeline order (``pipeline.schema.sources``)."""


def file_kind(rel: str) -> str | None:
    """The kind of the release file at POSIX path ``rel`` (relative to the release folder), or
    ``None`` when the layout has no such file."""
    top = {
        RELEASE_JSON: "release",
        DATASHEET: "datasheet",
        CHECKSUMS: "checksums",
        NPZ_LAYOUTS_JSON: "npz_layouts",
    }
    if rel in top:
        return top[rel]
    m = re.fullmatch(r"schemas/([a-z_0-9]+)\.schema\.json", rel)
    if m:
        return "schema" if m.group(1) in JSON_KINDS else None
    m = re.fullmatch(r"sessions/([^/]+)/(.+)", rel)
    if m is None or not SESSION_ID.match(m.group(1)):
        return None
    for pattern, kind in _SESSION_FILES:
        if re.fullmatch(pattern, m.group(2)):
            return kind
    return None


@dataclass(frozen=True)
class ArraySpec:
    """One array of an NPZ file kind.

    Fields:
        name: the array's key in the NPZ.
        kinds: allowed numpy dtype kinds (``"f"`` float, ``"iu"`` integer, ``"b"`` bool,
            ``"U"`` unicode string).
        shape: one entry per axis: a fixed size (int) or a named size shared by every array
            of the file (``frames``, ``persons``, ``joints``, ``dets``, ...). ``()`` = a scalar.
        doc: meaning, unit and frame of the values.
    """

    name: str
    kinds: str
    shape: tuple[int | str, ...]
    doc: str


def _kp3d() -> tuple[ArraySpec, ...]:
    fpj = ("frames", "persons", "joints")
    return (
        ArraySpec("__strtuple__joint_names", "U", ("joints",), "joint names (pipeline.schema.joints)"),
        ArraySpec("person_ids", "iu", ("persons",), "global person ids (meta.json athletes)"),
        ArraySpec("frame_indices", "iu", ("frames",), "video frame index of each row, increasing"),
        ArraySpec("__scalar__fps", "f", (), "frame rate, Hz"),
        ArraySpec("xyz_m", "f", (*fpj, 3), "joint positions, metres, world frame (z-up, right-handed)"),
        ArraySpec("valid", "b", fpj, "True where the joint has an estimate (xyz_m is meaningless elsewhere)"),
        ArraySpec("confidence", "f", fpj, "confidence in [0, 1]"),
        ArraySpec("n_views", "iu", fpj, "cameras used to triangulate (0 = not triangulated)"),
        ArraySpec(
            "reproj_err_px", "f", fpj, "mean reprojection error over the views used, pixels (NaN = n/a)"
        ),
        ArraySpec("__scalar__source", "U", (), "raw, filtered, fit or physics"),
        ArraySpec("filled", "b", fpj, "True where the joint was placed from the skeleton, not measured"),
    )


NPZ_LAYOUTS: dict[str, tuple[ArraySpec, ...]] = {
    "tracks2d": (
        ArraySpec("joint_names", "U", ("joints",), "joint names of keypoints_px"),
        ArraySpec("frame", "iu", ("dets",), "video frame index of the detection, in [0, n_frames)"),
        ArraySpec("track_id", "iu", ("dets",), "per-view track id (-1 = not in a track)"),
        ArraySpec(
            "person_id", "iu", ("dets",), "final global person id after association and edits (-1 = nobody)"
        ),
        ArraySpec("identity_confidence", "f", ("dets",), "association confidence in [0, 1]"),
        ArraySpec("bbox_xyxy_px", "f", ("dets", 4), "box in pixels of the distorted image"),
        ArraySpec("bbox_score", "f", ("dets",), "detector score in [0, 1]"),
        ArraySpec("keypoints_px", "f", ("dets", "joints", 2), "2D keypoints, pixels of the distorted image"),
        ArraySpec("keypoint_conf", "f", ("dets", "joints"), "keypoint confidence in [0, 1]"),
        ArraySpec("keypoint_valid", "b", ("dets", "joints"), "False where the source gave no keypoint"),
    ),
    "keypoints3d": _kp3d(),
    "bodyfit": (
        ArraySpec("__scalar__body_model", "U", (), "anny, smpl or smplx"),
        ArraySpec("__scalar__rig", "U", (), "body-model rig / topology name"),
        ArraySpec("__strtuple__bone_names", "U", ("bones",), "posed bones, in pose order"),
        ArraySpec("person_ids", "iu", ("persons",), "global person ids"),
        ArraySpec("frame_indices", "iu", ("frames",), "video frame index of each row"),
        ArraySpec("__scalar__fps", "f", (), "frame rate, Hz"),
        ArraySpec(
            "shape",
            "f",
            ("persons", "shape_dims"),
            "shape parameters (anny phenotypes in [0, 1]; SMPL betas)",
        ),
        ArraySpec(
            "pose", "f", ("frames", "persons", "bones", 3), "per-bone axis-angle, parent-local, radians"
        ),
        ArraySpec(
            "root_translation_m", "f", ("frames", "persons", 3), "root translation, metres, world frame"
        ),
        ArraySpec("valid", "b", ("frames", "persons"), "False where the person was not fitted"),
        ArraySpec("loss_final", "f", ("persons",), "final fit objective per person"),
    ),
    "physics": (
        ArraySpec("person_ids", "iu", ("persons",), "global person ids (MJCF body prefixes p{id}_)"),
        ArraySpec("frame_indices", "iu", ("frames",), "video frame index of each row"),
        ArraySpec("__scalar__fps", "f", (), "frame rate, Hz"),
        ArraySpec(
            "qpos",
            "f",
            ("frames", "nq"),
            "MuJoCo qpos of scene.xml (free roots: xyz + quat_wxyz; hinges: rad)",
        ),
        ArraySpec("qvel", "f", ("frames", "nv"), "MuJoCo qvel"),
        ArraySpec("ctrl", "f", ("frames", "nu"), "actuator controls (see actuation)"),
        ArraySpec("joint_torque_nm", "f", ("frames", "nu"), "actuator forces applied, N·m"),
        ArraySpec(
            "residual_root_force", "f", ("frames", "persons", 6), "residual root wrench (zero when unused)"
        ),
        ArraySpec("__scalar__actuation", "U", (), "pd or torque"),
        ArraySpec("contact_frame", "iu", ("contacts",), "row of each recorded contact"),
        ArraySpec("contact_person", "iu", ("contacts", 2), "person ids of both geoms (-1 = ground)"),
        ArraySpec("contact_body", "iu", ("contacts", 2), "indices into body_names"),
        ArraySpec("contact_depth_m", "f", ("contacts",), "penetration depth, metres (positive = overlap)"),
        ArraySpec("__strtuple__body_names", "U", ("bodies",), "MuJoCo body names referenced by contact_body"),
        ArraySpec(
            "untrackable", "b", ("frames", "persons"),
            "True where the person's window could not be tracked without the residual root force",
        ),
        ArraySpec(
            "observed", "b", ("frames", "persons"),
            "True where the person had valid input joints (elsewhere simulated, not their motion)",
        ),
    ),
}
"""Array layout of each NPZ kind. ``keypoints3d``, ``bodyfit`` and ``physics`` are cornerman's schema
npz form (``pipeline.schema.load_npz`` reads them back as ``Keypoints3D``, ``BodyFit``,
``PhysicsResult``; ``__scalar__``/``__strtuple__`` prefix 0-d and string-list fields)."""


def npz_layouts_doc() -> dict[str, dict[str, dict[str, object]]]:
    """``schemas/npz_layouts.json``: kind -> array name -> {dtype kinds, shape, doc}."""
    return {
        kind: {a.name: {"dtype_kinds": a.kinds, "shape": list(a.shape), "doc": a.doc} for a in specs}
        for kind, specs in NPZ_LAYOUTS.items()
    }
