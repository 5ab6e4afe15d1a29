"""Versioned dataset releases (``cornerman.dataset/v1``): export sessions to a documented folder and
validate one (layout in ``pipeline.dataset.layout``; ``docs/design/dataset_release.md``)."""

from pipeline.dataset.annotations import AnnotationRecord
from pipeline.dataset.export import ReleaseSummary, check_out_dir, export_release, write_checksums
from pipeline.dataset.layout import FORMAT_ID, NPZ_LAYOUTS, file_kind
from pipeline.dataset.schemas import json_schemas
from pipeline.dataset.validate import Problem, ValidationReport, validate_release

__all__ = [
    "FORMAT_ID",
    "NPZ_LAYOUTS",
    "AnnotationRecord",
    "Problem",
    "ReleaseSummary",
    "ValidationReport",
    "check_out_dir",
    "export_release",
    "file_kind",
    "json_schemas",
    "validate_release",
    "write_checksums",
]
