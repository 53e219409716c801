"""isplat on Dask (isplat.distributed): batches of views and frames split into slabs on a LocalCluster of worker
processes bound to 127.0.0.1; a killed worker loses no frames; one line naming the extra without Dask."""

import os
import signal
import subprocess
import sys

import cloudpickle
import imageio.v3 as iio
import numpy as np
import pytest
from distributed import Client, WorkerPlugin

from conftest import scene_text, write_volume
from isplat import distributed as D
from isplat import frame as F
from isplat.augfile import open_augmented
from isplat.errors import IsplatError
from isplat.renderer import Renderer

cloudpickle.register_pickle_by_value(sys.modules[__name__])    # the workers cannot import this test module


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from isplat.normals import encode

    tmp = tmp_path_factory.mktemp("dask")
    r = np.random.default_rng(5)
    z, y, x = np.mgrid[:20, :18, :22]
    dens = np.where(((x - 10.5) ** 2 + (y - 8.5) ** 2 + (z - 9.5) ** 2) < 64, 200, 0).astype(np.uint8)
    dens[r.random(dens.shape) < 0.15] = 120                          # a semi-transparent haze
    dens[2:6, 2:6, 15:20] = 250                                      # off-centre: the views of an orbit differ
    write_volume(tmp, dens, spacing=(1.0, 1.1, 0.9), normal=encode(r.normal(size=dens.shape + (3,))))
    return tmp


def make(files, overrides=(), **extra):
    from isplat.scene import parse_scene

    sections = dict(image="width = 64\nheight = 64", camera="azimuth = 20\nelevation = 25",
                    transfer="opacity = [[100, 0], [120, 0.15], [200, 0.9], [255, 0.9]]\n"
                             "color = [[0, 1, 0.5, 0], [255, 0.2, 0.6, 1]]",
                    shading="enabled = true", views="orbit_steps = 12")
    sections.update(extra)
    return parse_scene(scene_text("v.aug.h5", "v.idx.h5", **sections), files, "scene.toml", list(overrides))


@pytest.fixture(scope="module")
def client():
    with D.local_cluster(2) as cluster, Client(cluster) as c:
        yield c


def views_of(scene):
    return F.views_for(scene, open_augmented(scene.data.augmented))


def one_process(scene):
    r = Renderer(scene)
    return [r.render_view(n)[0] for n in range(len(r.views))]


def test_a_batch_on_two_workers_is_the_one_process_batch_bit_for_bit(files, client):
    scene = make(files)
    want = one_process(scene)
    got = list(D.render_views(client, scene, views_of(scene)))
    assert [g[0] for g in got] == list(range(12))                       # in order
    assert len({w.tobytes() for w in want}) == 12                       # the views differ
    for (n, rgba, stats, report), w in zip(got, want):
        assert rgba.dtype == w.dtype and np.array_equal(rgba, w), n
    assert report.axes == Renderer(scene).report.axes


def test_each_worker_makes_the_selection_once(files, client):
    scene = make(files, ["image.width=16", "image.height=16"])
    client.run(D.clear_cache)
    list(D.render_views(client, scene, views_of(scene)))
    list(D.render_views(client, scene, views_of(scene)))
    cached = client.run(lambda: len(D._cache))
    assert sum(cached.values()) <= 2            # at most one per worker, for 24 views


def test_the_renderer_drives_the_workers(files, client):
    """Renderer(scene, scheduler=client): the views rendered on the workers are the one-process frames, in view
    order, and the request made here is the workers' cache key."""
    scene = make(files, ["image.width=24", "image.height=24", "views.orbit_steps=3"])
    r = Renderer(scene, scheduler=client)
    assert r.mode == "dask" and r.selection is None and r.held_bytes() is None
    got = list(r.render_views())
    assert [n for n, *_ in got] == [0, 1, 2]
    for (_, rgba, _, _), want in zip(got, one_process(scene)):
        assert np.array_equal(rgba, want)
    keys = client.run(lambda: [k for k, _ in D._cache.items()])
    assert any(r.request in v for v in keys.values())


@pytest.mark.parametrize("n_slabs", [2, 3, 4])
def test_a_frame_split_into_slabs_on_workers_is_the_one_process_frame(files, client, n_slabs):
    """Early termination off: equal to rounding (1e-5); on (0.9): the premultiplied image differs by at most
    1 - et, as docs/design.md bounds it, and is not identical (each slab stops on its own)."""
    for et, tol in ((1.0, 1e-5), (0.9, 0.1 + 1e-6)):
        scene = make(files, [f"render.early_termination={et}", "views.orbit_steps=0", "camera.azimuth=200"])
        view = views_of(scene)[0]
        sel = Renderer(scene).selection
        whole = F.render_slab(F.prepare(sel, view))
        fut = D.submit_slabs(client, D.request_for(scene, [view]), view, n_slabs, None, f"t{n_slabs}-{et}")
        part, report, _ = fut.result()
        assert np.abs(part.img - whole.img).max() <= tol
        assert report.voxels_of_interest == sel.report.voxels_of_interest      # the slabs' reports added up
        assert report.file_bytes > 0 and report.needed_voxels >= sel.report.needed_voxels
        assert part.band_stats[:, 2].sum() >= whole.band_stats[:, 2].sum()
        if et == 1.0:
            assert part.band_stats[:, 2].sum() == whole.band_stats[:, 2].sum()   # every voxel splatted once
            (_, rgba, _, _), = D.render_views(client, scene, [view], slabs=n_slabs)
            assert np.abs(rgba - F.finish_image(whole.img, view.background)).max() <= 1e-5


def test_a_slice_stride_on_workers_is_the_one_process_frame(files, client):
    """render.slice_stride = 2 (every other slice, by its index): a frame rendered whole on a worker, or in
    slabs on the workers, is the one-process frame (to rounding), which is not the every-slice frame."""
    scene = make(files, ["render.slice_stride=2", "render.early_termination=1.0", "views.orbit_steps=0",
                         "camera.azimuth=200"])
    want = one_process(scene)[0]
    view = views_of(scene)[0]
    for slabs in (1, 2, 3):
        (_, rgba, _, _), = D.render_views(client, scene, [view], slabs=slabs)
        assert np.abs(rgba - want).max() <= 1e-5, slabs
    every = one_process(make(files, ["render.early_termination=1.0", "views.orbit_steps=0", "camera.azimuth=200"]))
    assert np.abs(every[0] - want).max() > 1e-3


def test_supersampled_frames_on_workers_are_box_filtered_like_one_process(files, client):
    """render.supersample = 2: a view rendered whole or in slabs on the workers is finished at the image's size,
    as in one process."""
    scene = make(files, ["render.supersample=2", "render.early_termination=1.0", "views.orbit_steps=0",
                         "image.width=24", "image.height=20"])
    want = one_process(scene)[0]
    view = views_of(scene)[0]
    for slabs in (1, 2):
        (_, rgba, _, _), = D.render_views(client, scene, [view], slabs=slabs)
        assert rgba.shape == want.shape == (20, 24, 4)
        assert np.abs(rgba - want).max() <= 1e-5


def test_slab_workers_hold_only_their_slabs_voxels(files, client):
    scene = make(files, ["views.orbit_steps=0", "render.early_termination=1.0"])
    view = views_of(scene)[0]
    client.run(D.clear_cache)
    list(D.render_views(client, scene, [view], slabs=2))
    held = client.run(lambda: [("slab" if k.slab else "sel", v[0].axes[k.axes].n_voxels)
                               for k, v in D._cache.items() + D._slab_cache.items()])
    assert sum(len(v) for v in held.values()) == 2 and all(k == "slab" for v in held.values() for k, _ in v)
    axis = view.axis_sign[0]
    total = Renderer(scene).selection.axes[axis].n_voxels
    assert sum(n for v in held.values() for kind, n in v) == total and all(n < total for v in held.values()
                                                                           for _, n in v)


def test_the_tree_joins_in_order_in_log_rounds():
    calls = []

    def join(a, b, level, i):
        calls.append(level)
        return f"({a}{b})"
    assert D.reduce_pairwise(list("abcde"), join) == "(((ab)(cd))e)"
    assert max(calls) == 2 and len(calls) == 4                               # ceil(log2 5) rounds, n - 1 joins


class KillOnce(WorkerPlugin):
    """Kills its worker process (SIGKILL, no goodbye) when the task of view 6 starts, once across restarts."""

    def __init__(self, marker):
        self.marker = marker

    def transition(self, key, start, finish, **kwargs):
        if finish == "executing" and str(key).startswith("isplat-view-") and str(key).endswith("-6"):
            try:
                os.remove(self.marker)
            except FileNotFoundError:
                return
            os.kill(os.getpid(), signal.SIGKILL)


def test_a_killed_worker_loses_no_frames(files, tmp_path):
    scene = make(files)
    want = one_process(scene)
    marker = tmp_path / "kill-once"
    marker.write_text("")
    with D.local_cluster(2) as cluster, Client(cluster) as c:
        c.register_plugin(KillOnce(str(marker)))
        pids = set(c.run(os.getpid).values())
        got = list(D.render_views(c, scene, views_of(scene)))
        c.wait_for_workers(2, timeout=60)
        after = set(c.run(os.getpid).values())
    assert not marker.exists() and pids - after                               # a worker was killed, and replaced
    assert [g[0] for g in got] == list(range(12))
    assert all(np.array_equal(rgba, w) for (_, rgba, _, _), w in zip(got, want))


def test_files_changed_under_the_workers_are_refused(files, tmp_path):
    import shutil

    for name in ("v.aug.h5", "v.idx.h5"):
        shutil.copy(files / name, tmp_path / name)
    scene = make(tmp_path)
    request = D.request_for(scene, views_of(scene)[:1])
    os.utime(tmp_path / "v.aug.h5", ns=(1, 1))
    D.clear_cache()
    with pytest.raises(IsplatError, match="worker's files differ"):
        D.worker_selection(request)


def cli(*args, cwd, hide_dask=False):
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    env["ISPLAT_PROGRESS"] = "0"
    pre = "import sys; sys.modules['distributed'] = None; " if hide_dask else ""
    code = pre + "from isplat.cli.main import main; main()"
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, cwd=cwd, env=env)


def test_cli_scheduler_writes_the_frames_of_one_process(files, client):
    from isplat.output import write_still
    from isplat.scene import load_scene

    (files / "orbit.toml").write_text(scene_text("v.aug.h5", "v.idx.h5", image="width = 32\nheight = 32",
                                                 transfer="opacity = [[100, 0], [200, 0.9]]",
                                                 views="orbit_steps = 4"))
    for n, rgba in enumerate(one_process(load_scene(files / "orbit.toml"))):
        write_still(str(files / f"one_{n:03d}.png"), rgba, 8, True)
    res = cli("render", "orbit.toml", "-o", "dask.png", "--scheduler", client.scheduler.address, "--json", cwd=files)
    assert res.returncode == 0, res.stderr
    for n in range(4):
        assert np.array_equal(iio.imread(files / f"one_{n:03d}.png"), iio.imread(files / f"dask_{n:03d}.png"))
    import json
    assert [v["view"] for v in json.loads(res.stdout)["views"]] == [0, 1, 2, 3]
    res = cli("render", "orbit.toml", "-o", "split.gif", "--scheduler", client.scheduler.address, "--slabs", "3",
              cwd=files)
    assert res.returncode == 0, res.stderr
    assert iio.imread(files / "split.gif", index=None).shape[0] == 4


@pytest.mark.parametrize("args,needle", [
    (("--scheduler", "local:2"), "pip install 'isplat[dask]'"),
])
def test_without_dask_the_scheduler_option_is_one_line_naming_the_extra(files, args, needle):
    res = cli("render", "orbit.toml", "-o", "x.png", *args, cwd=files, hide_dask=True)
    err = res.stderr.decode().strip().splitlines()
    assert res.returncode == 2 and len(err) == 1 and needle in err[0], res.stderr
    assert not list(files.glob("x*.png"))


@pytest.mark.parametrize("args,needle", [
    (("--scheduler", "local:zero"), "expected local:N"),
    (("--scheduler", "udp://x"), "expected local:N or tcp://HOST:PORT"),
    (("--slabs", "0"), "--slabs"),
])
def test_bad_scheduler_options_are_one_line(files, args, needle):
    (files / "one.toml").write_text(scene_text("v.aug.h5", "v.idx.h5", transfer="opacity = [[100, 0], [200, 0.9]]"))
    res = cli("render", "one.toml", "-o", "y.png", *args, cwd=files)
    err = res.stderr.decode().strip().splitlines()
    assert res.returncode == 2 and len(err) == 1 and needle in err[0], res.stderr


class _Cluster:
    """A client whose cluster has no workers at first and ``joined`` after waiting (None: none join)."""

    def __init__(self, joined):
        self.joined, self.waited = joined, False
        self.scheduler = type("S", (), {"address": "tcp://127.0.0.1:1"})()

    def scheduler_info(self, n_workers=-1):
        return {"workers": dict.fromkeys(self.joined or []) if self.waited else {}}

    def wait_for_workers(self, n, timeout=None):
        from distributed.client import WorkerStartTimeoutError

        self.waited = True
        if not self.joined:
            raise WorkerStartTimeoutError(0, n, timeout)


def test_a_cluster_without_workers_is_waited_for_then_refused_in_one_line():
    """No workers at the moment of asking (all restarting): the ones that join are used; none joining is one
    IsplatError naming the scheduler, not a division by zero when slabs are spread over ``s mod W`` workers."""
    assert D._workers(_Cluster(["tcp://b", "tcp://a"]), timeout=1) == ["tcp://a", "tcp://b"]
    with pytest.raises(IsplatError, match=r"tcp://127.0.0.1:1 has no workers \(none joined in 1 s\)"):
        D._workers(_Cluster(None), timeout=1)
