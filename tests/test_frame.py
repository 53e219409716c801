"""The render core's stages: selections from files and from arrays, slabs, partial images and compositing."""

import os
import subprocess
import sys
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from conftest import scene_text, write_volume
from isplat import frame as F
from isplat.errors import IsplatError
from isplat.selection import Selection, select_from_files

SLOW = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def rng_volume(seed, shape, levels=(0, 60, 120, 200)):
    r = np.random.default_rng(seed)
    return r.choice(np.array(levels, np.uint8), size=shape, p=[0.4, 0.2, 0.2, 0.2])


def channels(seed, shape):
    from isplat.normals import encode

    r = np.random.default_rng(seed)
    return r.integers(0, 256, shape).astype(np.uint8), encode(r.normal(size=shape + (3,)))


@pytest.fixture(scope="module")
def volume(tmp_path_factory):
    """A random volume with normals and gradient magnitudes, as files and as arrays."""
    shape = (10, 9, 11)
    dens = rng_volume(1, shape)
    gm, nrm = channels(1, shape)
    aug, idx = write_volume(tmp_path_factory.mktemp("frame"), dens, spacing=(1.0, 1.3, 0.8), gm=gm, normal=nrm,
                            gscale=0.5)
    return dens, gm, nrm, aug, idx


def scene(make_scene, volume, extra="", method="indexed", proj="orthographic", cam="azimuth = 30\nelevation = 20",
          threads=1):
    *_, aug, idx = volume
    return make_scene(aug, idx, image="width = 36\nheight = 30",
                      camera=f'projection = "{proj}"\n{cam}',
                      transfer="opacity = [[50, 0.0], [60, 0.5], [130, 0.3], [200, 0.95]]\n"
                               "color = [[0, 1, 0, 0], [255, 0, 0.5, 1]]\ngradient_opacity = [[0, 0.3], [100, 1]]",
                      shading="enabled = true",
                      render=f'method = "{method}"\nthreads = {threads}\n{extra}')


def from_files(sc):
    aug_views = F.views_for(sc, _aug(sc))
    return select_from_files(sc, F.axes_of(aug_views)), aug_views


def _aug(sc):
    from isplat.augfile import open_augmented
    return open_augmented(sc.data.augmented)


def one_pass(sel, view, et=None):
    setup = F.prepare(sel, view, et)
    return F.render_slab(setup), setup


# ---------------------------------------------------------------------------------------------------------
# selections: arrays in memory against files

@pytest.mark.parametrize("method", ["indexed", "full"])
@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
def test_arrays_in_memory_render_as_the_files_do(make_scene, volume, method, proj):
    dens, gm, nrm, *_ = volume
    cams = ["azimuth = 30\nelevation = 20", "azimuth = 100\nelevation = -10", "azimuth = 0\nelevation = 80"]
    for cam in cams:
        sc = scene(make_scene, volume, method=method, proj=proj, cam=cam)
        sel_f, views = from_files(sc)
        sel_a = Selection.from_arrays(dens, sc, normal=nrm, gradient_magnitude=gm, gradient_magnitude_scale=0.5,
                                      spacing=(1.0, 1.3, 0.8), axes=F.axes_of(views))
        img_f, st_f = F.render_frame(sel_f, views[0])
        img_a, st_a = F.render_frame(sel_a, views[0])
        assert np.array_equal(img_f, img_a)
        assert (st_f.voxels_examined, st_f.drawn) == (st_a.voxels_examined, st_a.drawn)
        assert img_f[..., 3].max() > 0.1


def test_selection_from_arrays_holds_the_same_arrays_as_from_files(make_scene, volume):
    dens, gm, nrm, *_ = volume
    sc = scene(make_scene, volume, cam="azimuth = 0\nelevation = 0")
    sel_f, views = from_files(sc)
    sel_a = Selection.from_arrays(dens, sc, normal=nrm, gradient_magnitude=gm, gradient_magnitude_scale=0.5,
                                  axes=F.axes_of(views))
    assert sel_f.axes.keys() == sel_a.axes.keys()
    for ax in sel_f.axes:
        for x, y in zip(sel_f.axes[ax].arrays(), sel_a.axes[ax].arrays()):
            assert x.dtype == y.dtype and np.array_equal(x, y)
    assert sel_f.held_bytes() == sel_a.held_bytes()


@given(seed=st.integers(0, 2**16), shape=st.tuples(*[st.integers(1, 7)] * 3),
       intervals=st.lists(st.tuples(st.integers(0, 255), st.integers(0, 40)), min_size=1, max_size=3))
@settings(max_examples=40, deadline=None)
def test_index_in_memory_equals_the_decoded_file(tmp_path_factory, seed, shape, intervals):
    from isplat.index import build_index, normalize_ranges, open_index, write_index
    from isplat.index.memory import load_axis_in_memory

    dens = np.random.default_rng(seed).integers(0, 256, shape).astype(np.uint8)
    ivs = normalize_ranges([(lo, min(255, lo + w)) for lo, w in intervals])
    path = tmp_path_factory.mktemp("idx") / "v.idx.h5"
    write_index(path, build_index(dens), dens.shape, "0" * 64)
    idx = open_index(path)
    for ax in "ijk":
        a, b = idx.load_axis(ax, ivs), load_axis_in_memory(dens, ax, ivs)
        for name in ("slice_block_ptr", "block_density", "block_voxel_ptr", "positions"):
            x, y = getattr(a, name), getattr(b, name)
            assert x.dtype == y.dtype and np.array_equal(x, y), (ax, name)
        assert (a.n_slices, a.n_a, a.n_b) == (b.n_slices, b.n_a, b.n_b)


def test_from_arrays_augments_a_float_volume(make_scene, volume):
    from isplat.augment import augment_array

    *_, aug, idx = volume
    x = np.random.default_rng(5).normal(size=(6, 7, 8)) * 100
    sc = make_scene(aug, idx, transfer="opacity = [[100, 0], [200, 0.8]]", shading="enabled = true")
    sel = Selection.from_arrays(x, sc, axes="k")
    ref = augment_array(x, (1.0, 1.0, 1.0))
    codes = Selection.from_arrays(ref["density"], sc, normal=ref["normal"], axes="k")
    for p, q in zip(sel.axes["k"].arrays(), codes.axes["k"].arrays()):
        assert np.array_equal(p, q)


def test_from_arrays_without_a_data_table(volume):
    from isplat.scene import parse_scene

    dens, *_ = volume
    sc = parse_scene("[image]\nwidth = 16\nheight = 16\n[transfer]\nopacity = [[100, 0], [200, 1]]\n"
                     "[shading]\nenabled = false", ".", "notebook", data_required=False)
    sel = Selection.from_arrays(dens, sc)
    img, stats = F.render_frame(sel, F.views_for(sc, sel)[0])
    assert img.shape == (16, 16, 4) and stats.drawn > 0


@pytest.mark.parametrize("kwargs, message", [
    (dict(normal=np.zeros((2, 2, 2), np.uint16), gradient_magnitude=np.zeros((10, 9, 11), np.uint8)),
     "normal has shape"),
    (dict(normal=np.zeros((10, 9, 11), np.float32), gradient_magnitude=np.zeros((10, 9, 11), np.uint8)),
     "normal has shape"),
    (dict(normal=np.zeros((10, 9, 11), np.uint16)), "needs gradient_magnitude codes too"),
    (dict(gradient_magnitude=np.zeros((10, 9, 11), np.uint8)), "needs normal codes too"),
    (dict(spacing=(1.0, 0.0, 1.0)), "spacing"),
    (dict(gradient_magnitude_scale=float("nan"), normal=np.zeros((10, 9, 11), np.uint16),
          gradient_magnitude=np.zeros((10, 9, 11), np.uint8)), "gradient_magnitude_scale"),
])
def test_from_arrays_refuses_what_does_not_fit(make_scene, volume, kwargs, message):
    dens, *_ = volume
    sc = scene(make_scene, volume)
    with pytest.raises(IsplatError, match=message):
        Selection.from_arrays(dens, sc, **kwargs)


def test_from_arrays_refuses_a_flat_array(make_scene, volume):
    with pytest.raises(IsplatError, match="3-D"):
        Selection.from_arrays(np.zeros((4, 4), np.uint8), scene(make_scene, volume))


def test_a_view_of_an_axis_not_selected_is_refused(make_scene, volume):
    dens, gm, nrm, *_ = volume
    sc = scene(make_scene, volume, cam="azimuth = 0\nelevation = 0")
    sel = Selection.from_arrays(dens, sc, normal=nrm, gradient_magnitude=gm, axes="k")
    with pytest.raises(IsplatError, match="was not selected"):
        F.render_frame(sel, F.views_for(sc, sel)[0])


# ---------------------------------------------------------------------------------------------------------
# slabs and partial images

def slab_cuts(n):
    """Random cuts of n slices into contiguous slabs: sorted distinct inner edges."""
    return st.lists(st.integers(1, max(1, n - 1)), max_size=6, unique=True).map(lambda e: [0, *sorted(e), n])


@given(data=st.data())
@SLOW
def test_slabs_that_continue_one_another_are_the_one_pass_frame(make_scene, volume, data):
    """Front to back, each slab continuing the partial image of those in front: the same image and the same
    counters as one pass, early termination included (it is what the progress bar and streaming do)."""
    method = data.draw(st.sampled_from(["indexed", "full"]))
    proj = data.draw(st.sampled_from(["orthographic", "perspective"]))
    threads = data.draw(st.sampled_from([1, 2]))
    et = data.draw(st.sampled_from([1.0, 0.9, 0.6]))
    sc = scene(make_scene, volume, method=method, proj=proj, threads=threads, extra=f"early_termination = {et}")
    sel, views = from_files(sc)
    whole, setup = one_pass(sel, views[0])
    edges = data.draw(slab_cuts(len(views[0].order)))
    part = F.blank(setup)
    for a, b in zip(edges[:-1], edges[1:]):
        F.render_slab(setup, a, b, part)
    assert np.array_equal(part.img, whole.img) and np.array_equal(part.sat, whole.sat)
    assert np.array_equal(part.band_stats, whole.band_stats)


@given(data=st.data())
@SLOW
def test_threads_finishing_their_own_rows_give_finish_image(make_scene, volume, data):
    """render_slab(finished=out): each thread finishes its bands' rows when its slices are done; ``out`` is
    finish_image of the partial bit for bit, for any thread count and after slabs in front; a non-finite
    pixel is refused as finish_image refuses it."""
    classification = data.draw(st.sampled_from(["post", "pre"]))
    threads = data.draw(st.sampled_from([1, 2, 3]))
    proj = data.draw(st.sampled_from(["orthographic", "perspective"]))
    sc = scene(make_scene, volume, proj=proj, threads=threads, extra=f'classification = "{classification}"')
    sel, views = from_files(sc)
    setup = F.prepare(sel, views[0])
    cut = data.draw(st.integers(0, len(views[0].order) - 1))
    part = F.render_slab(setup, 0, cut)
    out = np.full_like(part.img, np.nan)
    F.render_slab(setup, cut, None, part, out)
    assert np.array_equal(out, F.finish_image(part.img, views[0].background))
    img, _ = F.render_frame(sel, views[0])
    assert np.array_equal(img, out)
    none = np.full_like(part.img, np.nan)                   # nothing left to render: the partial as it is
    F.render_slab(setup, len(views[0].order), None, part, none)
    assert np.array_equal(none, out)
    part = F.blank(setup)
    part.img[data.draw(st.integers(0, part.img.shape[0] - 1)), 0, 3] = np.nan
    with pytest.raises(IsplatError, match="non-finite"):
        F.render_slab(setup, 0, None, part, np.empty_like(part.img))


@given(data=st.data())
@SLOW
def test_slabs_rendered_apart_and_composited_in_order_are_the_one_pass_frame(make_scene, volume, data):
    """Early termination off, float64: 'over' is associative, so slabs rendered apart (as threads or Dask
    workers would) and composited in visibility order give the one-pass frame to rounding."""
    method = data.draw(st.sampled_from(["indexed", "full"]))
    proj = data.draw(st.sampled_from(["orthographic", "perspective"]))
    sc = scene(make_scene, volume, method=method, proj=proj,
               extra='early_termination = 1.0\nprecision = "float64"')
    sel, views = from_files(sc)
    whole, setup = one_pass(sel, views[0])
    edges = data.draw(slab_cuts(len(views[0].order)))
    parts = [F.render_slab(setup, a, b) for a, b in zip(edges[:-1], edges[1:])]
    pairwise = data.draw(st.booleans())          # left to right, or a tree of pairs: both are 'over' in order
    while len(parts) > 1:
        if pairwise:
            parts = [F.composite(*parts[i:i + 2]) if i + 1 < len(parts) else parts[i] for i in range(0, len(parts), 2)]
        else:
            parts = [F.composite(parts[0], parts[1])] + parts[2:]
    assert np.abs(parts[0].img - whole.img).max() <= 1e-6
    assert parts[0].band_stats[:, 1].sum() == whole.band_stats[:, 1].sum()      # every voxel splatted once
    out = F.finish_image(parts[0].img, views[0].background)
    assert np.abs(out - F.finish_image(whole.img, views[0].background)).max() <= 1e-6


@given(data=st.data())
@SLOW
def test_slabs_composited_with_early_termination_differ_by_at_most_one_minus_the_threshold(make_scene, volume,
                                                                                          data):
    """With early termination each slab stops on its own and takes what one pass would have left out; all
    of it lies behind pixels whose opacity reached ``et``, so the difference is at most 1 - et."""
    et = data.draw(st.sampled_from([0.6, 0.9, 0.99]))
    sc = scene(make_scene, volume, method=data.draw(st.sampled_from(["indexed", "full"])),
               extra=f'early_termination = {et}\nprecision = "float64"')
    sel, views = from_files(sc)
    whole, setup = one_pass(sel, views[0])
    edges = data.draw(slab_cuts(len(views[0].order)))
    parts = [F.render_slab(setup, a, b) for a, b in zip(edges[:-1], edges[1:])]
    acc = parts[0]
    for p in parts[1:]:
        acc = F.composite(acc, p, et)
    assert np.abs(acc.img - whole.img).max() <= 1.0 - et + 1e-9
    # the composite's saturation state is its own: saturated where its opacity reached et
    assert np.array_equal(acc.sat == 1, acc.img[..., 3] >= et)


@given(front=st.lists(st.floats(0, 1), min_size=8, max_size=8), back=st.lists(st.floats(0, 1), min_size=8,
                                                                              max_size=8))
def test_over_is_the_premultiplied_formula(front, back):
    def premult(v):
        px = np.array(v, np.float64).reshape(2, 1, 4)
        px[..., :3] *= px[..., 3:]
        return px
    f, b = premult(front), premult(back)
    out = np.empty_like(f)
    from isplat.splat.composite import over
    over(f, b, out)
    assert np.allclose(out, f + (1 - f[..., 3:]) * b, atol=1e-15)


def test_progress_bar_slabs_draw_and_count_as_one_pass(make_scene, volume, monkeypatch):
    """Figures must not depend on the terminal: with a progress bar the slices go in slabs (issue #9 measured
    1,152 against 12,096 voxels examined before slabs continued one another)."""
    from isplat import progress

    long_vol = np.repeat(volume[0], 6, axis=0)                  # 60 k-slices: enough to be cut into slabs
    sc = make_scene(volume[3], volume[4], image="width = 24\nheight = 24",
                    camera="azimuth = 0\nelevation = 90\nzoom = 8",
                    transfer="opacity = [[50, 0.0], [60, 0.9], [200, 0.95]]", shading="enabled = false",
                    render="early_termination = 0.6\nthreads = 2")
    sel = Selection.from_arrays(long_vol, sc, axes="k")
    view = F.views_for(sc, sel)[0]
    assert view.axis_sign[0] == "k" and len(view.order) >= 40
    figures = []
    for terminal in (True, False):
        monkeypatch.setattr(progress, "enabled", lambda: terminal)
        monkeypatch.setattr(progress, "bar", lambda it, **kw: it)
        img, s = F.render_frame(sel, view)
        figures.append((img, s.voxels_examined, s.drawn, s.slices))
    assert np.array_equal(figures[0][0], figures[1][0])
    assert figures[0][1:] == figures[1][1:]
    assert figures[0][3] < len(view.order)        # early termination stopped the frame early


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(threads=st.integers(1, 4), az=st.floats(-180, 180), el=st.floats(-60, 60), zoom=st.floats(0.5, 3.0),
       cuts=st.sets(st.integers(1, 11), max_size=5))
def test_bin_regions_lists_the_regions_whose_box_meets_each_band(make_scene, tmp_path, threads, az, el, zoom, cuts):
    """bin_regions (orthographic) against the obvious: per band and slice, in order, the regions of the slice
    whose pixel box (the projected corners' hull grown by the reach, rounded outwards) meets the band's rows
    and the image's columns, for the frame's bands and for bands cut at any tile rows; bands that do not tile
    the image from row 0 in whole tiles are refused."""
    from isplat.splat import traverse as K

    dens = rng_volume(3, (6, 150, 140))
    aug, idx = tmp_path / "bins.aug.h5", tmp_path / "bins.idx.h5"
    if not aug.exists():                                    # (one tmp_path for all the examples)
        write_volume(tmp_path, dens, name="bins")
    sc = make_scene(aug, idx, image="width = 70\nheight = 90", transfer="opacity = [[50, 0.0], [60, 0.8]]",
                    camera=f"azimuth = {az}\nelevation = {el}\nzoom = {zoom}",
                    render=f"threads = {threads}\nclassification = \"pre\"", shading="enabled = false")
    sel = select_from_files(sc, "ijk")
    view = F.views_for(sc, sel)[0]
    setup = F.prepare(sel, view)
    vox, bins0 = setup.plan.source
    coef, (ex, ey) = setup.plan.geo.coef, setup.plan.reach
    edges = [0, *sorted(8 * c for c in cuts), 90]
    uneven = np.stack([edges[:-1], edges[1:]], axis=1).astype(np.int64)
    listed = 0
    for rows, bins in ((setup.rows, bins0),
                       (uneven, K.Bins(*K.bin_regions(view.order, vox, setup.plan.geo, ex, ey, uneven, 70)))):
        listed += _check_bins(view, vox, coef, ex, ey, rows, bins)
    assert listed > 0
    for bad in ([[1, 90]], [[0, 12], [12, 90]], [[0, 16], [24, 90]], [[0, 16], [16, 16], [16, 90]]):
        with pytest.raises(ValueError, match="bands must tile"):
            K.bin_regions(view.order, vox, setup.plan.geo, ex, ey, np.array(bad, np.int64), 70)


def _check_bins(view, vox, coef, ex, ey, rows, bins):
    """Asserts bins (of the bands ``rows``) are the obvious regions; returns how many are listed."""
    from isplat.splat import traverse as K

    nra = -(-vox.n_a // K.REGION)
    listed = 0
    for oi, c in enumerate(view.order):
        xs, ys = coef[K.X0] + c * coef[K.XC], coef[K.Y0] + c * coef[K.YC]
        g = np.arange(vox.slice_ptr[c], vox.slice_ptr[c + 1])
        a0, b0 = (vox.region_id[g] % nra) * K.REGION, (vox.region_id[g] // nra) * K.REGION
        a1, b1 = np.minimum(a0 + K.REGION, vox.n_a) - 1, np.minimum(b0 + K.REGION, vox.n_b) - 1
        px = np.stack([xs + a * coef[K.XA] + b * coef[K.XB] for a in (a0, a1) for b in (b0, b1)])
        py = np.stack([ys + a * coef[K.YA] + b * coef[K.YB] for a in (a0, a1) for b in (b0, b1)])
        x0, x1 = np.ceil(px.min(0) - ex), np.floor(px.max(0) + ex)
        y0, y1 = np.ceil(py.min(0) - ey), np.floor(py.max(0) + ey)
        for bi, (r0, r1) in enumerate(rows):
            meets = (x1 >= 0) & (x0 <= 69) & (y1 >= max(r0, 0)) & (y0 <= r1 - 1) & (y1 >= 0) & (y0 <= 89)
            got = bins.regions[bins.ptr[bi, oi]:bins.ptr[bi, oi + 1]]
            assert np.array_equal(got, g[meets]), (oi, bi)
            listed += got.size
    return listed


@pytest.mark.parametrize("threads", [1, 2, 3, 4, 5, 8])
@pytest.mark.parametrize("per_thread", [1, 2, 3])
def test_band_layout_puts_the_large_bands_in_the_middle_and_first(threads, per_thread):
    """band_layout: the learned bands' ends rise to the whole work and their order takes every band once; with
    two bands per thread the ``threads`` large bands (twice the small ones) are the middle of the image and taken
    first, the small ones its top and bottom, so that at equal speed every thread takes one large and one small
    band (an equal share), and with one of two threads at half speed both end at 2/3 of the one-speed time
    (threads taking the next band when free). Otherwise equal shares in the image's order."""
    n = per_thread * threads
    ends, order = F.band_layout(n, threads)
    shares = np.diff(np.r_[0.0, ends])
    assert np.isclose(ends[-1], 1.0) and (shares > 0).all() and sorted(order.tolist()) == list(range(n))
    if threads < 2 or per_thread != 2:
        assert np.allclose(shares, 1.0 / n) and order.tolist() == list(range(n))
        return
    large = np.sort(order[:threads])
    assert np.allclose(shares[large], 2 * shares[order[threads:]].max())
    assert (np.diff(large) == 1).all() and large[0] == threads // 2       # contiguous, half the small ones above
    per = np.bincount(np.arange(n) % threads, shares[order])
    assert np.allclose(per, 1.0 / threads)
    if threads == 2:                    # list scheduling: thread 1 at half speed
        free, done = [0.0, 0.0], 0.0
        for b in order:
            t = int(np.argmin(free))
            free[t] += shares[b] * (1 if t == 0 else 2)
            done = max(done, free[t])
        assert np.isclose(done, 2 / 3)


@settings(max_examples=200, deadline=None)
@given(est=st.lists(st.floats(0, 1e3), min_size=2, max_size=14), threads=st.integers(2, 3), short=st.integers(0, 7))
def test_balanced_bands_tile_the_image_and_come_within_a_tile_row_of_the_best_cut(est, threads, short):
    """balanced_bands: bands of whole tiles (the last ending at the image's last row), each at least one tile,
    and the busiest thread (the threads taking the bands in band_layout's order, each by the thread free first)
    within the costliest tile row of the best cut, found by trying every cut."""
    import itertools
    from isplat.splat.composite import TILE

    est = np.array(est)
    n, h = len(est), len(est) * TILE - short
    nb = min(4, n)
    rows = F.balanced_bands(est, nb, threads, h)
    assert rows.shape == (nb, 2) and rows.dtype == np.int64 and rows[0, 0] == 0 and rows[-1, 1] == h
    assert (rows[1:, 0] == rows[:-1, 1]).all() and (rows[:, 0] % TILE == 0).all() and (rows[:, 1] > rows[:, 0]).all()
    cum = np.concatenate([[0.0], np.cumsum(est)])

    order = F.band_layout(nb, threads)[1]

    def busiest(edges):
        edges = np.asarray(edges)
        return max(_threads_take(cum[edges[1:]] - cum[edges[:-1]], order, threads))

    best = min(busiest((0, *c, n)) for c in itertools.combinations(range(1, n), nb - 1))
    assert busiest(np.r_[rows[:, 0] // TILE, n]) <= best + est.max() + 1e-9 * cum[-1]


def _threads_take(cost, queue, threads):
    """Each thread's work when ``threads`` threads of equal speed take the bands (of cost ``cost``) in the order
    ``queue``, each band by the thread that comes free first (the first on a tie), as render_slab's threads do:
    an event loop over the time at which each thread comes free."""
    free_at = {t: 0.0 for t in range(threads)}
    work = [0.0] * threads
    for b in queue:
        t = min(free_at, key=lambda u: (free_at[u], u))
        free_at[t] += cost[b]
        work[t] += cost[b]
    return work


@pytest.mark.parametrize("threads", [2, 3])
def test_thread_sums_follow_threads_that_take_the_next_band_when_free(threads):
    """_thread_sums: each thread's work when the threads take the bands in the queue's order, each by the thread
    free first, against the event loop of _threads_take on random costs and orders (not thread t taking the
    bands t, t + threads, ...: the thread whose large band ends first takes the next band)."""
    rng = np.random.default_rng(threads)
    for _ in range(200):
        n = int(rng.integers(1, 9))
        cost, queue = rng.random(n), rng.permutation(n)
        assert np.allclose(F._thread_sums(cost, threads, queue), _threads_take(cost, queue, threads))
    assert F._thread_sums(np.array([1.0, 5.0, 4.0, 3.0]), 2, np.array([1, 2, 0, 3])).tolist() == [8.0, 5.0]


def _frames_on(true_cost, threads, height, frames, slowed=None, rows_seen=None):
    """``frames`` frames whose bands cost ``true_cost`` per tile row, each learning from the last (band_rows,
    learn_bands); per frame the busiest thread's cost over the mean, and what was learned. ``slowed``: {frame:
    factor} for frames whose first band took that much longer (other work on the machine); ``rows_seen``: a list
    that gets each frame's bands."""
    from types import SimpleNamespace

    learning = F.BandLearning()
    view = SimpleNamespace(frame=SimpleNamespace(height=height, width=64), axis_sign=("k", 1),
                           render=SimpleNamespace(classification="post", sheets="slices", mode="composite"))
    cum = np.concatenate([[0.0], np.cumsum(true_cost)])
    key = F._balance_key(view, threads)
    out = []
    for _ in range(frames):
        rows = F.band_rows(learning, view, threads)
        queue = F.band_queue(learning, view, threads, len(rows))
        spent = cum[-(-rows[:, 1] // 8)] - cum[rows[:, 0] // 8]
        per = np.array(_threads_take(spent, queue, threads))
        if rows_seen is not None:
            rows_seen.append(rows[:, 0].tolist())
        if slowed and len(out) in slowed:
            spent = spent * np.r_[slowed[len(out)], np.ones(len(spent) - 1)]
        first = key not in learning.costs
        before = None if first else learning.costs[key].est
        F.learn_bands(learning.costs, SimpleNamespace(rows=rows, band_seconds=spent, view=view, threads=threads,
                                                      empty=False, queue=queue))
        est = learning.costs[key].est
        assert (est is None) == first              # the first frame (cold caches) only marks the kind seen
        kept = est is before                            # a balanced frame changes nothing (BALANCE_SLACK)
        bands = [] if first or kept else zip(rows[:, 0] // 8, -(-rows[:, 1] // 8), spent)
        for y0, y1, s in bands:                         # the band's time over its rows
            known = s if before is None else 0.5 * (s + before[y0:y1].sum())   # (averaged with what was known),
            assert np.isclose(est[y0:y1].sum(), known) and (est[y0:y1] > 0).all()  # none of them left idle
        out.append(per.max() / per.mean())
    return out


@pytest.mark.parametrize("threads", [2, 3, 4])
@pytest.mark.parametrize("profile", ["bump", "step", "two bumps"])
def test_bands_learned_from_the_frames_times_balance_the_threads(threads, profile):
    """A frame's bands are cut by the work per tile row the frames before found: on a fixed cost profile (the
    head's rows of bone, material in the upper rows only, two separate objects) even bands leave a thread
    with a larger share; after a few frames the busiest thread is within one tile row's work of the mean (or
    BALANCE_SLACK), and the bands stay where they are but for a cut tried now and then."""
    x = np.arange(64.0)
    true = {"bump": np.exp(-((x - 20) / 5) ** 2) + 0.01, "step": (x < 24) + 0.01,
            "two bumps": np.exp(-((x - 10) / 3) ** 2) + np.exp(-((x - 50) / 3) ** 2) + 0.001}[profile]
    ratios = _frames_on(true, threads, 512, 16)
    bound = 1.0 + true.max() * threads / true.sum()         # one tile row's work above the mean
    # the first frame: even bands (two bumps on 2 threads: the bumps' bands taken first, one by each thread)
    assert ratios[0] > 1.1 or (profile, threads) == ("two bumps", 2)
    last = ratios[-6:]
    assert np.median(last) <= max(1.0 + F.BALANCE_SLACK, bound) and max(last) <= ratios[0]
    assert sum(abs(a - b) > 1e-3 for a, b in zip(last, last[1:])) <= 2     # settled (a cut tried at most once)


@pytest.mark.parametrize("threads", [2, 4])
@pytest.mark.parametrize("when", [[5], [5, 8], [4, 7, 10, 13]])
def test_a_frame_slowed_by_other_work_moves_no_band(threads, when):
    """Bands that balance the threads stay where they are when a frame, or frames 3 apart, are slowed by other
    work on the machine (one band 40% longer): the bands move only when the median of the last RECENT frames (of
    at least two) is out of balance, not on one frame's time. Two frames in a row out of balance do move them, so
    that learning follows a real change of the work."""
    x = np.arange(64.0)
    seen = []
    _frames_on(np.ones_like(x), threads, 512, 16, {f: 1.4 for f in when}, seen)
    assert all(r == seen[0] for r in seen)
    moved = []
    _frames_on(np.ones_like(x), threads, 512, 16, {5: 1.4, 6: 1.4}, moved)
    assert any(r != moved[0] for r in moved)


def _skewed_bands() -> "F.Learned":
    """What 2 threads would learn of a 62-row image (8 tile rows) whose work is nearly all in its 7th tile row:
    4 bands cut there (not the even bands), the large middle ones first."""
    skewed = np.array([0.01, 0.01, 0.01, 0.01, 0.01, 0.01, 5.0, 0.01])
    return F.Learned(skewed, F.balanced_bands(skewed, 4, 2, 62), {}, F.band_layout(4, 2)[1])


@pytest.mark.parametrize("classification", ["pre", "post"])
@pytest.mark.parametrize("method", ["indexed", "full"])
def test_frames_on_learned_or_any_bands_give_the_one_thread_image(make_scene, volume, monkeypatch, classification,
                                                                   method):
    """Frames on 2 threads, each cutting its bands by what the frames before it took, and a frame on bands cut
    by a skewed cost, all give the one-thread image bit for bit."""
    monkeypatch.setattr(F, "MIN_BAND_TILES", 1)
    *_, aug, idx = volume

    def sc(threads):
        return make_scene(aug, idx, image="width = 40\nheight = 62", camera="azimuth = 30\nelevation = 20",
                          transfer="opacity = [[50, 0.0], [60, 0.5], [130, 0.3], [200, 0.95]]",
                          shading="enabled = true",
                          render=f'method = "{method}"\nthreads = {threads}\nclassification = "{classification}"')

    sel_1, views_1 = from_files(sc(1))
    one = F.render_frame(sel_1, views_1[0])[0]
    sel, views = from_files(sc(2))
    key = F._balance_key(views[0], 2)
    bands = F.BandLearning()
    for _ in range(3):
        assert np.array_equal(F.render_frame(sel, views[0], None, bands)[0], one)
    learned = bands.costs[key]
    assert learned.est.shape == (8,) and (learned.est > 0).all()       # (frame 2's, learned during frame 3)
    bands.costs[key] = _skewed_bands()
    setup = F.prepare(sel, views[0], None, bands)
    assert setup.rows.tolist() == bands.costs[key].rows.tolist() != F.image_bands(62, 2).tolist()
    assert setup.queue.tolist() == [1, 2, 0, 3]         # the large middle bands first
    assert np.array_equal(F.render_frame(sel, views[0], None, bands)[0], one)


@pytest.mark.parametrize("classification", ["pre", "post"])
@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_any_thread_count_and_a_slowed_thread_give_the_one_thread_image_bit_for_bit(make_scene, volume, monkeypatch,
                                                                                   classification, projection):
    """Threads take the next band when free (render_slab), so which thread renders which band depends on their
    speeds: 1, 2 and 3 threads, over frames on even then learned bands, and 2 threads with one of them slowed
    (as by another process taking its core), all give the one-thread image bit for bit."""
    import threading

    monkeypatch.setattr(F, "MIN_BAND_TILES", 1)
    *_, aug, idx = volume

    def frames(threads, n=3):
        sel, views = from_files(make_scene(
            aug, idx, image="width = 40\nheight = 62",
            camera=f'projection = "{projection}"\nazimuth = 30\nelevation = 20',
            transfer="opacity = [[50, 0.0], [60, 0.5], [130, 0.3], [200, 0.95]]", shading="enabled = true",
            render=f'threads = {threads}\nclassification = "{classification}"'))
        bands = F.BandLearning()
        return [F.render_frame(sel, views[0], None, bands)[0] for _ in range(n)]

    one = frames(1, 1)[0]
    for threads in (2, 3):
        assert all(np.array_equal(img, one) for img in frames(threads)), threads
    fast, took = F.T.render, []

    def slowed(*args):                  # the pool's thread sleeps before each band it takes
        if threading.current_thread().name.endswith("_0"):
            time.sleep(0.003)
        took.append((threading.current_thread().name, int(args[-1].mine[0])))
        return fast(*args)

    monkeypatch.setattr(F.T, "render", slowed)
    assert all(np.array_equal(img, one) for img in frames(2))
    names = {name for name, _ in took}      # the calling thread draws bands beside the pool's thread
    assert threading.current_thread().name in names and all(
        name == threading.current_thread().name or name.startswith("isplat") for name in names)


def test_bands_are_learned_while_the_next_frame_renders(make_scene, volume, monkeypatch):
    """A frame's band times are learned (learn_bands) during the next frame, while its threads render, from the
    calling thread: after frame 1 nothing is learned yet; after frame 2 frame 1 has marked its kind seen;
    after frame 3 frame 2 has started the profile. Each frame is learned once, in order."""
    import threading

    *_, aug, idx = volume
    sel, views = from_files(make_scene(aug, idx, image="width = 40\nheight = 64", render="threads = 2",
                                       transfer="opacity = [[50, 0.0], [60, 0.5], [200, 0.95]]"))
    key = F._balance_key(views[0], 2)
    calls, orig = [], F.learn_bands
    monkeypatch.setattr(F, "learn_bands", lambda costs, t: calls.append((threading.current_thread().name,
                                                                             t.band_seconds.copy())) or orig(costs, t))
    bands = F.BandLearning()        # the frames' state, kept by the caller (a Renderer), not by the selection
    F.render_frame(sel, views[0], None, bands)
    assert key not in bands.costs and len(bands.pending) == 1 and calls == []
    F.render_frame(sel, views[0], None, bands)
    assert bands.costs[key].est is None and len(bands.pending) == 1
    F.render_frame(sel, views[0], None, bands)
    assert bands.costs[key].est is not None and len(bands.pending) == 1
    assert [name for name, _ in calls] == [threading.current_thread().name] * 2
    assert not np.array_equal(calls[0][1], calls[1][1])          # two frames' times, not one twice


def test_run_parallel_runs_meanwhile_while_the_items_run_and_waits_for_them():
    """run_parallel's ``meanwhile`` runs in the calling thread while the pool's items run (here the items wait
    for it), and the items are all done when run_parallel returns or raises what ``meanwhile`` raised."""
    import threading
    import time

    from isplat.threads import run_parallel

    started, done = threading.Event(), []

    def item(x):
        assert started.wait(10)
        time.sleep(0.05)
        done.append(x)
        return x * x

    assert run_parallel(item, range(3), 3, meanwhile=started.set) == [0, 1, 4]

    def fail():
        started.set()
        raise RuntimeError("meanwhile failed")

    started.clear()
    done.clear()
    with pytest.raises(RuntimeError, match="meanwhile failed"):
        run_parallel(item, range(3), 3, meanwhile=fail)
    assert sorted(done) == [0, 1, 2]
    seen = []
    assert run_parallel(lambda x: seen.append(x) or x, range(2), 1, meanwhile=lambda: seen.append("after")) == [0, 1]
    assert seen == [0, 1, "after"]                               # one thread: after the items


def test_a_views_shading_table_is_made_once_and_only_for_that_view(make_scene, volume):
    """Frames of the same view (here another transfer function) take the table made for the first; another view
    or other Phong terms make their own; each equals a table made afresh; only the last few are kept."""
    from isplat.splat import shade as SH

    SH._table.cache_clear()
    tables, views = {}, {}
    for az, specular, opacity in ((0, 0.3, 0.8), (0, 0.3, 0.5), (40, 0.3, 0.8), (0, 0.6, 0.8)):
        sc = make_scene(volume[3], volume[4], camera=f"azimuth = {az}",
                        transfer=f"opacity = [[50, 0.0], [60, {opacity}]]", shading=f"specular = {specular}")
        view = views[(az, specular, opacity)] = F.views_for(sc, Selection.from_arrays(volume[0], sc,
                                                                                      normal=volume[2]))[0]
        tables[(az, specular, opacity)] = SH.shade_table(view.shading, view.frame, view.geom, threads=2)
    assert tables[(0, 0.3, 0.8)] is tables[(0, 0.3, 0.5)]
    assert not np.array_equal(tables[(0, 0.3, 0.8)], tables[(40, 0.3, 0.8)])
    assert not np.array_equal(tables[(0, 0.3, 0.8)], tables[(0, 0.6, 0.8)])
    assert SH._table.cache_info().currsize == 3
    SH._table.cache_clear()
    for key, view in views.items():
        fresh = SH.shade_table(view.shading, view.frame, view.geom)
        assert fresh is not tables[key] and np.array_equal(fresh, tables[key])
    SH.shade_table(view.shading, view.frame, view.geom, threads=2, dtype=np.float64)
    SH.shade_table(view.shading, view.frame, view.geom, threads=3, dtype=np.float64)
    assert SH._table.cache_info().currsize == SH._table.cache_info().maxsize == 4


# ---------------------------------------------------------------------------------------------------------
# the bounds-checking switch

def test_boundscheck_switch_turns_numba_bounds_checks_on(tmp_path):
    """ISPLAT_BOUNDSCHECK=1 (with its own numba cache) makes an index out of bounds an IndexError."""
    code = ("import numpy as np\n"
            "from isplat.jit import OPTIONS\n"
            "from isplat.splat.select import flat_indices\n"
            "assert OPTIONS['boundscheck'] is True\n"
            "try:\n"
            "    flat_indices(np.array([0, 1]), np.array([0, 5]), np.zeros(2, np.int32), 4, np.array([1, 4, 16]))\n"
            "except IndexError:\n"
            "    print('caught')\n")
    env = dict(os.environ, ISPLAT_BOUNDSCHECK="1", NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "caught"


# ---------------------------------------------------------------------------------------------------------
# loading compiled code from numba's cache (isplat.jit._CacheLoad)

CACHED = """
import sys
import numpy as np
from isplat.jit import jit, leaf

@leaf
def _step(x):
    return 2.0 * x + 1.0

@jit
def kernel(a):
    out = np.empty(a.shape[0] + 1)       # an allocation: needs numba's runtime initialised
    for i in range(a.shape[0]):
        out[i] = _step(a[i])
    out[-1] = a.sum()
    return out
"""
CACHED_RUN = """
import logging, sys
logging.basicConfig(level=logging.INFO, format="%(message)s")
sys.path.insert(0, sys.argv[1])
import numpy as np
from cached_mod import kernel
out = kernel(np.arange(5.0))
print(repr(out.tolist()), kernel.stats.cache_hits[kernel.signatures[0]], 'numba.np.polynomial.polynomial_core' in sys.modules)
"""


def test_cached_kernels_load_without_numbas_registry_refresh(tmp_path):
    """The first process compiles and saves; the next loads the machine code from the cache, without importing
    the typing and lowering registries that only compiling needs (numba.np.polynomial stands for them), and
    computes the same; ISPLAT_NUMBA_STOCK_LOAD=1 loads through numba's own cache object (registries
    refreshed) with the same result. A compile is announced once, as an INFO log line naming the cache."""
    (tmp_path / "mod").mkdir()
    (tmp_path / "mod" / "cached_mod.py").write_text(CACHED)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("ISPLAT_NUMBA_STOCK_LOAD", None)

    def run(**extra):
        out = subprocess.run([sys.executable, "-c", CACHED_RUN, str(tmp_path / "mod")], env=dict(env, **extra),
                             capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        values, hits, registries = out.stdout.split("] ")[0] + "]", *out.stdout.split("] ")[1].split()
        announced = [line for line in out.stderr.splitlines() if "compiling the kernels" in line]
        return values, int(hits), registries == "True", announced

    expected = repr([1.0, 3.0, 5.0, 7.0, 9.0, 10.0])
    values, hits, registries, announced = run()              # compiled (numba's compiler refreshes)
    assert (values, hits, registries) == (expected, 0, True)
    assert len(announced) == 1 and str(tmp_path / "cache") in announced[0]
    assert run() == (expected, 1, False, [])                 # loaded, no refresh, nothing said
    assert run(ISPLAT_NUMBA_STOCK_LOAD="1") == (expected, 1, True, [])


def test_a_stage_called_from_python_computes_as_its_python(monkeypatch):
    """A stage has no Python wrapper (isplat.jit._Stage): a call from Python goes through a small compiled
    caller made for it and returns what the function computes as Python; ``ISPLAT_STRICT_STAGES=1`` makes such
    a call an error."""
    from isplat import jit as J
    from isplat.normals import _sgn
    from isplat.splat.traverse import footprint_box

    assert type(_sgn) is J._Stage and type(footprint_box) is J._Stage
    for x in (-2.5, 0.0, 3.0):
        assert _sgn(x) == _sgn.py_func(x)
    args = (10.3, 4.7, 2.2, 1.5, 0, 32, 40)
    assert footprint_box(*args) == footprint_box.py_func(*args)
    monkeypatch.setattr(J, "STRICT", True)
    with pytest.raises(RuntimeError, match="footprint_box is a compiled stage"):
        footprint_box(*args)


def test_isplat_never_calls_a_stage_from_python(tmp_path):
    """Every stage is reached from compiled code only (a stage called from Python would compile a caller in
    every process, uncached): the whole pipeline, with every kind of frame, runs with ISPLAT_STRICT_STAGES=1."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    env.update(ISPLAT_STRICT_STAGES="1", ISPLAT_PROGRESS="0")

    def run(*args):
        out = subprocess.run([sys.executable, "-m", "isplat", *args], cwd=tmp_path, env=env, capture_output=True,
                             text=True, timeout=600)
        assert out.returncode == 0, (args, out.stderr)

    run("sample", "engine", "-o", "e.npy", "--shape", "24,20,16")
    run("augment", "e.npy", "-o", "e.aug.h5")
    run("index", "e.aug.h5", "-o", "e.idx.h5")
    (tmp_path / "s.toml").write_text(scene_text("e.aug.h5", "e.idx.h5", image="width = 24\nheight = 20",
                                                transfer="opacity = [[60, 0], [120, 0.6], [255, 0.9]]"))
    for sets in ([], ["render.classification=\"pre\""], ["render.method=\"full\""],
                 ["render.method=\"full\"", "render.classification=\"pre\""], ["camera.projection=\"perspective\""],
                 ["camera.projection=\"perspective\"", "render.classification=\"pre\""],
                 ["render.sheets=\"image\"", "render.classification=\"pre\""], ["render.supersample=2"],
                 ["shading.enabled=false", "render.threads=3"]):
        run("render", "s.toml", "-o", f"{len(os.listdir(tmp_path))}.png", *[f"--set={s}" for s in sets])
    run("render", "s.toml", "-o", "slabs.png", "--slabs", "3")
    run("render", "s.toml", "-o", "dask.png", "--slabs", "2", "--scheduler", "local:2")
    run("stats", "e.aug.h5", "e.idx.h5", "--scene", "s.toml")


def test_a_cached_kernel_is_stale_when_any_file_of_compiled_functions_changes(tmp_path):
    """A kernel's cache is fresh only while its own file and every file of isplat's compiled functions are
    unchanged (each technique's kernel holds traverse.py's stages): the same stamp loads, another compiles
    again. And ``KERNEL_SOURCES`` names every module that compiles functions."""
    from pathlib import Path

    import isplat
    from isplat import jit as J

    root = Path(isplat.__file__).parent
    compiling = {str(p.relative_to(root)) for p in root.rglob("*.py")
                 if "import jit" in p.read_text() or "import leaf" in p.read_text() or p.name == "jit.py"}
    assert compiling == set(J.KERNEL_SOURCES)
    (tmp_path / "mod").mkdir()
    (tmp_path / "mod" / "cached_mod.py").write_text(CACHED)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("ISPLAT_NUMBA_STOCK_LOAD", None)
    code = ("import sys\nimport isplat.jit as J\nJ.kernel_sources_stamp = lambda: sys.argv[2]\n" + CACHED_RUN)

    def hits(stamp):
        out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "mod"), stamp], env=env,
                             capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        return int(out.stdout.split("] ")[1].split()[0])

    assert [hits("a"), hits("a"), hits("b"), hits("b"), hits("a")] == [0, 1, 0, 1, 0]


def test_prebuilt_kernels_load_on_a_first_run_without_compiling(tmp_path):
    """isplat.prebuilt compiles what a workload calls for x86-64-v3 into a folder with a manifest; a process
    with an empty numba cache then loads the kernel from it (a cache hit, nothing compiled, the same values);
    a manifest for other sources is ignored, and so is the folder when bounds checks are on."""
    from isplat import prebuilt as PB

    if not PB.portable_here():
        pytest.skip("not an x86-64-v3 CPU")
    mod = tmp_path / "mod"
    mod.mkdir()
    (mod / "cached_mod.py").write_text(CACHED)
    (mod / "work_mod.py").write_text("import numpy as np\nimport cached_mod\n\n\ndef run():\n"
                                     "    cached_mod.kernel(np.arange(3.0))\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(mod), os.environ.get("PYTHONPATH", "")]))
    env.pop("ISPLAT_NUMBA_STOCK_LOAD", None)
    built = subprocess.run([sys.executable, "-c", "import sys; from isplat.prebuilt import build; "
                            "print(build(sys.argv[1], 'work_mod:run', ['cached_mod'])['kernels'])",
                            str(tmp_path / "pre")], env=env, capture_output=True, text=True, timeout=300)
    assert built.returncode == 0, built.stderr
    assert built.stdout.split()[-1] == "1"

    def run(cache, **extra):
        env_run = dict(env, NUMBA_CACHE_DIR=str(tmp_path / cache), ISPLAT_PREBUILT=str(tmp_path / "pre"), **extra)
        out = subprocess.run([sys.executable, "-c", CACHED_RUN, str(mod)], capture_output=True, text=True,
                             env=env_run, timeout=300)
        assert out.returncode == 0, out.stderr
        hits = int(out.stdout.split("] ")[1].split()[0])
        return out.stdout.split("] ")[0] + "]", hits, "compiling the kernels" in out.stderr

    expected = repr([1.0, 3.0, 5.0, 7.0, 9.0, 10.0])
    assert run("empty1") == (expected, 1, False)
    assert run("empty2", ISPLAT_BOUNDSCHECK="1") == (expected, 0, True)
    manifest = tmp_path / "pre" / "manifest.json"
    manifest.write_text(manifest.read_text().replace('"sources": "', '"sources": "0'))
    assert run("empty3") == (expected, 0, True)


def test_numba_disable_jit_still_imports_the_kernels():
    """NUMBA_DISABLE_JIT=1 (numba's switch for debugging kernels as Python) leaves the functions plain: every
    kernel module still imports, and a kernel runs as Python."""
    code = ("import numpy as np\n"
            "import isplat.frame, isplat.splat.post, isplat.splat.select, isplat.index.codec, isplat.augment\n"
            "from isplat.splat.composite import finish\n"
            "assert not hasattr(finish, 'py_func')\n"
            "out = np.zeros((1, 1, 4), np.float32)\n"
            "print(finish(np.array([[[0.5, 0, 0, 0.5]]], np.float32), np.zeros(4), out), out[0, 0, 0])\n")
    out = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, NUMBA_DISABLE_JIT="1"),
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "1.0"]


@pytest.mark.parametrize("sets, plan, fields", [
    ([], "PostPlan", ()), (['render.classification="pre"'], "PrePlan", ("fp", "sheet")),
    (['render.classification="pre"', 'render.sheets="image"'], "SheetsPlan", ("fp", "sheet")),
    (['render.mode="mip"'], "MipPlan", ()), (['render.mode="minip"'], "MipPlan", ())])
def test_each_technique_prepares_a_plan_of_its_own(sets, plan, fields):
    """frame.prepare asks the scene's technique (frame.TECHNIQUES) for its plan, a named tuple registered with the
    traversal (traverse.register): the post-classified one has no footprint and no sheet."""
    import importlib

    from isplat.scene import parse_scene
    from isplat.splat import traverse as T

    vol = np.zeros((8, 8, 8), np.uint8)
    vol[2:6, 2:6, 2:6] = 200
    sc = parse_scene("[image]\nwidth = 16\nheight = 16\n[transfer]\nopacity = [[100, 0], [200, 0.8]]", ".", "t.toml",
                     sets, data_required=False)
    sel = Selection.from_arrays(vol, sc)
    setup = F.prepare(sel, F.views_for(sc, sel)[0])
    assert type(setup.plan).__name__ == plan and type(setup.plan) in T.TECHNIQUES
    assert {f for f in ("fp", "sheet") if f in setup.plan._fields} == set(fields)
    modules = {importlib.import_module(m, "isplat").__name__ for m in F.TECHNIQUES.values()}
    assert {c.__module__ for c in T.TECHNIQUES} == modules
    assert F.render_slab(setup).img[..., 3].max() > 0.5


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(h=st.integers(1, 40), w=st.integers(1, 9), threads=st.integers(1, 5), seed=st.integers(0, 2**31 - 1),
       bg=st.tuples(*[st.floats(0, 1)] * 4))
def test_finish_image_by_row_blocks_is_the_whole_and_the_obvious_formula(h, w, threads, seed, bg):
    """Any thread count finishes each pixel alike; the result is (premultiplied + (1 - a) * bg_a * bg_rgb) over
    alpha a + (1 - a) * bg_a, clipped to [0, 1]; and a non-finite pixel in any row block is refused."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 1, (h, w, 1))
    img = np.concatenate([rng.uniform(0, 1, (h, w, 3)) * a, a], axis=-1).astype(np.float32)
    out = F.finish_image(img, bg, threads=threads)
    assert np.array_equal(out, F.finish_image(img, bg))
    a64 = img[..., 3:].astype(np.float64)
    t = (1 - a64) * bg[3]
    alpha = a64 + t
    rgb = np.where(alpha > 0, (img[..., :3] + t * np.asarray(bg[:3])) / np.where(alpha > 0, alpha, 1), 0.0)
    want = np.clip(np.concatenate([rgb, alpha], axis=-1), 0, 1)
    assert np.abs(out - want).max() <= 1e-6
    img[rng.integers(h), rng.integers(w), rng.integers(4)] = np.nan
    with pytest.raises(IsplatError, match="non-finite"):
        F.finish_image(img, bg, threads=threads)


@settings(max_examples=150, deadline=None)
@given(a=st.tuples(st.integers(-5, 300), st.integers(0, 40)), b=st.tuples(st.integers(-5, 300), st.integers(0, 40)),
       base=st.tuples(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3)),
       terms=st.tuples(*[st.floats(-3, 3, allow_subnormal=False)] * 4), fractional=st.booleans())
def test_rect_hull_orthographic_is_the_hull_of_the_corners_bit_for_bit(a, b, base, terms, fractional):
    """rect_hull (orthographic) takes each bound from the least or greatest terms in a and in b; against the
    obvious hull of the four corners' projections, computed as the perspective branch and the pixel map do
    (``(x0 + a Xa) + b Xb``): the same floats, bit for bit (rounding is monotonic)."""
    from isplat.splat import traverse as K

    a0, a1 = a[0], a[0] + a[1]
    b0, b1 = b[0], b[0] + b[1]
    if fractional:                                  # _cell_pixels passes the square's bounds as floats
        a0, a1, b0, b1 = a0 - 0.5, a1 + 0.25, b0 - 0.5, b1 + 0.25
    coef = [0.0] * 16
    coef[K.XA], coef[K.XB], coef[K.YA], coef[K.YB] = terms
    xs, ys = base
    xs_c = [(xs + ka * coef[K.XA]) + kb * coef[K.XB] for ka in (a0, a1) for kb in (b0, b1)]
    ys_c = [(ys + ka * coef[K.YA]) + kb * coef[K.YB] for ka in (a0, a1) for kb in (b0, b1)]
    got = K.rect_hull(a0, a1, b0, b1, np.array([xs, ys, 0.0]), tuple(coef), False)
    assert got == (True, min(xs_c), max(xs_c), min(ys_c), max(ys_c), 1.0)


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 10 ** 6), h=st.integers(1, 40), w=st.integers(1, 40), p=st.floats(0, 1), data=st.data())
def test_occlusion_look_ups_against_the_obvious(seed, h, w, p, data):
    """_tiles_whole (the summed-area table of whole tiles, build_sat) and pixels_saturated against numpy on a
    random saturation mask: whether every tile a box touches is whole, whether every pixel in it is set."""
    from isplat.splat import traverse as K
    from isplat.splat.composite import TILE

    sat = (np.random.default_rng(seed).random((h, w)) < p).astype(np.uint8)
    npix = F._tile_pixels(h, w)
    tile_sat = np.zeros(npix.shape, np.int32)
    np.add.at(tile_sat, (np.arange(h)[:, None] // TILE, np.arange(w)[None, :] // TILE), sat)
    ty0 = data.draw(st.integers(0, npix.shape[0] - 1))
    satab = np.zeros((npix.shape[0] - ty0 + 1, npix.shape[1] + 1), np.int32)
    K.build_sat(tile_sat, npix, ty0, satab)
    y0 = data.draw(st.integers(ty0 * TILE, h - 1))
    y1 = data.draw(st.integers(y0, h - 1))
    x0 = data.draw(st.integers(0, w - 1))
    x1 = data.draw(st.integers(x0, w - 1))
    whole = tile_sat >= npix
    touched = whole[y0 // TILE:y1 // TILE + 1, x0 // TILE:x1 // TILE + 1]
    assert K._tiles_whole(satab, ty0, x0, x1, y0, y1) == touched.all()
    assert K.pixels_saturated(sat, x0, x1, y0, y1) == sat[y0:y1 + 1, x0:x1 + 1].all()


def _hidden_reference(a0, b0, size, n_a, n_b, xs, ys, coef, ex, ey, w, y0b, y1b, et_on, sat, pixels):
    """The occlusion test of one square of a slice, orthographic, as docs/design.md states it: its footprints'
    pixel box (the hull of its corners grown by the reach) meets no pixel of the band, or (early termination on)
    only saturated ones (``pixels`` False: whole tiles only)."""
    import math

    from isplat.splat import traverse as K
    from isplat.splat.composite import TILE

    a1, b1 = min(a0 + size, n_a) - 1, min(b0 + size, n_b) - 1
    xa, xb = (a0 * coef[K.XA], a1 * coef[K.XA]), (b0 * coef[K.XB], b1 * coef[K.XB])
    ya, yb = (a0 * coef[K.YA], a1 * coef[K.YA]), (b0 * coef[K.YB], b1 * coef[K.YB])
    x0 = max(int(math.ceil(xs + min(xa) + min(xb) - ex)), 0)
    x1 = min(int(math.floor(xs + max(xa) + max(xb) + ex)), w - 1)
    y0 = max(int(math.ceil(ys + min(ya) + min(yb) - ey)), y0b)
    y1 = min(int(math.floor(ys + max(ya) + max(yb) + ey)), y1b - 1)
    if x0 > x1 or y0 > y1:
        return True
    if not et_on:
        return False
    tiles = [(ty, tx) for ty in range(y0 // TILE, y1 // TILE + 1) for tx in range(x0 // TILE, x1 // TILE + 1)]
    whole = all(sat[ty * TILE:(ty + 1) * TILE, tx * TILE:(tx + 1) * TILE].all() for ty, tx in tiles)
    return whole or (pixels and bool(sat[y0:y1 + 1, x0:x1 + 1].all()))


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 10 ** 6), n_a=st.integers(1, 64), n_b=st.integers(1, 64), scale=st.floats(0.2, 2.0),
       turn=st.one_of(st.sampled_from([0.0, 1.5707963267948966]), st.floats(0, 6.3)),
       p=st.sampled_from([0.0, 0.02, 0.3, 0.9]), et_on=st.booleans(), data=st.data())
def test_visible_cells_against_a_test_per_cell(seed, n_a, n_b, scale, turn, p, et_on, data):
    """visible_cells (orthographic: a block in the clear keeps its cells untested, _block_test) against the
    obvious: every cell of the slice tested on its own, in order, behind its region's and block's tests; a random
    slice's projection (axis-aligned too: a cell one voxel wide then spans no pixel when the reach is under half
    a pixel), band and saturation mask (sparse to dense)."""
    from isplat.splat import traverse as K
    from isplat.splat.composite import TILE

    rng = np.random.default_rng(seed)
    h, w = 48, 56
    sat = (rng.random((h, w)) < p).astype(np.uint8)
    npix = F._tile_pixels(h, w)
    tile_sat = np.zeros(npix.shape, np.int32)
    np.add.at(tile_sat, (np.arange(h)[:, None] // TILE, np.arange(w)[None, :] // TILE), sat)
    ty0, ty1 = 0, npix.shape[0]                                # the whole image, or a band of it
    if data.draw(st.booleans()):
        ty0 = data.draw(st.integers(0, npix.shape[0] - 1))
        ty1 = data.draw(st.integers(ty0 + 1, npix.shape[0]))
    y0b, y1b = ty0 * TILE, min(ty1 * TILE, h)
    satab = np.zeros((ty1 - ty0 + 1, npix.shape[1] + 1), np.int32)
    K.build_sat(tile_sat, npix, ty0, satab)
    coef = np.zeros(16)
    coef[[K.XA, K.XB, K.YA, K.YB]] = scale * np.array([np.cos(turn), -np.sin(turn), np.sin(turn), np.cos(turn)])
    coef[[K.XB, K.YB]] *= data.draw(st.floats(0.5, 2.0))
    xs, ys = rng.uniform(-10, 30), rng.uniform(-10, 30)       # mostly inside the image, some blocks in the clear
    ex, ey = abs(coef[K.XA]) + abs(coef[K.XB]), abs(coef[K.YA]) + abs(coef[K.YB])
    base = (xs, ys, 0.0, 0.0, 0.0, 0.0, 0.0)
    boxes = (n_a, n_b, base, tuple(coef), False, ex, ey, w, y0b, y1b, ty0, et_on)
    # one region: its blocks and their cells inside the slice, each cell with a random count of voxels
    bpos = [bp for bp in range(16) if (bp % 4) * 16 < n_a and (bp // 4) * 16 < n_b]
    cpos, ccount, bptr, bvox = [], [], [0], [0]
    for bp in bpos:
        for cp in range(16):
            if (bp % 4) * 16 + (cp % 4) * 4 < n_a and (bp // 4) * 16 + (cp // 4) * 4 < n_b and rng.random() < 0.8:
                cpos.append(cp)
                ccount.append(int(rng.integers(1, 17)))
        bptr.append(len(cpos))
        bvox.append(bvox[-1] + sum(ccount[bptr[-2]:]))
    hier = (np.zeros(1, np.int32), np.array([0, len(bpos)], np.int64), np.array(bpos, np.uint8),
            np.array(bptr, np.int64), np.array(bvox, np.int64), np.array(cpos, np.uint8), np.array(ccount, np.uint8))
    cells = np.zeros((max(len(cpos), 1), 4), np.int64)
    nc = K.visible_cells(np.zeros(1, np.int64), 0, 1, hier, n_a, boxes, satab, sat, tile_sat, cells)
    args = (n_a, n_b, xs, ys, coef, ex, ey, w, y0b, y1b, et_on, sat)
    want = []
    if not _hidden_reference(0, 0, 64, *args, False):
        for k, bp in enumerate(bpos):
            ba0, bb0 = (bp % 4) * 16, (bp // 4) * 16
            if _hidden_reference(ba0, bb0, 16, *args, False):
                continue
            n = bvox[k]
            for q in range(bptr[k], bptr[k + 1]):
                ca0, cb0 = ba0 + (cpos[q] % 4) * 4, bb0 + (cpos[q] // 4) * 4
                if not _hidden_reference(ca0, cb0, 4, *args, True):
                    want.append([n, n + ccount[q], ca0, cb0])
                n += ccount[q]
    assert cells[:nc].tolist() == want


def _signatures() -> int:
    """The compiled signatures of every numba function of isplat's kernel modules (isplat.jit.KERNEL_SOURCES)."""
    import importlib

    from numba.core.dispatcher import Dispatcher

    from isplat.jit import KERNEL_SOURCES

    mods = [importlib.import_module("isplat." + f[:-3].replace("/", ".")) for f in KERNEL_SOURCES]
    return sum(len(v.signatures) for m in mods for v in vars(m).values() if isinstance(v, Dispatcher))


@pytest.mark.parametrize("classification", ["pre", "post"])
def test_a_run_of_frames_compiles_nothing_after_its_first_frames(make_scene, volume, monkeypatch, classification):
    """Views of an orbit, each rendered several times on 2 threads, on even bands, then on bands cut by what
    was learned, compile nothing after the first frames: every frame of a run gives the kernels the types the
    first gave (learned bands' rows were writable, and compiled the kernels again)."""
    monkeypatch.setattr(F, "MIN_BAND_TILES", 1)
    *_, aug, idx = volume
    sel, views = from_files(make_scene(aug, idx, image="width = 40\nheight = 62",
                                       views="orbit_steps = 3",
                                       transfer="opacity = [[50, 0.0], [60, 0.5], [200, 0.95]]",
                                       render=f'threads = 2\nclassification = "{classification}"'))
    bands = F.BandLearning()
    for _ in range(2):
        for v in views:
            F.render_frame(sel, v, None, bands)
    first = _signatures()
    for key in bands.costs:
        bands.costs[key] = _skewed_bands()
    for _ in range(3):
        for v in views:
            F.render_frame(sel, v, None, bands)
    assert len(bands.costs) == len({F._balance_key(v, 2) for v in views}) == 3
    assert _signatures() == first
