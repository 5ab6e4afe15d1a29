"""Imported once by the local executor's forkserver: every stage's step module (and their
scientific dependencies) is loaded before jobs fork, so a job starts in milliseconds."""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)

try:
    from pipeline.runner import get_specs

    get_specs()
except Exception as e:  # noqa: BLE001  (a broken step must fail its jobs readably, not the forkserver)
    log.warning("preloading the pipeline stages failed (jobs will import them themselves): %s", e)
