"""Threads: how many cores this process may use, and one shared pool per thread count.

The compiled kernels release the GIL, so plain Python threads run them side by side.
"""

from __future__ import annotations

import itertools
import os
from concurrent.futures import ThreadPoolExecutor, wait

_POOLS: dict[int, ThreadPoolExecutor] = {}


def default_threads() -> int:
    """Cores this process may use."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def _pool(threads: int) -> ThreadPoolExecutor:
    """The pool that works beside the calling thread when ``threads`` threads run: ``threads - 1`` threads."""
    if threads not in _POOLS:
        _POOLS[threads] = ThreadPoolExecutor(max_workers=threads - 1, thread_name_prefix="isplat")
    return _POOLS[threads]


def run_parallel(fn, items, threads: int, meanwhile=None) -> list:
    """``[fn(x) for x in items]`` on ``threads`` threads when there is more than one item: the calling thread
    and ``threads - 1`` of a pool, each taking the next item when free (the calling thread does not sleep
    while the pool works and wake when it is done: on a loaded machine both cost a wait for a core).
    ``meanwhile()``, if given, runs in the calling thread before it takes items (after the items when they
    all run here); the items are all finished before this returns or raises (``meanwhile``'s error, else the
    first item's in the items' order)."""
    items = list(items)
    if threads <= 1 or len(items) <= 1:
        out = [fn(x) for x in items]
        if meanwhile is not None:
            meanwhile()
        return out
    n = len(items)
    results, errors = [None] * n, [None] * n
    queue = itertools.count()           # next() is atomic: each item is taken once

    def take():
        while (i := next(queue)) < n:
            try:
                results[i] = fn(items[i])
            except BaseException as e:  # noqa: BLE001 (raised in the caller, after all items are done)
                errors[i] = e

    futures = [_pool(threads).submit(take) for _ in range(min(threads, n) - 1)]
    try:
        if meanwhile is not None:
            meanwhile()
    finally:
        take()
        # a pool thread that has not started has nothing left to take (also when this runs in a pool thread)
        wait([f for f in futures if not f.cancel()])
    for e in errors:
        if e is not None:
            raise e
    return results
