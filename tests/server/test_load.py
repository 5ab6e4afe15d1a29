"""Bounded load test on loopback: 50 concurrent session/job submissions plus polling."""

from __future__ import annotations

import pytest

from server.loadtest import run_bench

pytestmark = [pytest.mark.e2e, pytest.mark.slow]  # slow: kept out of the 3-minute fast tier


def test_load_nothing_lost_nothing_twice_db_consistent() -> None:
    (row,) = run_bench(n_submissions=50, n_workers=2, n_pollers=3, n_frames=20, timeout_s=400)
    assert row["errors"] == 0, row["first_errors"]
    assert row["jobs_submitted"] == 50 and row["jobs_lost"] == 0
    assert row["jobs_completed"] == 50 and row["jobs_failed"] == 0
    assert row["jobs_claimed_twice"] == 0
    assert row["db_sessions"] == 50 and row["db_jobs"] == 50 and row["sessions_with_one_job"] == 50
    assert row["integrity"] == "ok" and row["foreign_key_violations"] == 0 and row["journal_mode"] == "wal"
