"""pipeline.shared: the shared models/data folders are found without any variable set."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline import shared


def _unset(monkeypatch: pytest.MonkeyPatch) -> None:
    for var in (shared.MODELS_ENV, shared.DATA_ENV, shared.SHARED_ENV):
        monkeypatch.delenv(var, raising=False)


def test_a_shared_folder_beside_the_checkout_is_found(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    _unset(monkeypatch)
    repo = tmp_path / "main"
    (tmp_path / "shared" / "data" / "shelf").mkdir(parents=True)
    (tmp_path / "shared" / "models").mkdir(parents=True)
    monkeypatch.setattr(shared, "_REPO", repo)
    monkeypatch.chdir(tmp_path)  # the working directory's ../shared does not exist
    assert shared.shared_data_dir() == (tmp_path / "shared" / "data").resolve()
    assert shared.shared_models_dir() == (tmp_path / "shared" / "models").resolve()
    assert shared.dataset_dir("shelf") == (tmp_path / "shared" / "data" / "shelf").resolve()
    with pytest.raises(ValueError, match="dataset 'nope' not found.*CORNERMAN_TEST_DATA_DIR"):
        shared.dataset_dir("nope")


def test_variables_win_and_a_wrong_one_is_not_replaced_by_a_guess(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    _unset(monkeypatch)
    (tmp_path / "mine").mkdir()
    monkeypatch.setenv(shared.DATA_ENV, str(tmp_path / "mine"))
    assert shared.shared_data_dir() == tmp_path / "mine"
    monkeypatch.setenv(shared.DATA_ENV, str(tmp_path / "missing"))
    assert shared.shared_data_dir() is None
    assert "missing" in shared.describe_lookup()
    monkeypatch.delenv(shared.DATA_ENV)
    (tmp_path / "sh" / "models").mkdir(parents=True)
    monkeypatch.setenv(shared.SHARED_ENV, str(tmp_path / "sh"))
    assert shared.shared_models_dir() == tmp_path / "sh" / "models"
