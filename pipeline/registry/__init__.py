"""Model registry: named models, where to find them, and a verifying downloader."""

from pipeline.registry.download import (
    cache_dir,
    download,
    download_model,
    find_model,
    how_to_get,
    labelled_search_dirs,
    resolve_model,
    search_dirs,
    sha256_file,
    verify_file,
)
from pipeline.registry.models import MODELS, UNKNOWN_SHA256, ModelInfo, canonical_name, get_model

__all__ = [
    "MODELS",
    "UNKNOWN_SHA256",
    "ModelInfo",
    "cache_dir",
    "canonical_name",
    "download",
    "download_model",
    "find_model",
    "get_model",
    "how_to_get",
    "labelled_search_dirs",
    "resolve_model",
    "search_dirs",
    "sha256_file",
    "verify_file",
]
