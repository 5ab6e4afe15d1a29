"""Finding and downloading registry models.

Lookup order of ``resolve_model``: the explicit ``models_dir`` (CLI ``--models-dir``),
then the shared models folder (``$CORNERMAN_MODELS_DIR``, else ``../shared/models``:
``pipeline.shared``), then the cache
``$CORNERMAN_CACHE_DIR/models`` (default ``~/.cache/cornerman/models``).

Downloads go to ``<file>.part`` and resume with an HTTP ``Range`` request when a partial
file exists (a server that ignores ``Range`` makes the download restart cleanly). The
result is checked against the registry's sha256 (a mismatch removes the file and
raises); models without a published checksum are recorded on first download in
``checksums.json`` next to them (trust on first use).
"""

from __future__ import annotations

import hashlib
import http.client
import json
import logging
import os
import shutil
import urllib.error
import urllib.request
import zipfile
from collections.abc import Callable
from pathlib import Path

from pipeline.registry.models import ALIASES, UNKNOWN_SHA256, ModelInfo, get_model
from pipeline.shared import MODELS_ENV, shared_models_dir

log = logging.getLogger(__name__)

CHECKSUMS_FILE = "checksums.json"
_CHUNK = 1 << 20


def cache_dir() -> Path:
    """``$CORNERMAN_CACHE_DIR/models`` (default ``~/.cache/cornerman/models``)."""
    root = os.environ.get("CORNERMAN_CACHE_DIR")
    base = Path(root).expanduser() if root else Path.home() / ".cache" / "cornerman"
    return base / "models"


def labelled_search_dirs(models_dir: Path | str | None = None) -> list[tuple[str, Path]]:
    """``(where it comes from, folder)`` for every folder ``resolve_model`` looks in, in order:
    the explicit folder (``--models-dir`` / ``stage_config.detect2d.models_dir``), the shared
    models folder when one exists (``pipeline.shared``), the cache. Duplicates are dropped."""
    dirs: list[tuple[str, Path]] = []
    if models_dir is not None:
        dirs.append(("--models-dir", Path(models_dir).expanduser()))
    shared = shared_models_dir()
    if shared is not None:
        dirs.append((f"shared models folder (${MODELS_ENV}, else ../shared/models)", shared))
    dirs.append(("cache ($CORNERMAN_CACHE_DIR/models; downloads go here)", cache_dir()))
    out: list[tuple[str, Path]] = []
    for label, d in dirs:
        if d not in [p for _, p in out]:
            out.append((label, d))
    return out


def search_dirs(models_dir: Path | str | None = None) -> list[Path]:
    """The folders ``resolve_model`` looks in, in order (``labelled_search_dirs``)."""
    return [d for _, d in labelled_search_dirs(models_dir)]


def candidate_names(info: ModelInfo) -> tuple[str, ...]:
    return (info.filename, *ALIASES.get(info.name, ()))


def find_model(name: str, models_dir: Path | str | None = None) -> Path | None:
    """The model file if present in one of ``search_dirs``; ``None`` otherwise.

    ``name`` may be any spelling ``get_model`` accepts (``rtmpose-m``)."""
    info = get_model(name)
    for d in search_dirs(models_dir):
        for fn in candidate_names(info):
            if (d / fn).is_file():
                return d / fn
    return None


def resolve_model(name: str, models_dir: Path | str | None = None) -> Path:
    """Path of the model file; ``ValueError`` naming the model, where it looked and how to get it."""
    info = get_model(name)
    p = find_model(info.name, models_dir)
    if p is not None:
        return p
    looked = ", ".join(str(d / fn) for d in search_dirs(models_dir) for fn in candidate_names(info))
    raise ValueError(
        f"model {info.name!r} not found; looked for {looked}. To get it, {how_to_get(info)}, or put "
        f"{info.filename} in a folder given by --models-dir (session.json: stage_config.detect2d.models_dir) "
        f"or {MODELS_ENV}."
    )


def how_to_get(info: ModelInfo) -> str:
    """One clause a user can act on: the download command, or why the file cannot be
    downloaded and what to do instead (the registry's ``source``)."""
    if info.url:
        return f"download it with `cornerman models download {info.name}` (from {info.url})"
    return f"it is not downloadable, place it by hand: {info.source}"


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(_CHUNK), b""):
            h.update(chunk)
    return h.hexdigest()


def _read_checksums(folder: Path) -> dict[str, str]:
    p = folder / CHECKSUMS_FILE
    if not p.is_file():
        return {}
    try:
        data = json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{p}: invalid JSON ({e}); delete it to re-record checksums") from e
    return {str(k): str(v) for k, v in data.items()}


def _record_checksum(folder: Path, name: str, digest: str) -> None:
    data = _read_checksums(folder)
    data[name] = digest
    tmp = folder / (CHECKSUMS_FILE + ".tmp")
    try:
        tmp.write_text(json.dumps(data, indent=2, sort_keys=True))
        tmp.replace(folder / CHECKSUMS_FILE)
    except OSError as e:  # a read-only offline folder: nothing to record into
        log.warning("cannot record the checksum of %s in %s: %s", name, folder, e)


def expected_sha256(info: ModelInfo, folder: Path) -> str | None:
    """The published checksum, else the one recorded on first use in ``folder``, else None."""
    if info.sha256 != UNKNOWN_SHA256:
        return info.sha256
    return _read_checksums(folder).get(info.name)


def fetch(
    url: str,
    part: Path,
    progress: Callable[[int, int | None], None] | None = None,
    timeout_s: float = 60.0,
) -> None:
    """Download ``url`` into ``part``, resuming from its current size with an HTTP Range request.

    A server answering 200 to a Range request sends the whole file: the partial file
    is then truncated and the download restarts. ``ValueError`` on HTTP/network errors.
    """
    have = part.stat().st_size if part.exists() else 0
    req = urllib.request.Request(url, headers={"User-Agent": "cornerman-model-downloader"})
    if have:
        req.add_header("Range", f"bytes={have}-")
    try:
        resp = urllib.request.urlopen(req, timeout=timeout_s)
    except urllib.error.HTTPError as e:
        if e.code == 416 and have:
            log.info("%s: server says the partial file is already complete", part)
            return
        raise ValueError(f"download of {url} failed: HTTP {e.code} {e.reason}") from e
    except (urllib.error.URLError, TimeoutError, OSError) as e:
        raise ValueError(f"download of {url} failed: {e}") from e
    with resp:
        status = getattr(resp, "status", 200)
        length = resp.headers.get("Content-Length")
        if have and status == 206:
            mode, done = "ab", have
            total = have + int(length) if length else None
            log.info("resuming %s at byte %d", url, have)
        else:
            mode, done = "wb", 0
            total = int(length) if length else None
        try:
            with open(part, mode) as f:
                while True:
                    chunk = resp.read(_CHUNK)
                    if not chunk:
                        break
                    f.write(chunk)
                    done += len(chunk)
                    if progress is not None:
                        progress(done, total)
        except (TimeoutError, OSError, http.client.HTTPException) as e:
            raise ValueError(
                f"download of {url} interrupted after {done} bytes (run again to resume): {e}"
            ) from e
    if total is not None and done < total:
        raise ValueError(f"download of {url} interrupted after {done} of {total} bytes (run again to resume)")


def _extract_member(archive: Path, member: str, dest: Path) -> None:
    try:
        with zipfile.ZipFile(archive) as z:
            names = [n for n in z.namelist() if Path(n).name == member]
            if not names:
                raise ValueError(f"{archive}: no member named {member!r} (has {z.namelist()[:10]})")
            with z.open(names[0]) as src, open(dest, "wb") as dst:
                shutil.copyfileobj(src, dst, _CHUNK)
    except zipfile.BadZipFile as e:
        raise ValueError(f"{archive}: not a valid zip archive ({e})") from e


def download(
    info: ModelInfo,
    dest_dir: Path | None = None,
    progress: Callable[[int, int | None], None] | None = None,
    force: bool = False,
) -> Path:
    """Download ``info`` into ``dest_dir`` (default: the cache) and verify it; returns the file.

    An existing verified file is returned as is (unless ``force``). A checksum mismatch
    removes the downloaded file and raises ``ValueError``.
    """
    if not info.url:
        raise ValueError(f"model {info.name!r} has no download address: {info.source}")
    folder = Path(dest_dir) if dest_dir is not None else cache_dir()
    folder.mkdir(parents=True, exist_ok=True)
    final = folder / info.filename
    if final.is_file() and not force:
        verify_file(info, final)
        return final
    is_zip = info.archive_member is not None
    part = folder / (info.filename + (".zip" if is_zip else "") + ".part")
    fetch(info.url, part, progress)
    tmp = folder / (info.filename + ".tmp")
    if is_zip:
        try:
            _extract_member(part, str(info.archive_member), tmp)
        except ValueError:
            part.unlink(missing_ok=True)  # a corrupt archive cannot be resumed: start over next time
            tmp.unlink(missing_ok=True)
            raise
        part.unlink()
    else:
        part.replace(tmp)
    try:
        verify_file(info, tmp)
    except ValueError:
        tmp.unlink(missing_ok=True)
        raise
    tmp.replace(final)
    log.info("downloaded %s to %s", info.name, final)
    return final


def verify_file(info: ModelInfo, path: Path) -> str:
    """Check ``path`` against the expected checksum; records it on first use. Returns the sha256.

    ``ValueError`` naming the file and both checksums on mismatch.
    """
    digest = sha256_file(path)
    want = expected_sha256(info, path.parent)
    if want is None:
        _record_checksum(path.parent, info.name, digest)
        log.warning("%s: no published sha256; recorded %s (trust on first use)", info.name, digest)
        return digest
    if digest != want:
        raise ValueError(
            f"{path}: sha256 {digest} does not match the expected {want} for model {info.name!r}"
        )
    return digest


def download_model(
    name: str,
    models_dir: Path | str | None = None,
    progress: Callable[[int, int | None], None] | None = None,
    force: bool = False,
) -> Path:
    """Download the registry model ``name`` into ``models_dir`` (default: the cache)."""
    return download(get_model(name), Path(models_dir) if models_dir is not None else None, progress, force)
