"""Threads: how many cores this process may use, and one shared pool per thread count.

The compiled kernels release the GIL, so plain Python threads run them side by side.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor, wait

_POOLS: dict[int, ThreadPoolExecutor] = {}


def default_threads() -> int:
    """Cores this process may use."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def run_parallel(fn, items, threads: int, meanwhile=None) -> list:
    """``[fn(x) for x in items]``, on a pool of ``threads`` threads when there is more than one item.
    ``meanwhile()``, if given, runs in the calling thread while the pool works (after the items when they run
    here); the items are all finished before this returns or raises."""
    items = list(items)
    if threads <= 1 or len(items) <= 1:
        out = [fn(x) for x in items]
        if meanwhile is not None:
            meanwhile()
        return out
    if threads not in _POOLS:
        _POOLS[threads] = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="isplat")
    futures = [_POOLS[threads].submit(fn, x) for x in items]
    try:
        if meanwhile is not None:
            meanwhile()
    finally:
        wait(futures)                   # no item left running on buffers the caller may drop
    return [f.result() for f in futures]
