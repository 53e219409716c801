"""Batches of views, and frames split into slabs, on a Dask cluster (the optional ``dask`` extra).

``isplat render SCENE --scheduler local:N`` (a LocalCluster of N single-threaded worker processes on
127.0.0.1) or ``--scheduler tcp://HOST:PORT`` (a running cluster) renders a batch of views on the workers:

- **Batches** (:func:`render_views`): one task per view. Each worker opens the scene's files and makes the
  selection once and keeps it (a worker-side cache keyed by the views' :class:`~isplat.request.RenderRequest`:
  the files' identity, path, size and modification time, and everything the selection depends on), so the
  following views cost one frame each. Frames come back in order. A worker that dies is replaced and its
  views are rendered again elsewhere (Dask reschedules them; ``retries`` covers exceptions too).
- **Slabs** (``slabs=K``): each frame's slices in visibility order are cut into K slabs
  (:func:`isplat.frame.slab_bounds`); slab s goes to worker ``s mod W`` and is rendered from a selection
  restricted to its slices (:func:`isplat.slabs.restrict`, cached on that worker), and the partial images are
  composited in visibility order by a tree of pairwise 'over' tasks (log2 K rounds, no all-to-one step).
  Equal to the one-process frame to rounding with early termination off; with it on, each slab stops on its
  own and the premultiplied image differs by at most ``1 - et`` per channel (docs/design.md, docs/scale.md).

Nothing here is imported unless ``--scheduler`` is given; without Dask that option fails with one line
naming the extra.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import time
import uuid

import numpy as np

from .errors import IsplatError
from .request import SelectionCache, file_identity  # noqa: F401  (file_identity: public here too)

log = logging.getLogger(__name__)

EXTRA = "dask"
RETRIES = 2                 # a task that raises is tried again this many times (a dead worker does not count)
_CACHE_SIZE = 4             # whole selections kept per worker
_SLAB_CACHE_SIZE = 16       # slab selections kept per worker
_cache = SelectionCache(_CACHE_SIZE)            # whole selections, with their frames' band learning
_slab_cache = SelectionCache(_SLAB_CACHE_SIZE)  # slabs' selections


def require_dask():
    """Import ``distributed`` or fail with one line naming the extra."""
    try:
        import distributed
    except ImportError:
        raise IsplatError(f"--scheduler needs Dask, which is not installed: pip install 'isplat[{EXTRA}]'") from None
    return distributed


def local_cluster(n_workers: int, threads_per_worker: int = 1):
    """A LocalCluster of ``n_workers`` processes bound to 127.0.0.1, no dashboard (the scheduler's small HTTP
    server of health routes takes a free port on 127.0.0.1, not 8787)."""
    distributed = require_dask()
    return distributed.LocalCluster(n_workers=n_workers, threads_per_worker=threads_per_worker, processes=True,
                                    host="127.0.0.1", dashboard_address=None, silence_logs=logging.ERROR,
                                    scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})


@contextlib.contextmanager
def connect(spec: str):
    """A Client for ``local:N`` (a LocalCluster made here and closed on exit) or ``tcp://HOST:PORT``."""
    distributed = require_dask()
    spec = str(spec)
    if spec.startswith("local:"):
        n = spec[len("local:"):]
        if not n.isdigit() or not 1 <= int(n) <= 256:
            raise IsplatError(f"--scheduler {spec}: expected local:N with N worker processes, 1..256")
        with local_cluster(int(n)) as cluster, distributed.Client(cluster) as client:
            yield client
    elif spec.startswith(("tcp://", "tls://")):
        try:
            client = distributed.Client(spec, timeout="20s")
        except OSError as exc:
            raise IsplatError(f"--scheduler {spec}: cannot reach the scheduler ({exc})") from None
        with client:
            yield client
    else:
        raise IsplatError(f"--scheduler {spec}: expected local:N or tcp://HOST:PORT")


# --- the selection's identity and the worker-side cache ----------------------------------------------------------

def request_for(scene, views, method: str | None = None):
    """The :class:`~isplat.request.RenderRequest` of ``views`` (isplat.frame.View) of ``scene``'s files: the
    workers' cache key, and all they need to make the selection."""
    from .augfile import open_augmented
    from .frame import axes_of
    from .request import RenderRequest

    return RenderRequest.from_files(scene, open_augmented(scene.data.augmented), axes_of(views), method)


def _select_here(request):
    """Read the selection of ``request`` (of its slab only, if it has one) from the files this worker sees,
    after checking they are the client's."""
    from .request import _identity_or_path
    from .selection import select

    if ("files", _identity_or_path(request.augmented), _identity_or_path(request.index)) != request.source:
        raise IsplatError(f"{request.augmented}: the worker's files differ from the client's (path, size or "
                          f"modification time); put them on storage every worker shares")
    log.debug(f"worker {os.getpid()}: selecting for {request.augmented}")
    return select(request)


def worker_selection(request):
    """``(selection, band learning)`` of ``request`` on this worker: made once (files read here), then reused."""
    return _cache.get(request, lambda: _select_here(request))


def slab_selection(request, axis: str, slices: np.ndarray):
    """The part of the selection that renders ``slices`` of ``axis`` on this worker (cached): cut from the
    whole selection if this worker holds it, else read from the files for those slices alone (the index
    blocks of the transfer function's densities along ``axis`` are decoded, then only the slab's are kept and
    only their channel values gathered), so the worker holds only its slabs' voxels (docs/scale.md)."""
    from .slabs import restrict, slice_runs

    slab = dataclasses.replace(request, axes=axis, slab=tuple(slice_runs(slices, 1 << 62)))

    def make():
        whole = _cache.peek(request)
        if whole is not None:
            return restrict(whole[0], axis, slices)
        return _select_here(slab)
    return _slab_cache.get(slab, make)[0]


def clear_cache() -> None:
    """Forget this process's selections."""
    _cache.clear()
    _slab_cache.clear()


# --- tasks (run on the workers) ------------------------------------------------------------------------------

def _worker_threads(view):
    """A view whose ``render.threads = 0`` (every core) uses this worker's thread count instead."""
    if view.render.threads:
        return view
    try:
        from distributed import get_worker
        n = get_worker().state.nthreads
    except (ImportError, ValueError, AttributeError):
        return view
    return dataclasses.replace(view, render=dataclasses.replace(view.render, threads=int(n)))


def view_task(request, view, et):
    """Render one view on a worker: (straight RGBA (H, W, 4), FrameStats, LoadReport)."""
    from .frame import render_frame

    sel, bands = worker_selection(request)
    rgba, stats = render_frame(sel, _worker_threads(view), et, bands)
    return rgba, stats, sel.report


def slab_task(request, view, start, stop, et):
    """Render slab ``order[start:stop]`` of a view from that slab's selection: (Partial, LoadReport,
    seconds). The counters are reduced over the worker's bands to one row as :func:`isplat.frame.frame_stats`
    reads them (the deepest band's examined voxels and slices; the others summed), so partials of workers with
    different thread counts composite, and the rows add up over the slabs."""
    from .frame import prepare, render_slab

    view = _worker_threads(view)
    axis = view.axis_sign[0]
    sel = slab_selection(request, axis, view.order[start:stop])
    t0 = time.perf_counter()
    part = render_slab(prepare(sel, view, et), start, stop)
    bs = part.band_stats
    part.band_stats = np.array([[bs[:, 0].max(), bs[:, 1].sum(), bs[:, 2].sum(), bs[:, 3].max()]], dtype=np.int64)
    return part, sel.report, time.perf_counter() - t0


def composite_task(front, back, et):
    """``front`` over ``back`` (each a (Partial, LoadReport, seconds)), in visibility order; the seconds
    add up (worker time spent on the frame), and so do the slabs' reports (bytes read and needed)."""
    from .frame import composite

    t0 = time.perf_counter()
    out = composite(front[0], back[0], et)
    return out, front[1].plus(back[1]), front[2] + back[2] + time.perf_counter() - t0


def finish_task(parts, view):
    """The composited partial of a view as (straight RGBA, FrameStats, LoadReport); the stats' seconds are
    the workers' time on the frame."""
    from .frame import finish_image, frame_stats

    part, report, seconds = parts
    return finish_image(part.img, view.background, view.render.supersample), frame_stats(view, part, seconds), report


# --- the client's side ---------------------------------------------------------------------------------------

def _workers(client, timeout: float = 60.0) -> list[str]:
    """The cluster's workers now; when it has none (all of them restarting, or not yet joined), the ones that
    join within ``timeout`` seconds."""
    workers = sorted(client.scheduler_info(n_workers=-1)["workers"])
    if not workers:
        try:
            client.wait_for_workers(1, timeout=timeout)
        except TimeoutError:
            raise IsplatError(f"the Dask cluster at {client.scheduler.address} has no workers "
                              f"(none joined in {timeout:g} s)") from None
        workers = sorted(client.scheduler_info(n_workers=-1)["workers"])
    return workers


def reduce_pairwise(items: list, combine):
    """Join ``items`` (in order) by a tree of pairs: ``combine(items[0], items[1])``, ``combine(items[2],
    items[3])``, ... then the same on the results, ceil(log2 n) rounds; an odd last item waits a round.
    ``combine(front, back, level, i)`` keeps the order, so an associative, non-commutative join is exact."""
    level = 0
    while len(items) > 1:
        nxt = [combine(items[i], items[i + 1], level, i // 2) for i in range(0, len(items) - 1, 2)]
        items = nxt + ([items[-1]] if len(items) % 2 else [])
        level += 1
    return items[0]


def submit_slabs(client, request, view, n_slabs: int, et, token: str, workers=None):
    """The future of one frame's composited partial, (Partial, LoadReport, seconds): ``n_slabs`` slabs
    rendered on workers ``s mod W``, composited pairwise in visibility order (:func:`reduce_pairwise`)."""
    from .frame import slab_bounds

    workers = workers or _workers(client)
    et_val = float(view.render.early_termination if et is None else et)
    parts = [client.submit(slab_task, request, view, a, b, et, key=f"isplat-slab-{token}-{s}",
                           workers=[workers[s % len(workers)]], allow_other_workers=True, retries=RETRIES)
             for s, (a, b) in enumerate(slab_bounds(len(view.order), n_slabs))]
    return reduce_pairwise(parts, lambda f, b, level, i: client.submit(
        composite_task, f, b, et_val, key=f"isplat-over-{token}-{level}-{i}", retries=RETRIES))


def render_views(client, request, views, slabs: int = 1, et=None, method: str | None = None, bar=None):
    """Render ``views`` on the cluster; yields ``(n, rgba, FrameStats, LoadReport)`` in view order.

    ``request``: the views' :class:`~isplat.request.RenderRequest` (or a scene: its request is made here, with
    ``method``, :func:`request_for`). ``slabs`` > 1 splits each frame into that many slabs (sort-last).
    ``bar``: a progress bar to update once per frame.
    """
    from distributed import as_completed

    from .request import RenderRequest

    if not isinstance(request, RenderRequest):
        request = request_for(request, views, method)
    batch = uuid.uuid4().hex[:12]
    workers = _workers(client) if slabs > 1 else None
    futures = []
    for n, view in enumerate(views):
        token = f"{batch}-{n}"
        if slabs > 1:
            part = submit_slabs(client, request, view, slabs, et, token, workers)
            futures.append(client.submit(finish_task, part, view, key=f"isplat-finish-{token}", retries=RETRIES))
        else:
            futures.append(client.submit(view_task, request, view, et, key=f"isplat-view-{token}",
                                         retries=RETRIES))
    position = {f.key: n for n, f in enumerate(futures)}
    done, next_n = {}, 0
    for fut in as_completed(futures):
        n = position[fut.key]
        done[n] = fut.result()
        futures[n] = None               # release the frame on the cluster
        if bar is not None:
            bar.update(1)
        while next_n in done:
            yield (next_n, *done.pop(next_n))
            next_n += 1
