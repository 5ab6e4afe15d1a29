"""Session artifact folders: atomic writes, manifests, staleness."""

from pipeline.artifacts.store import (
    ArtifactStore,
    FileHashCache,
    Manifest,
    config_hash,
    sha256_bytes,
    sha256_file,
)

__all__ = ["ArtifactStore", "FileHashCache", "Manifest", "config_hash", "sha256_bytes", "sha256_file"]
