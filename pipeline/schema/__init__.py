"""Typed data model shared by every stage (numpy only: no torch/mujoco imports)."""

from pipeline.schema.annotations import (
    Annotation,
    AssignIdentity,
    FixKeypoint,
    LabelContact,
    MarkInvalid,
    MergeTracks,
    SplitTrack,
    SwapIdentities,
    annotation_from_dict,
    annotation_to_dict,
    annotations_for,
    annotations_hash,
    load_annotations,
    save_annotations,
)
from pipeline.schema.association import Association
from pipeline.schema.base import from_arrays, load_npz, save_npz, to_arrays
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Detections2D, Tracks2D
from pipeline.schema.joints import COCO17, COCO17_FEET, FEET6
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit, PhysicsResult
from pipeline.schema.session import SessionConfig

__all__ = [
    "Annotation",
    "AssignIdentity",
    "Association",
    "BodyFit",
    "COCO17",
    "COCO17_FEET",
    "CameraRig",
    "Detections2D",
    "FEET6",
    "FixKeypoint",
    "Keypoints3D",
    "LabelContact",
    "MarkInvalid",
    "MergeTracks",
    "PhysicsResult",
    "SessionConfig",
    "SplitTrack",
    "SwapIdentities",
    "Tracks2D",
    "annotation_from_dict",
    "annotation_to_dict",
    "annotations_for",
    "annotations_hash",
    "from_arrays",
    "load_annotations",
    "load_npz",
    "save_annotations",
    "save_npz",
    "to_arrays",
]
