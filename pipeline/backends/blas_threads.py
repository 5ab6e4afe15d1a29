"""Pin BLAS to one thread while the physics runs, so its result does not depend on the core count.

The iLQR is chaotic: a rounding difference in one backward pass grows into a different
trajectory. OpenBLAS splits a matrix product over its threads and sums the parts in a
different order on 1 and on 2 threads, so the same bout gave different results on
different machines (bench bout 2, multi-person: deepest capsule overlap 25.6 mm with
``OMP_NUM_THREADS=2``, 6.3 mm with 1; with the pin both give 6.3 mm). The matrices are
small (≈ 250 × 250), so the single thread costs nothing measurable (backward passes
7.3 s on 2 threads, 7.9 s on 1 while another process shared the machine).

The limit is process-wide (it is the BLAS library's own setting). Nested or concurrent
users in one process share it: the first sets it, the last restores the original.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

_lock = threading.Lock()
_users = 0
_limiter: Any = None


@contextmanager
def single_blas_thread() -> Iterator[None]:
    """Run the body with every loaded BLAS library limited to one thread."""
    from threadpoolctl import threadpool_limits

    global _users, _limiter
    with _lock:
        if _users == 0:
            _limiter = threadpool_limits(limits=1, user_api="blas")
        _users += 1
    try:
        yield
    finally:
        with _lock:
            _users -= 1
            if _users == 0 and _limiter is not None:
                _limiter.restore_original_limits()
                _limiter = None


def blas_threads() -> list[int]:
    """Thread counts of the loaded BLAS libraries (for tests and diagnostics)."""
    from threadpoolctl import threadpool_info

    return [int(i["num_threads"]) for i in threadpool_info() if i.get("user_api") == "blas"]
