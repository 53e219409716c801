"""Dask: a batch of views on workers, and the sort-last model of one frame split into slabs.
``python -m benchmarks scale [--quick]`` (part of ``make bench``; needs the ``dask`` extra).

Measures, warm (numba cache present, selections made), the `head` sample with examples/head.toml (bone, lit):

* a 36-view orbit at 512 x 512: one process with 2 threads against a LocalCluster of 2 single-threaded worker
  processes (wall time of the batch, frames back in the client), interleaved, medians;
* the model of a frame split into K slabs (isplat.distributed.submit_slabs): per-slab time (the per-frame
  tables of ``prepare`` plus the slab's slices), the composite ('over') time, the bytes of a partial image
  and of a frame, and the cluster's per-task latency and transfer rate; from them the frame time on K workers;
* that prediction against the measured frame time on 1 and 2 workers, and the predictions for 8, 64 and 512
  workers with the assumptions stated.

Writes the section "scale" of docs/scale.md.
"""

from __future__ import annotations

import math
import pickle
import statistics
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from . import _doc

SECTION = "scale"        # the section of its page this benchmark writes
TECHNIQUES = ["post"]     # render.classification of its rows (the page's stamp)
SOURCES = _doc.sources(_doc.RENDER, _doc.READ, _doc.SAMPLES, ("isplat/distributed.py", "isplat/slabs.py",
                       "isplat/augment.py", "examples/head.toml", "benchmarks/scale.py"))
from .render import ROOT, ensure_head

SCENE = ROOT / "examples" / "head.toml"


def _log(msg):
    print(f"[scale] {msg}", file=sys.stderr, flush=True)


def _scene(aug, idx, size, *extra):
    from isplat.scene import load_scene

    return load_scene(SCENE, [f'data.augmented="{aug}"', f'data.index="{idx}"', f"image.width={size}",
                              f"image.height={size}", *extra])


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def _med(xs):
    return statistics.median(xs)


def batch(client, aug, idx, size, n_views, repeats):
    """Wall time of the orbit: one process (2 threads) and the cluster (workers 1 thread each), interleaved."""
    from isplat import distributed as D
    from isplat.renderer import Renderer

    one = Renderer(_scene(aug, idx, size, f"views.orbit_steps={n_views}", "render.threads=2"))
    dask_scene = _scene(aug, idx, size, f"views.orbit_steps={n_views}", "render.threads=0")
    views = one.views
    for n in range(len(views)):                       # warm: kernels, the selection on every worker
        one.render_view(n)
    list(D.render_views(client, dask_scene, views))
    t_one, t_dask = [], []
    for _ in range(repeats):
        t, frames = _timed(lambda: [one.render_view(n)[0] for n in range(len(views))])
        t_one.append(t)
        t, got = _timed(lambda: list(D.render_views(client, dask_scene, views)))
        t_dask.append(t)
    same = all(np.array_equal(g[1], f) for g, f in zip(got, frames))
    return _med(t_one), _med(t_dask), same, one.selection


def slab_model(sel, view, ks, repeats):
    """In one process, one thread (as a worker): per-slab prepare and render times for K slabs, 'over' time."""
    from isplat import frame as F
    from isplat.slabs import restrict

    axis = view.axis_sign[0]
    n = len(view.order)
    out = {}
    for k in ks:
        prep, rend = [], []
        parts = []
        for a, b in F.slab_bounds(n, k):
            s = restrict(sel, axis, view.order[a:b])
            tp, tr = [], []
            for _ in range(repeats):
                t, setup = _timed(lambda: F.prepare(s, view))
                tp.append(t)
                t, part = _timed(lambda: F.render_slab(setup, a, b))
                tr.append(t)
            prep.append(_med(tp))
            rend.append(_med(tr))
            parts.append(part)
        out[k] = dict(prep=prep, render=rend, parts=parts)
    p = out[ks[-1]]["parts"]
    t_over = _med([_timed(lambda: F.composite(p[0], p[1], 0.99))[0] for _ in range(max(3, repeats))])
    t_finish = _med([_timed(lambda: F.finish_image(p[0].img, view.background))[0] for _ in range(max(3, repeats))])
    bytes_partial = len(pickle.dumps(p[0], protocol=5))
    bytes_frame = F.finish_image(p[0].img, view.background).nbytes
    return out, t_over, t_finish, bytes_partial, bytes_frame


def _noop(x=None):
    return 0 if x is None else int(x.nbytes)


def _pass(x):
    return x


def cluster_costs(client, nbytes, repeats, floor=32 << 20):
    """The cluster's costs, measured with tasks that do nothing: the round trip of one task (submit, run,
    result back), each further task of a chain whose steps alternate between the two workers, and the rate of
    moving ``nbytes`` to a worker."""
    from isplat.distributed import _workers

    w = _workers(client)
    n = repeats
    first = _med([_timed(lambda: client.submit(_noop, pure=False).result())[0] for _ in range(n)])

    def chain(steps):
        f = client.submit(_noop, pure=False, workers=[w[0]])
        for i in range(steps):
            f = client.submit(_pass, f, pure=False, workers=[w[(i + 1) % len(w)]])
        return f.result()
    per_hop = max(0.0, (_med([_timed(lambda: chain(2))[0] for _ in range(n)]) - first) / 2)
    size = max(nbytes, floor)                                        # large enough to time above the noise
    arr = np.ones(size // 4, np.float32)
    moved = []
    for _ in range(n):
        t, fut = _timed(lambda: client.scatter(arr, direct=False, hash=False))
        moved.append(t)
        del fut
    return first, per_hop, size / max(1e-3, _med(moved))


def predict(k, m, t_over, t_finish, b_part, b_frame, first, per_hop, bw, n_slices):
    """Frame time on k workers (one slab each): a chain slab -> L = ceil(log2 k) rounds of 'over' -> finish
    -> client: the first task's round trip, one hop per further task, the work and the bytes moved."""
    k = min(k, n_slices)
    levels = math.ceil(math.log2(k)) if k > 1 else 0
    slab = _slab_time(m)
    return first + (1 + levels) * per_hop + slab + levels * (t_over + b_part / bw) + t_finish + b_frame / bw


def measured_split(client, scene, view, k, workers, b_part, b_frame, t_finish):
    """One frame split into k slabs on the cluster: the model's terms as the workers measure them (the k slabs
    rendered at once, each on its worker, then one 'over' on a worker; the cluster's latencies and transfer
    rate), and right after, the frame end to end.
    ``t_finish``: the finishing work, measured in this process. Returns (predicted, measured) seconds."""
    from isplat import distributed as D
    from isplat.frame import slab_bounds

    request = D.request_for(scene, [view])
    tag = f"{k}-{time.time_ns()}"
    slabs = [client.submit(D.slab_task, request, view, a, b, None, workers=[workers[s % len(workers)]],
                           key=f"bench-slab-{tag}-{s}") for s, (a, b) in enumerate(slab_bounds(len(view.order), k))]
    res = client.gather(slabs)
    t_slab = max(r[2] for r in res)
    t_over = 0.0
    if k > 1:
        joined = client.submit(D.composite_task, slabs[0], slabs[1], 0.99, key=f"bench-over-{tag}").result()
        t_over = joined[2] - res[0][2] - res[1][2]
    first, per_hop, bw = cluster_costs(client, b_part, 3, floor=0)
    levels = math.ceil(math.log2(k)) if k > 1 else 0
    predicted = first + (1 + levels) * per_hop + t_slab + levels * (t_over + b_part / bw) + t_finish + b_frame / bw
    del slabs, res
    part = D.submit_slabs(client, request, view, k, None, f"bench-{tag}", workers[:k])
    measured = _timed(lambda: client.submit(D.finish_task, part, view, key=f"bench-frame-{tag}").result())[0]
    return predicted, measured


def extrapolate(m8, n_slices, k):
    """Per-slab time on k workers from the K=8 measurement: the render work divided by k with the measured
    imbalance (max / mean), the per-frame tables (prepare) in full on every worker."""
    mean_r = statistics.mean(m8["render"]) * 8
    imb = max(m8["render"]) / max(1e-12, statistics.mean(m8["render"]))
    kk = min(k, n_slices)
    return dict(prep=[max(m8["prep"])], render=[mean_r / kk * imb])


def run(out_dir: Path, quick: bool) -> Path:
    from distributed import Client

    from isplat import distributed as D
    from isplat.frame import views_for
    from isplat.augfile import open_augmented

    shape = (64, 64, 56) if quick else None
    size, n_views, repeats = (64, 4, 2) if quick else (512, 36, 5)
    aug, idx = ensure_head(shape)
    ks = (1, 2, 4, 8)
    with D.local_cluster(2) as cluster, Client(cluster) as client:
        _log("batch")
        t_one, t_dask, same, sel = batch(client, aug, idx, size, n_views, repeats)
        scene1 = _scene(aug, idx, size, "render.threads=1")
        view = views_for(scene1, open_augmented(aug))[0]
        _log("slab model")
        model, t_over, t_finish, b_part, b_frame = slab_model(sel, view, ks, repeats)
        first, per_hop, bw = cluster_costs(client, b_part, max(10, 3 * repeats))
        workers = D._workers(client)
        _log("split frames on 1 and 2 workers")
        pm = {1: [], 2: []}
        for _ in range(2):                                             # warm: slab selections on their workers
            for k in (1, 2):
                measured_split(client, scene1, view, k, workers, b_part, b_frame, t_finish)
        for _ in range(repeats):                                       # interleaved
            for k in (1, 2):
                pm[k].append(measured_split(client, scene1, view, k, workers, b_part, b_frame, t_finish))
    measured = dict(locals())
    return _page(out_dir, SimpleNamespace(**measured))


def _slab_time(m):
    return max(p + r for p, r in zip(m["prep"], m["render"]))


def _page(out_dir, r) -> Path:
    """Write the section from the measurements ``r`` (the locals of :func:`run`)."""
    quick, shape, size, n_views, repeats, sel, view, model, ks = (r.quick, r.shape, r.size, r.n_views, r.repeats,
                                                                   r.sel, r.view, r.model, r.ks)
    t_one, t_dask, same, t_over, t_finish, b_part, b_frame = (r.t_one, r.t_dask, r.same, r.t_over, r.t_finish,
                                                              r.b_part, r.b_frame)
    first, per_hop, bw, pm = r.first, r.per_hop, r.bw, r.pm
    n_slices = len(view.order)
    pred = {k: _med([p for p, _ in v]) for k, v in pm.items()}
    meas = {k: _med([m for _, m in v]) for k, v in pm.items()}
    BW_NET, HOP_NET = 1.25e9, 1e-3                                    # assumptions for a real cluster
    big = {k: predict(k, extrapolate(model[8], n_slices, k), t_over, t_finish, b_part, b_frame, 2 * HOP_NET,
                      HOP_NET, BW_NET, n_slices) for k in (8, 64, 512)}
    ms = lambda s: f"{s * 1000:.1f} ms"                               # noqa: E731
    mib = lambda b: f"{b / 2**20:.2f} MiB"                            # noqa: E731
    sel_mib = sel.held_bytes() / 2**20
    tech = "post" if sel.post else "pre"
    TECHNIQUES[:] = [tech]                  # the stamp names the technique examples/head.toml rendered with
    def row(k):
        rend = model[k]["render"]
        mean = statistics.mean(rend)
        return (f"| {k} | {ms(max(model[k]['prep']))} | {ms(max(rend))} | {ms(mean)} "
                f"| {max(rend) / max(1e-12, mean):.2f} | {sum(rend) / max(1e-12, sum(model[1]['render'])):.2f} |")
    rows = "\n".join(row(k) for k in ks)
    t1 = sum(model[1]["render"])
    body = f"""```
python -m benchmarks scale{' --quick' if quick else ''}
```
Machine: {_doc.machine_line()}; isplat {_doc.git_rev()}. Shared with other work while measured: read ratios
and medians, not single numbers. Scene: examples/head.toml (bone, lit, early termination 0.99), the `head`
sample {'x'.join(map(str, shape)) if shape else '256x256x225'}, {size} x {size}. **Technique: {tech}**
(`render.classification = "{tech}"`, as the scene renders) in every row below.

### A batch of views: {n_views}-view orbit, warm
| run ({tech}) | wall time ({n_views} views, median of {repeats}) | per view |
|---|---|---|
| one process, 2 threads | {t_one:.2f} s | {ms(t_one / n_views)} |
| LocalCluster, 2 workers x 1 thread (`--scheduler local:2`) | {t_dask:.2f} s | {ms(t_dask / n_views)} |

Ratio cluster / one process: **{t_dask / t_one:.2f}**. Frames bit for bit equal to the one-process frames:
**{'yes' if same else 'NO'}**. Each worker holds the scene's selection ({sel_mib:.1f} MiB); each frame comes back to
the client as float32 RGBA ({mib(b_frame)}).

### The model of one frame split into K slabs (one thread per slab, as a worker)
Principal axis {view.axis_sign[0]}, {n_slices} slices. Per slab: `prepare` (the frame's tables: opacity, shading of
the 65,536 normal codes, footprint) is paid in full by every worker; the render is the slab's slices. Measured
in this process, one thread, slabs one after another (medians of {repeats}); these are the inputs of the
predictions for larger clusters below. The last column is the work lost to early termination: a slab rendered
apart does not know what the slabs in front cover, so it splats voxels one pass would skip.

| K ({tech}) | prepare (max) | slab render (max) | slab render (mean) | imbalance max/mean | work: sum of slabs / one pass |
|---|---|---|---|---|---|
{rows}

One 'over' of two partials: {ms(t_over)}; finishing a frame: {ms(t_finish)}. A partial image is {mib(b_part)}
pickled (premultiplied RGBA float32 + saturation bytes), a frame {mib(b_frame)}. Cluster here (loopback):
{ms(first)} for one task's round trip (submit, run, result back), {ms(per_hop)} for each further task of a chain
alternating between the workers, {bw / 1e6:.0f} MB/s moving 32 MiB (or a partial, if larger) to a worker
(`client.scatter`).

Frame time on K workers = round trip + (1 + L) hops + max slab (prepare + render) + L x (over + partial / rate)
+ finish + frame / rate, with L = ceil(log2 K) rounds of the pairwise tree (K - 1 'over' tasks in all; the
bytes moved per frame are (K - 1) partials between workers plus one frame to the client:
{mib(b_part)} x (K - 1) + {mib(b_frame)}).

Checked on this machine's cluster, with the terms measured just before each frame (the slabs of a frame
rendered at once, each on its worker; one 'over' on a worker; the round trip, hop and rate for one partial),
then the frame end to end;
medians of {repeats} interleaved frames:

| workers (slabs), {tech} | predicted | measured |
|---|---|---|
| 1 | {ms(pred[1])} | {ms(meas[1])} |
| 2 | {ms(pred[2])} | {ms(meas[2])} |

Predictions for a real cluster (assumed: 10 GbE, {BW_NET / 1e9:.2f} GB/s per link, {HOP_NET * 1000:.0f} ms per task hop
and twice that for the first round trip,
one core per worker, the same volume and image, the render work {ms(t1)} divided evenly up to the imbalance
measured at K = 8, at most one slab per slice ({n_slices} slices), `prepare` in full on every worker):

| workers, {tech} | predicted frame time | of which slab | composite rounds |
|---|---|---|---|
""" + "\n".join(
        f"| {k} | {ms(big[k])} | {ms(_slab_time(extrapolate(model[8], n_slices, k)))} "
        f"| {math.ceil(math.log2(min(k, n_slices)))} |" for k in (8, 64, 512)) + "\n"
    return _doc.update_section(Path(out_dir) / "scale.md", "scale", body, title="isplat at scale: Dask")
