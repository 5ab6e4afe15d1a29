from __future__ import annotations

import hashlib
import http.server
import io
import threading
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from pipeline.registry import (
    MODELS,
    UNKNOWN_SHA256,
    ModelInfo,
    download,
    resolve_model,
    sha256_file,
    verify_file,
)

PAYLOAD = bytes(range(256)) * 4096  # 1 MiB


class _Server:
    """A local HTTP server with Range support and switchable misbehaviour."""

    def __init__(self, files: dict[str, bytes]) -> None:
        self.files = files
        self.truncate_next = False  # send half the body, then close
        self.ignore_range = False
        self.range_headers: list[str | None] = []
        srv = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 - http.server API
                data = srv.files.get(self.path)
                rng = self.headers.get("Range")
                srv.range_headers.append(rng)
                if data is None:
                    self.send_error(404)
                    return
                start = 0
                if rng and not srv.ignore_range:
                    start = int(rng.split("=")[1].split("-")[0])
                    if start >= len(data):
                        self.send_response(416)
                        self.end_headers()
                        return
                    self.send_response(206)
                    self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
                else:
                    self.send_response(200)
                body = data[start:]
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                if srv.truncate_next:
                    srv.truncate_next = False
                    self.wfile.write(body[: len(body) // 2])
                    self.wfile.flush()
                    self.close_connection = True
                    return
                self.wfile.write(body)

            def log_message(self, *args: object) -> None:
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        self.thread = threading.Thread(
            target=self.httpd.serve_forever, kwargs={"poll_interval": 0.02}, daemon=True
        )
        self.thread.start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def server() -> Iterator[_Server]:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("rtm-sdk/end2end.onnx", PAYLOAD)
        z.writestr("rtm-sdk/pipeline.json", b"{}")
    srv = _Server({"/m.onnx": PAYLOAD, "/m.zip": buf.getvalue()})
    yield srv
    srv.close()


def _info(url: str, sha: str, member: str | None = None) -> ModelInfo:
    return ModelInfo("testmodel", "detector", "yolox", url, sha, (64, 64), "MIT", archive_member=member)


SHA = hashlib.sha256(PAYLOAD).hexdigest()


def test_download_correct_checksum(server: _Server, tmp_path: Path) -> None:
    p = download(_info(server.url + "/m.onnx", SHA), tmp_path)
    assert p == tmp_path / "testmodel.onnx" and sha256_file(p) == SHA
    assert sorted(x.name for x in tmp_path.iterdir()) == ["testmodel.onnx"]
    # Already present and valid: no second request.
    n = len(server.range_headers)
    assert download(_info(server.url + "/m.onnx", SHA), tmp_path) == p
    assert len(server.range_headers) == n


def test_download_wrong_checksum_removes_file(server: _Server, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="does not match"):
        download(_info(server.url + "/m.onnx", "0" * 64), tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_interrupted_download_resumes_with_range(server: _Server, tmp_path: Path) -> None:
    server.truncate_next = True
    with pytest.raises(ValueError, match="interrupted"):
        download(_info(server.url + "/m.onnx", SHA), tmp_path)
    part = tmp_path / "testmodel.onnx.part"
    assert 0 < part.stat().st_size < len(PAYLOAD)
    have = part.stat().st_size
    p = download(_info(server.url + "/m.onnx", SHA), tmp_path)
    assert server.range_headers[-1] == f"bytes={have}-"
    assert sha256_file(p) == SHA and not part.exists()


def test_interrupted_download_restarts_when_range_ignored(server: _Server, tmp_path: Path) -> None:
    server.truncate_next = True
    with pytest.raises(ValueError, match="interrupted"):
        download(_info(server.url + "/m.onnx", SHA), tmp_path)
    server.ignore_range = True
    p = download(_info(server.url + "/m.onnx", SHA), tmp_path)
    assert sha256_file(p) == SHA


def test_zip_member_and_trust_on_first_use(server: _Server, tmp_path: Path) -> None:
    info = _info(server.url + "/m.zip", UNKNOWN_SHA256, member="end2end.onnx")
    p = download(info, tmp_path)
    assert sha256_file(p) == SHA
    assert SHA in (tmp_path / "checksums.json").read_text()
    assert not any(x.name.endswith((".part", ".tmp")) for x in tmp_path.iterdir())
    p.write_bytes(PAYLOAD[:-1] + b"x")  # tampered after first use
    with pytest.raises(ValueError, match="does not match"):
        verify_file(info, p)


def test_http_error_is_clear(server: _Server, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="404"):
        download(_info(server.url + "/nothing.onnx", SHA), tmp_path)


def test_missing_model_error_names_model_dirs_and_remedy(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("CORNERMAN_MODELS_DIR", raising=False)
    monkeypatch.setenv("CORNERMAN_CACHE_DIR", str(tmp_path / "cache"))
    with pytest.raises(ValueError) as e:
        resolve_model("yolox_s", tmp_path / "offline")
    msg = str(e.value)
    assert "yolox_s" in msg and str(tmp_path / "offline") in msg and str(tmp_path / "cache" / "models") in msg
    assert "cornerman models download yolox_s" in msg
    with pytest.raises(ValueError, match="unknown model 'nope'"):
        resolve_model("nope")


def test_resolve_from_env_and_alias(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "pose_landmark_full.onnx").write_bytes(b"x")
    monkeypatch.setenv("CORNERMAN_MODELS_DIR", str(tmp_path))
    assert resolve_model("blazepose_full") == tmp_path / "pose_landmark_full.onnx"


def test_registry_entries_are_well_formed() -> None:
    for name in ("vitpose_b", "vitpose_l", "vitpose_h", "rtmpose_m", "rtmpose_l", "yolox_s", "yolox_m"):
        assert name in MODELS
    for m in MODELS.values():
        assert m.sha256 == UNKNOWN_SHA256 or len(m.sha256) == 64
        assert m.url is None or m.url.startswith("https://")
        assert m.url is not None or m.source


@pytest.mark.requires_models
def test_shared_models_match_registry_checksums(models_dir: Path) -> None:
    for name in ("yolox_nano", "rtmdet_nano", "blazepose_full", "movenet_lightning"):
        p = resolve_model(name, models_dir)
        assert sha256_file(p) == MODELS[name].sha256, name


def test_cli_list_and_verify(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from typer.testing import CliRunner

    from pipeline.cli.models import app

    monkeypatch.delenv("CORNERMAN_MODELS_DIR", raising=False)
    monkeypatch.setenv("CORNERMAN_CACHE_DIR", str(tmp_path / "cache"))
    (tmp_path / "yolox_nano.onnx").write_bytes(b"not the model")
    runner = CliRunner()
    res = runner.invoke(app, ["list", "--models-dir", str(tmp_path)])
    assert res.exit_code == 0 and "vitpose_b" in res.output
    res = runner.invoke(app, ["verify", "--models-dir", str(tmp_path)])
    assert res.exit_code == 1 and "MISMATCH" in res.output
    res = runner.invoke(app, ["download", "blazepose_full", "--models-dir", str(tmp_path)])
    assert res.exit_code == 2 and "not downloadable" in res.output


def test_model_names_accept_hyphens_and_any_case(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from pipeline.registry import canonical_name, find_model, get_model

    monkeypatch.setenv("CORNERMAN_MODELS_DIR", str(tmp_path / "shared"))
    monkeypatch.setenv("CORNERMAN_CACHE_DIR", str(tmp_path / "cache"))
    assert canonical_name(" RTMPose-M ") == "rtmpose_m"
    assert get_model("rtmpose-m") is MODELS["rtmpose_m"] and get_model("YOLOX_Nano") is MODELS["yolox_nano"]
    (tmp_path / "rtmpose_m.onnx").write_bytes(b"x")
    assert find_model("rtmpose-m", tmp_path) == tmp_path / "rtmpose_m.onnx"
    assert resolve_model("RTMPOSE-M", tmp_path) == tmp_path / "rtmpose_m.onnx"
    with pytest.raises(ValueError, match="model 'rtmpose_l' not found.*cornerman models download rtmpose_l"):
        resolve_model("rtmpose-l", tmp_path)
    with pytest.raises(ValueError, match="unknown model 'rtm-pose'"):
        get_model("rtm-pose")


def test_cli_download_takes_any_spelling(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from typer.testing import CliRunner

    import pipeline.cli.models as cli_models

    got: list[str] = []

    def fake_download(name: str, models_dir: object, progress: object, force: bool) -> Path:
        got.append(name)
        return tmp_path / f"{name}.onnx"

    monkeypatch.setattr(cli_models, "download_model", fake_download)
    res = CliRunner().invoke(cli_models.app, ["download", "rtmpose-m"])
    assert res.exit_code == 0, res.output
    assert got == ["rtmpose_m"] and "rtmpose_m.onnx" in res.output
    res = CliRunner().invoke(cli_models.app, ["download", "Movenet-Lightning"])
    assert res.exit_code == 2 and "movenet_lightning is not downloadable" in res.output and got == ["rtmpose_m"]


def test_cli_models_explains_what_a_video_session_needs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from typer.testing import CliRunner

    from pipeline.cli.main import app
    from pipeline.cli.models import session_models
    from pipeline.stages.detect2d import Detect2DConfig

    shared, cache, mine = tmp_path / "shared", tmp_path / "cache", tmp_path / "mine"
    shared.mkdir()
    mine.mkdir()
    monkeypatch.setenv("CORNERMAN_MODELS_DIR", str(shared))
    monkeypatch.setenv("CORNERMAN_CACHE_DIR", str(cache))
    needed = session_models()
    assert [n for _, n in needed[:2]] == [Detect2DConfig().detector, Detect2DConfig().pose_model]
    res = CliRunner().invoke(app, ["models", "--models-dir", str(mine)])  # no command: the list
    assert res.exit_code == 0, res.output
    out = res.output
    assert "A video session needs" in out
    for role, name in needed:
        line = next(ln for ln in out.splitlines() if f"{role}: {name}" in ln)
        assert "missing" in line
        how = f"cornerman models download {name}" if MODELS[name].url else "not downloadable"
        assert how in line, line
    for folder, label in ((mine, "--models-dir"), (shared, "shared models folder"), (cache / "models", "cache")):
        assert any(str(folder) in ln and label in ln for ln in out.splitlines()), (folder, out)
    detector = needed[0][1]
    (mine / f"{detector}.onnx").write_bytes(b"x")
    out = CliRunner().invoke(app, ["models", "list", "--models-dir", str(mine)]).output
    assert any("found" in ln and str(mine / f"{detector}.onnx") in ln for ln in out.splitlines())
