"""The named models cornerman knows: where they come from, how to check and decode them.

``sha256`` is the checksum of the final ``.onnx`` file (after extraction from an archive).
``"unknown"`` means no published checksum was found: the first download records the
file's hash in the cache's ``checksums.json`` (trust on first use) and later
verifications compare against it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

UNKNOWN_SHA256 = "unknown"

_OMM = "https://download.openmmlab.com/mmpose/v1/projects/rtmposev1/onnx_sdk"
_YOLOX = "https://github.com/Megvii-BaseDetection/YOLOX/releases/download/0.1.1rc0"
_EASY_VITPOSE = "https://huggingface.co/JunkyByte/easy_ViTPose/resolve/main/onnx/coco"


@dataclass(frozen=True)
class ModelInfo:
    """One downloadable model.

    Fields:
        name: registry name (also the cached file's stem: ``<name>.onnx``).
        task: ``"detector"`` (person boxes) or ``"pose"`` (top-down keypoints).
        decoder: how outputs are decoded (``pipeline.backends`` ``make_detector`` /
            ``make_pose_estimator`` kinds).
        url: official download address; ``None`` when the file is not published as
            ONNX (it must be placed in the models folder by hand).
        sha256: hex checksum of the ``.onnx`` file, or ``"unknown"`` (trust on first use).
        input_size_hw: network input height, width in pixels.
        licence: SPDX-style licence of the weights.
        archive_member: for ``.zip`` downloads, the member that is the model.
        source: where the file comes from, for humans.
    """

    name: str
    task: Literal["detector", "pose"]
    decoder: Literal["yolox", "rtmdet_end2end", "blazepose", "movenet", "heatmap", "simcc"]
    url: str | None
    sha256: str
    input_size_hw: tuple[int, int]
    licence: str
    archive_member: str | None = None
    source: str = ""

    @property
    def filename(self) -> str:
        return f"{self.name}.onnx"


MODELS: dict[str, ModelInfo] = {
    m.name: m
    for m in (
        ModelInfo(
            "yolox_nano", "detector", "yolox", f"{_YOLOX}/yolox_nano.onnx",
            "695e750a5d5754bb5a8d5325643b59282191a7e7a564e435a415fd3c578eab14", (416, 416), "Apache-2.0",
            source="YOLOX release 0.1.1rc0 (Megvii), COCO 80 classes",
        ),
        ModelInfo(
            "yolox_s", "detector", "yolox", f"{_YOLOX}/yolox_s.onnx", UNKNOWN_SHA256, (640, 640), "Apache-2.0",
            source="YOLOX release 0.1.1rc0 (Megvii), COCO 80 classes",
        ),
        ModelInfo(
            "yolox_m", "detector", "yolox", f"{_YOLOX}/yolox_m.onnx", UNKNOWN_SHA256, (640, 640), "Apache-2.0",
            source="YOLOX release 0.1.1rc0 (Megvii), COCO 80 classes",
        ),
        ModelInfo(
            "rtmdet_nano", "detector", "rtmdet_end2end",
            f"{_OMM}/rtmdet_nano_8xb32-100e_coco-obj365-person-05d8511e.zip",
            "4720eda18a18402e7b76d85827d4bc60fba18111fc0b74b559e4d24da9ddc3d2", (320, 320), "Apache-2.0",
            archive_member="end2end.onnx",
            source="RTMPose ONNX SDK (OpenMMLab), person-only RTMDet-nano, mmdeploy end2end",
        ),
        ModelInfo(
            "blazepose_full", "pose", "blazepose", None,
            "dbc8a63d3f33af6ffc857807d4fecb66e98bcc816408a04976b811dfa3a21318", (256, 256), "Apache-2.0",
            source="pose_landmark_full.tflite of the mediapipe 0.10.14 wheel converted with tf2onnx (opset 17); "
            "not published as ONNX: copy pose_landmark_full.onnx as blazepose_full.onnx or keep its original name",
        ),
        ModelInfo(
            "movenet_lightning", "pose", "movenet", None,
            "9493df70973fa37b94ae4f19b0023b5a6167c09b19f3a60d5bf68c0f8cc5bc82", (192, 192), "Apache-2.0",
            source="MoveNet SinglePose Lightning v4 int8 TF-Hub tflite converted with tf2onnx; "
            "not published as ONNX: keep it as movenet_lightning_int8.onnx in the models folder",
        ),
        ModelInfo(
            "rtmpose_m", "pose", "simcc", f"{_OMM}/rtmpose-m_simcc-body7_pt-body7_420e-256x192-e48f03d0_20230504.zip",
            UNKNOWN_SHA256, (256, 192), "Apache-2.0", archive_member="end2end.onnx",
            source="RTMPose ONNX SDK (OpenMMLab), body7, COCO-17, SimCC",
        ),
        ModelInfo(
            "rtmpose_l", "pose", "simcc", f"{_OMM}/rtmpose-l_simcc-body7_pt-body7_420e-256x192-4dba18fc_20230504.zip",
            UNKNOWN_SHA256, (256, 192), "Apache-2.0", archive_member="end2end.onnx",
            source="RTMPose ONNX SDK (OpenMMLab), body7, COCO-17, SimCC",
        ),
        ModelInfo(
            "vitpose_b", "pose", "heatmap", f"{_EASY_VITPOSE}/vitpose-b-coco.onnx", UNKNOWN_SHA256, (256, 192),
            "Apache-2.0",
            source="ViTPose++-B COCO-17 heatmaps; ONNX export of the official ViTPose weights listed by the "
            "RTMPose/rtmlib model zoo (easy_ViTPose)",
        ),
        ModelInfo(
            "vitpose_l", "pose", "heatmap", f"{_EASY_VITPOSE}/vitpose-l-coco.onnx", UNKNOWN_SHA256, (256, 192),
            "Apache-2.0",
            source="ViTPose++-L COCO-17 heatmaps; ONNX export of the official ViTPose weights (easy_ViTPose)",
        ),
        ModelInfo(
            "vitpose_h", "pose", "heatmap", None, UNKNOWN_SHA256, (256, 192), "Apache-2.0",
            source="ViTPose-H is published only as a PyTorch checkpoint (mmpose: td-hm_ViTPose-huge_8xb64-210e_"
            "coco-256x192-e32adcd4_20230314.pth, >2 GB ONNX needs external data); export it to a single "
            "vitpose_h.onnx with mmdeploy and place it in the models folder",
        ),
    )
}  # fmt: skip

# Other file names under which a model may already be present (the shared test models).
ALIASES: dict[str, tuple[str, ...]] = {
    "blazepose_full": ("pose_landmark_full.onnx",),
    "movenet_lightning": ("movenet_lightning_int8.onnx",),
}


def canonical_name(name: str) -> str:
    """The registry spelling of a model name: case, surrounding blanks and ``-`` versus ``_``
    do not matter (``RTMPose-M`` -> ``rtmpose_m``, the spelling of OpenMMLab's file names).
    The result need not be a known model (``get_model`` checks that)."""
    return name.strip().lower().replace("-", "_")


def get_model(name: str) -> ModelInfo:
    """The registry entry of ``name`` or one of its spellings (``canonical_name``);
    ``ValueError`` listing the known names otherwise."""
    key = canonical_name(name)
    if key not in MODELS:
        raise ValueError(f"unknown model {name!r}; known models: {', '.join(sorted(MODELS))}")
    return MODELS[key]
