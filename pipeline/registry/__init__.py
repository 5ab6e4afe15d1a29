"""Model registry: named models, where to find them, and a verifying downloader."""

from pipeline.registry.download import (
    cache_dir,
    download,
    download_model,
    find_model,
    resolve_model,
    search_dirs,
    sha256_file,
    verify_file,
)
from pipeline.registry.models import MODELS, UNKNOWN_SHA256, ModelInfo, get_model

__all__ = [
    "MODELS",
    "UNKNOWN_SHA256",
    "ModelInfo",
    "cache_dir",
    "download",
    "download_model",
    "find_model",
    "get_model",
    "resolve_model",
    "search_dirs",
    "sha256_file",
    "verify_file",
]
