"""Threads: how many cores this process may use, and one shared pool per thread count.

The compiled kernels release the GIL, so plain Python threads run them side by side.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

_POOLS: dict[int, ThreadPoolExecutor] = {}


def default_threads() -> int:
    """Cores this process may use."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def run_parallel(fn, items, threads: int) -> list:
    """``[fn(x) for x in items]``, on a pool of ``threads`` threads when there is more than one item."""
    items = list(items)
    if threads <= 1 or len(items) <= 1:
        return [fn(x) for x in items]
    if threads not in _POOLS:
        _POOLS[threads] = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="isplat")
    return list(_POOLS[threads].map(fn, items))
