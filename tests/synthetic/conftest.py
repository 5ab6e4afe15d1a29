"""Fixtures for the synthetic-bout tests: one default bout shared by the module tests."""

from __future__ import annotations

import pytest

from pipeline.synthetic import SyntheticBout, SyntheticConfig, make_bout


@pytest.fixture(scope="session")
def default_bout() -> SyntheticBout:
    """The default demo bout (300 frames, 4 cameras, seed 0)."""
    return make_bout(SyntheticConfig())
