"""``cornerman serve`` / ``demo``: a busy port is refused before any work; the links are
printed only once the API answers, one per role, coach first."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from rich.console import Console
from typer.testing import CliRunner

from pipeline.cli.main import app
from server.cli import WORKER_NICENESS, check_port, free_port, print_links

runner = CliRunner()


@pytest.fixture
def busy_port() -> Iterator[int]:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield int(s.getsockname()[1])


def test_check_port(busy_port: int) -> None:
    with pytest.raises(ValueError, match=rf"cannot serve on 127\.0\.0\.1:{busy_port}: .*pass --port \d+ \(free now\)"):
        check_port("127.0.0.1", busy_port)
    check_port("127.0.0.1", free_port())


def test_demo_on_a_busy_port_fails_before_any_compute(busy_port: int, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    import pipeline.synthetic

    def no_compute(*a: object, **k: object) -> None:
        raise AssertionError("the demo computed before checking the port")

    monkeypatch.setattr(pipeline.synthetic, "make_demo_session", no_compute)
    monkeypatch.setenv("CORNERMAN_HOME", str(tmp_path / "home"))
    r = runner.invoke(app, ["demo", "--port", str(busy_port), "--session-dir", str(tmp_path / "demo")])
    assert r.exit_code == 2, r.output
    assert f"cannot serve on 127.0.0.1:{busy_port}" in r.output and "--port" in r.output
    assert "token" not in r.output and "http://" not in r.output  # no links for a server that never ran
    assert not (tmp_path / "demo").exists()


def test_serve_on_a_busy_port_fails_before_touching_the_home(busy_port: int, tmp_path: Path) -> None:
    r = runner.invoke(app, ["serve", "--port", str(busy_port), "--home", str(tmp_path / "home")])
    assert r.exit_code == 2 and f"cannot serve on 127.0.0.1:{busy_port}" in r.output
    assert not (tmp_path / "home").exists()


def test_links_are_labelled_by_role_coach_first() -> None:
    console = Console(record=True, width=300)
    print_links(console, "http://127.0.0.1:8000", {"admin": "tA", "annotator": "tN", "coach": "tC"}, demo_id=3)
    text = console.export_text()
    lines = [ln.strip() for ln in text.splitlines() if " token t" in ln]
    assert [ln.split()[0] for ln in lines] == ["coach", "annotator", "admin"]
    assert lines[0].endswith("token tC") and "read-only" in lines[0]
    assert "?token=" not in text and "http://127.0.0.1:8000/login" in text  # no token in any link
    assert "session 3" in text and "http://127.0.0.1:8000/viewer/3/" in text


def test_serve_prints_the_links_once_the_api_answers(tmp_path: Path) -> None:
    port = free_port()
    code = ("from pathlib import Path; from server.cli import serve; "
            f"serve(host='127.0.0.1', port={port}, workers=1, home=Path({str(tmp_path / 'home')!r}))")
    log_path = tmp_path / "serve.log"
    env = dict(os.environ, OMP_NUM_THREADS="1")
    with open(log_path, "wb") as logf:
        proc = subprocess.Popen([sys.executable, "-c", code], stdout=logf, stderr=subprocess.STDOUT, env=env,
                                start_new_session=True)
    try:
        t_end = time.monotonic() + 60
        while " token cm_" not in log_path.read_text() or "admin" not in log_path.read_text().split("ready", 1)[-1]:
            assert proc.poll() is None and time.monotonic() < t_end, log_path.read_text()
            time.sleep(0.2)
        log = log_path.read_text()
        assert log.index("Uvicorn running on") < log.index("cornerman server ready") < log.index("/login")
        roles = [ln.split()[0] for ln in log.splitlines() if " token cm_" in ln]
        assert roles == ["coach", "annotator", "admin"] and "?token=" not in log
        # The job worker runs at a lower CPU priority than the server (WORKER_NICENESS), so that
        # a pipeline job leaves the pages responsive; it lowers it as it starts.
        pids = [int(x) for x in re.findall(r"\d+", log.split("workers started (pids", 1)[1].split(")", 1)[0])]
        want = min(19, os.getpriority(os.PRIO_PROCESS, proc.pid) + WORKER_NICENESS)
        t_end = time.monotonic() + 60
        while [os.getpriority(os.PRIO_PROCESS, p) for p in pids] != [want] * len(pids):
            assert time.monotonic() < t_end, ([os.getpriority(os.PRIO_PROCESS, p) for p in pids], want)
            time.sleep(0.2)
        assert len(pids) == 1
    finally:
        proc.send_signal(signal.SIGINT)  # serve stops its workers and exits without a traceback
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
    assert proc.returncode == 0 and "Traceback" not in log_path.read_text(), log_path.read_text()[-2000:]
