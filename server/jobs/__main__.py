"""``python -m server.jobs``: one worker process (what ``cornerman worker`` runs)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from server.cli import worker


def main() -> None:
    ap = argparse.ArgumentParser(prog="python -m server.jobs", description="cornerman job worker")
    ap.add_argument("--home", type=Path, default=None, help="server home (default: CORNERMAN_HOME or ./data/server)")
    ap.add_argument("--executor", choices=("local", "ray"), default="local")
    ap.add_argument("--ray-address", default=None)
    ap.add_argument("--concurrency", type=int, default=1)
    a = ap.parse_args()
    logging.basicConfig(level=logging.INFO)
    worker(a.home, a.executor, a.ray_address, a.concurrency)


if __name__ == "__main__":
    main()
