"""``bundle``: one file as is, several as a ZIP whose bytes depend on the files only."""

from __future__ import annotations

import io
import time
import zipfile

import pytest

from pipeline.io.export.write import ZIP_DATE_TIME, bundle

FILES = {"scene.xml": b"<mujoco/>", "motion.npz": bytes(range(256)) * 8, "replay.py": b"print('hi')\n"}


def test_one_file_is_sent_as_is() -> None:
    assert bundle({"a.csv": b"x,y\n"}) == b"x,y\n"


def test_the_same_files_give_the_same_zip_at_any_time(monkeypatch: pytest.MonkeyPatch) -> None:
    first = bundle(FILES)
    later = time.time() + 3 * 3600 + 7  # another hour, minute and (even) second
    monkeypatch.setattr(time, "time", lambda: later)
    assert bundle(FILES) == first
    z = zipfile.ZipFile(io.BytesIO(first))
    assert z.namelist() == list(FILES)  # in the given order
    for info in z.infolist():
        assert info.date_time == ZIP_DATE_TIME and info.compress_type == zipfile.ZIP_DEFLATED
        assert (info.external_attr >> 16) & 0o777 == 0o644
        assert z.read(info) == FILES[info.filename]
