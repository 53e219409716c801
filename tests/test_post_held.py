"""post's sampler with only the needed voxels loaded (isplat.splat.post's ``held``, as a reader of range runs
leaves the channels): the bits of the quads held against a voxel-by-voxel reference, and the image of channels
loaded by the range key equal bit for bit to the full channels'."""

import itertools

import numpy as np
import pytest
from conftest import write_volume
from hypothesis import given, settings
from hypothesis import strategies as st
from test_post import post_scene, random_normals

from isplat.renderer import Renderer
from isplat.splat import post as P


def reference_held_quads(loaded, axis):
    """bool [k, j, i]: whether the quad of ``axis``'s slices whose first corner is the voxel has its four corners
    loaded (the next voxel along a and b clamped to the edge), voxel by voxel."""
    from isplat.grid import SLICE_AXES
    ia, ib, _ = SLICE_AXES[axis]                  # i, j, k = 0, 1, 2; the array is [k, j, i]
    da, db = 2 - ia, 2 - ib
    n = loaded.shape
    out = np.zeros(n, bool)
    for v in np.ndindex(*n):
        ok = True
        for sa in (0, 1):
            for sb in (0, 1):
                w = list(v)
                w[da] = min(w[da] + sa, n[da] - 1)
                w[db] = min(w[db] + sb, n[db] - 1)
                ok &= bool(loaded[tuple(w)])
        out[v] = ok
    return out


@settings(max_examples=40, deadline=None)
@given(st.tuples(st.integers(1, 6), st.integers(1, 11), st.integers(1, 11)), st.sampled_from("ijk"),
       st.floats(0, 1), st.integers(0, 10 ** 6))
def test_held_quads_equal_the_voxel_by_voxel_reference(shape, axis, p, seed):
    loaded = np.random.default_rng(seed).random(shape) < p
    bits = P.held_quads(loaded, shape, axis)
    got = np.unpackbits(bits, bitorder="little")[:loaded.size].reshape(shape).astype(bool)
    assert bits.size == -(-loaded.size // 8)
    assert np.array_equal(got, reference_held_quads(loaded, axis))


def needed_by_range(density, intervals):
    """bool [k, j, i]: voxels whose range key (least and greatest density over the in-slice 3 x 3 squares of the
    three slice axes, benchmarks/range_runs.py's ``union``) meets an interval, voxel by voxel."""
    out = np.zeros(density.shape, bool)
    n = density.shape
    for v in np.ndindex(*n):
        vals = set()
        for d in range(3):
            rng = [[v[e]] if e == d else [x for x in (v[e] - 1, v[e], v[e] + 1) if 0 <= x < n[e]] for e in range(3)]
            vals |= {int(density[w]) for w in itertools.product(*rng)}
        out[v] = any(min(vals) <= b and max(vals) >= a for a, b in intervals)
    return out


def sparse_volume(seed, shape):
    """Blocks of 0 and of 200 with a few 120s (in the window): 200s far from a 120 and from the 0s are left out
    and zero-filled, next to 200s kept, so that a quad between them would draw the zeros' ramp through the
    window."""
    r = np.random.default_rng(seed)
    coarse = (r.random(tuple(-(-n // 4) for n in shape)) < 0.6).astype(np.uint8) * 200
    dens = np.kron(coarse, np.ones((4, 4, 4), np.uint8))[:shape[0], :shape[1], :shape[2]]
    dens[r.random(shape) < 0.02] = 120
    return np.ascontiguousarray(dens)


TF_WINDOW = "opacity = [[100, 0.0], [110, 0.6], [130, 0.6], [140, 0.0]]\ncolor = [[0, 1, 0, 0], [255, 0, 0.5, 1]]"


def pool_of(channels, held, extra=0.0, seed=0, zero=True):
    """A pool (WholeChannels with a brick table, as the runs reader makes) of the whole-shape ``channels``
    (flat ``[k, j, i]``, any empty) holding the bricks with a voxel in ``held`` (bool ``[k, j, i]``) and, with
    probability ``extra``, others (all their voxels not loaded), and its loaded bits (uint64, 8 words a row).
    ``zero``: the voxels not in ``held`` zero (as the runs reader leaves them), else as in ``channels``."""
    from isplat.selection import WholeChannels
    shape = held.shape
    g = [-(-n // 8) for n in shape]

    def bricks(a):
        pad = np.zeros([n * 8 for n in g], a.dtype)
        pad[:shape[0], :shape[1], :shape[2]] = a.reshape(shape)
        return pad.reshape(g[0], 8, g[1], 8, g[2], 8).transpose(0, 2, 4, 1, 3, 5).reshape(-1, 512)

    mask = bricks(held)
    used = mask.any(axis=1) | (np.random.default_rng(seed).random(mask.shape[0]) < extra)
    table = np.zeros(mask.shape[0], np.uint32)
    table[used] = np.arange(1, int(used.sum()) + 1)

    def rows(a):
        out = np.zeros((int(used.sum()) + 1, 512), a.dtype)
        out[1:] = np.where(mask[used], bricks(a)[used], 0) if zero else bricks(a)[used]
        return out.reshape(-1)

    pooled = [rows(a) if a.size else a for a in channels]
    words = np.packbits(rows(held), bitorder="little").view("<u8")
    return WholeChannels(pooled[0], pooled[1], pooled[2], table=table, shape=tuple(shape)), words


def _render_held(sc, density, held, layout="pool"):
    """The image with the channels zero-filled where ``held`` is False, as a reader of range runs leaves them,
    and the bits of the quads held made from ``held``: whole-shape channels (isplat.splat.post.held_quads) or,
    as the runs reader holds them, a pool (held_pool)."""
    from dataclasses import replace

    from isplat.selection import WholeChannels
    r = Renderer(sc)
    sel = r.selection
    d, gm, nrm = (a.copy() for a in sel.whole.flat())
    keep = held.reshape(-1)
    for ch in (d, gm, nrm):
        if ch.shape[0]:
            ch[~keep] = 0                       # what a reader of the needed voxels leaves in the rest
    if layout == "whole":
        whole, bits = WholeChannels(d, gm, nrm), {ax: P.held_quads(held, sel.shape, ax) for ax in sel.request.axes}
    else:
        whole, words = pool_of((d, gm, nrm), held, extra=0.2, zero=layout == "pool")
        bits = {ax: P.held_pool(words, whole.table, sel.shape, ax) for ax in sel.request.axes}
        if layout == "packed":          # the rows sharing places, as the runs reader packs them (a voxel not
            from test_pool_pack import packed_channel                  # loaded: another row's, or zero)
            from isplat.runsplace import pack_rows
            bases, n = pack_rows(words)
            whole = replace(whole, density=packed_channel(whole.density, words, bases, n),
                            gradient_magnitude=packed_channel(whole.gradient_magnitude, words, bases, n),
                            normal=packed_channel(whole.normal, words, bases, n), bases=bases, loaded=words)
    r.selection = replace(sel, whole=whole, held=bits)
    return r.render_view(0)[0], r


@pytest.mark.parametrize("cam", ["azimuth = 0\nelevation = 0", "azimuth = 90\nelevation = 0",
                                 "azimuth = 0\nelevation = 90", "azimuth = 33\nelevation = 21"])
@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("layout", ["pool", "whole", "packed"])
def test_only_the_needed_voxels_loaded_give_the_same_image(tmp_path, make_scene, cam, seed, layout):
    shape = (12, 13, 11)
    dens = sparse_volume(seed, shape)
    aug, idx = write_volume(tmp_path, dens, normal=random_normals(seed, shape))
    sc = post_scene(make_scene, aug, idx, cam, transfer=TF_WINDOW, image="width = 40\nheight = 36")
    r0 = Renderer(sc)
    full = r0.render_view(0)[0]
    held = needed_by_range(dens, r0.report.intervals)
    assert 0 < held.sum() < held.size
    img, _ = _render_held(sc, dens, held, layout)
    assert np.array_equal(img, full)
    assert full[..., 3].max() > 0.2


def test_without_the_test_the_zeros_show(tmp_path, make_scene):
    """The pool zero-filled but every quad marked held: quads with a zeroed corner draw wrong densities."""
    from dataclasses import replace
    shape = (12, 13, 11)
    dens = sparse_volume(1, shape)
    aug, idx = write_volume(tmp_path, dens, normal=random_normals(1, shape))
    sc = post_scene(make_scene, aug, idx, "azimuth = 33\nelevation = 21", transfer=TF_WINDOW,
                    image="width = 40\nheight = 36")
    full = Renderer(sc).render_view(0)[0]
    held = needed_by_range(dens, Renderer(sc).report.intervals)
    img, r = _render_held(sc, dens, held)
    assert np.array_equal(img, full)
    r.selection = replace(r.selection, held={ax: np.full_like(b, 255) for ax, b in r.selection.held.items()})
    assert not np.array_equal(r.render_view(0)[0], full)


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10 ** 6), az=st.floats(0, 360), el=st.floats(-80, 80), zoom=st.floats(0.5, 3.0),
       proj=st.sampled_from(["orthographic", "perspective"]), unit=st.sampled_from([4, 8, 16]),
       layout=st.sampled_from(["pool", "packed"]))
def test_property_only_the_needed_voxels_loaded(tmp_path_factory, seed, az, el, zoom, proj, unit, layout):
    from conftest import scene_text
    from isplat.scene import parse_scene
    tmp = tmp_path_factory.mktemp("held")
    shape = tuple(int(x) for x in np.random.default_rng(seed).integers(3, 13, 3))
    dens = sparse_volume(seed, shape)
    aug, idx = write_volume(tmp, dens, normal=random_normals(seed, shape))
    text = scene_text(aug, idx, image="width = 32\nheight = 28", transfer=TF_WINDOW, shading="enabled = true",
                      camera=f'projection = "{proj}"\nazimuth = {az}\nelevation = {el}\nzoom = {zoom}',
                      render='classification = "post"\nearly_termination = 1.0')
    sc = parse_scene(text, tmp, "t.toml")
    old = P.scan_unit
    P.scan_unit = lambda jac, target=None: unit          # squares of every side, partial or not
    try:
        r0 = Renderer(sc)
        full = r0.render_view(0)[0]
        img, _ = _render_held(sc, dens, needed_by_range(dens, r0.report.intervals), layout)
    finally:
        P.scan_unit = old
    assert np.array_equal(img, full)


@settings(max_examples=30, deadline=None)
@given(st.tuples(st.integers(1, 6), st.integers(1, 70), st.integers(1, 70)), st.sampled_from("ijk"),
       st.floats(0, 1), st.integers(0, 10 ** 6))
def test_held_quads_from_the_bits_equal_the_reference(shape, axis, p, seed):
    """From loaded_bits' words, on shapes whose lines and planes cross the 64-bit words anywhere."""
    loaded = np.random.default_rng(seed).random(shape) < p
    got = np.unpackbits(P.held_quads(P.loaded_bits(loaded), shape, axis), bitorder="little")[:loaded.size]
    assert np.array_equal(got.reshape(shape).astype(bool), reference_held_quads(loaded, axis))


EXTENT = st.one_of(st.integers(1, 20), st.sampled_from([8, 16]))     # (edges on a brick's last voxel too)


@settings(max_examples=100, deadline=None)
@given(st.tuples(EXTENT, EXTENT, EXTENT), st.sampled_from("ijk"), st.floats(0, 1), st.floats(0, 1),
       st.integers(0, 10 ** 6))
def test_held_pool_equals_the_reference(shape, axis, p, extra, seed):
    """held_pool's bits (a pool's layout, bricks with no voxel loaded pooled too) are the voxel-by-voxel
    reference's, on shapes whose edges cut the 8^3 bricks anywhere; row 0 (no brick) holds none."""
    loaded = np.random.default_rng(seed).random(shape) < p
    whole, words = pool_of([np.zeros(0, np.uint8)] * 3, loaded, extra, seed)
    got = np.unpackbits(P.held_pool(words, whole.table, shape, axis), bitorder="little").astype(np.uint8)
    want, _ = pool_of([reference_held_quads(loaded, axis).astype(np.uint8).reshape(-1)] * 3, loaded, extra, seed,
                      zero=False)
    inside, _ = pool_of([np.ones(loaded.size, np.uint8)] * 3, loaded, extra, seed, zero=False)   # in the volume
    keep = inside.density.astype(bool)
    assert np.array_equal(got[keep], want.density[keep])
    assert not got[:512].any()
    assert words.size == 8 * (whole.table.max(initial=0) + 1)
