"""A prototype of the explicit-SIMD row span (issue 27 item 2), measured against the scalar sample it would replace.

``python -m benchmarks.simd_span [--rounds N]`` (from the repository root; needs the chest data that
``python -m benchmarks sampler`` makes under out/bench-sampler/*/data).

What it measures. Both kernels render the same orthographic frame of issue 27's chest scene (the real
:class:`isplat.frame.Setup`: its whole channels, its transfer and Phong tables, its slice geometry, its slice
order), sampling *every* quad of every slice (no index, no occlusion tests: the rows' spans over the whole slice),
with early termination, one thread:

* ``scalar``: per pixel of a row span what :func:`isplat.splat.post._sample_square` does for a square whose quads
  are all needed (the saturation byte, :func:`isplat.splat.post._pixel_quad`) and then the real
  :func:`isplat.splat.post._sample` (the code of today's frames);
* ``simd``: the span in chunks of 8 pixels, each a lane of LLVM vectors (:func:`benchmarks._simd.span8`: the
  inverse map, the quads, the density taps, the bilinear density, the opacity and colour tables' lerps, the Phong
  factors of the four corners weighted by their gradient magnitudes, the compositing into the 8 pixels' RGBA;
  masks instead of branches).

This frame is the best case for lanes: whole rows of needed pixels. The real frame (the index's quads only, in
squares of 8 or 16 voxels, each pixel's quad flags tested) fills 2.8 of 8 lanes on the chest, and there the
prototype is slower (docs/design.md, *Where a frame's time goes, per sample*; benchmarks/simd_post.patch puts it
in the renderer).

The two images must be bit for bit equal (the same operations in the same order per lane, no fused
multiply-add); the script checks that, and first :func:`check_rows` (random rows, flags, saturated pixels,
float32 and float64 images, each shading), and prints ns per composited sample of each, frames interleaved, and
the median of the per-round ratios. The numbers are in docs/design.md (*Where a frame's time goes, per sample*).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

from benchmarks._simd import span8
from isplat.splat.composite import TILE
from isplat.splat.post import _cell_pixels, _ortho_inverse, _pixel_quad, _row_span, _sample, lerp_tables
from isplat.splat.select import CELL
from isplat.splat.traverse import SliceGeometry, slice_bases

# ---------------------------------------------------------------------------------------------------------------
# the two kernels: the same frame, every quad of every slice sampled, orthographic, early termination on


@njit(nogil=True)
def frame_scalar(order, whole, alpha, color, shade, use_gm, use_shade, geo, img, sat, tile_sat, et):
    """Per pixel of each row span, today's sample (:func:`isplat.splat.post._sample`); returns the samples
    composited."""
    density, gm, nrm, strides, n_a, n_b = whole.density, whole.gm, whole.nrm, whole.strides, whole.n_a, whole.n_b
    cs = np.empty(1)
    H, W = img.shape[0], img.shape[1]
    u0, u1, v0, v1 = -0.5, n_a - 0.5, -0.5, n_b - 0.5
    drawn = 0
    for c in order:
        base = slice_bases(c, geo, cs)
        inv = _ortho_inverse(base, geo.coef)
        x0, x1, y0, y1 = _cell_pixels(u0, u1, v0, v1, base, geo.coef, False, W, 0, H)
        cbase = c * strides[2] + strides[3]
        for y in range(y0, y1 + 1):
            xa, xb = _row_span(y, u0, u1, v0, v1, inv, x0, x1)
            for x in range(xa, xb + 1):
                if sat[np.uint64(y), np.uint64(x)] != 0:
                    continue
                ok, u, v, qa, qb = _pixel_quad(x, y, False, base, geo.coef, inv, u0, u1, v0, v1)
                if not ok:
                    continue
                fu, fv = max(u - qa, 0.0), max(v - qb, 0.0)
                done = _sample(x, y, fu, fv, cbase + qa * strides[0] + qb * strides[1],
                               strides[0] if qa + 1 < n_a else 0, strides[1] if qb + 1 < n_b else 0, u, v,
                               density, gm, nrm, alpha, color, shade, use_gm, use_shade, base, geo, img,
                               sat, tile_sat, et, False, None, None)
                drawn += done > 0
    return drawn


@njit(nogil=True)
def frame_simd(order, whole, alpha, color, shade, use_gm, use_shade, geo, img, sat, tile_sat, et):
    """:func:`frame_scalar` with each row span's pixels 8 at a time, in vector lanes
    (:func:`benchmarks._simd.span8`)."""
    density, gm, nrm, strides, n_a, n_b = whole.density, whole.gm, whole.nrm, whole.strides, whole.n_a, whole.n_b
    cs = np.empty(1)
    H, W = img.shape[0], img.shape[1]
    u0, u1, v0, v1 = -0.5, n_a - 0.5, -0.5, n_b - 0.5
    mark = np.zeros(1, np.uint8)
    drawn = 0
    for c in order:
        base = slice_bases(c, geo, cs)
        inv = _ortho_inverse(base, geo.coef)
        x0, x1, y0, y1 = _cell_pixels(u0, u1, v0, v1, base, geo.coef, False, W, 0, H)
        cbase = c * strides[2] + strides[3]
        for y in range(y0, y1 + 1):
            xa, xb = _row_span(y, u0, u1, v0, v1, inv, x0, x1)
            d, _ = span8(y, xa, xb, True, u0, u1, v0, v1, inv, cbase, mark, 1, density, gm, nrm, strides, n_a, n_b,
                         alpha, color, shade, use_gm, use_shade, img, sat, tile_sat, et)
            drawn += d
    return drawn


# ---------------------------------------------------------------------------------------------------------------
# the row check: span8 against the per-pixel loop on random rows


@njit
def _scalar_row(y, xa, xb, every, u0, u1, v0, v1, inv, cbase, mark, nca, density, gm, nrm, strides, n_a, n_b, alpha,
                color, shade, use_gm, use_shade, geo, img, sat, tile_sat, et):
    """isplat.splat.post._sample_square's per-pixel loop for one row (orthographic, no cuts, labels or thick axis)."""
    drawn = newly = 0
    base = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    for x in range(xa, xb + 1):
        if sat[y, x] != 0:
            continue
        ok, u, v, qa, qb = _pixel_quad(x, y, False, base, geo.coef, inv, u0, u1, v0, v1)
        if not ok:
            continue
        if not every:
            flags = mark[(qb // CELL) * nca + qa // CELL]
            la = qa % CELL
            lb = qb % CELL
            if not (flags & 1 or (la == CELL - 1 and flags & 2) or (lb == CELL - 1 and flags & 4)
                    or (la == CELL - 1 and lb == CELL - 1 and flags & 8)):
                continue
        fu, fv = max(u - qa, 0.0), max(v - qb, 0.0)
        done = _sample(x, y, fu, fv, cbase + qa * strides[0] + qb * strides[1], strides[0] if qa + 1 < n_a else 0,
                       strides[1] if qb + 1 < n_b else 0, u, v, density, gm, nrm, alpha, color, shade, use_gm,
                       use_shade, base, geo, img, sat, tile_sat, et, False, None, None)
        drawn += done > 0
        newly += done > 1
    return drawn, newly


@njit
def _simd_row(y, xa, xb, every, u0, u1, v0, v1, inv, cbase, mark, nca, density, gm, nrm, strides, n_a, n_b, alpha,
              color, shade, use_gm, use_shade, img, sat, tile_sat, et):
    return span8(y, xa, xb, every, u0, u1, v0, v1, inv, cbase, mark, nca, density, gm, nrm, strides, n_a, n_b, alpha,
                 color, shade, use_gm, use_shade, img, sat, tile_sat, et)


def _geo():
    z3 = (0.0, 0.0, 0.0)
    return SliceGeometry(tuple([0.0] * 16), (z3, z3, z3), z3, False, 1.0, 0.0, 1.0, np.zeros((0, 4)),
                         tuple([0.0] * 9))


def check_rows(use_shade, phong_cols, dtype):
    """Random volumes, tables (with opacity 0 codes), inverse maps, flags, saturated pixels and early termination:
    every row's image, saturation, tile counts and counters of :func:`benchmarks._simd.span8` equal the per-pixel
    loop's (:func:`_scalar_row`), bit for bit; raises AssertionError if not. Returns (samples, pixels saturated)."""
    rng = np.random.default_rng(27 + use_shade + phong_cols)
    geo = _geo()
    total = np.zeros(2, np.int64)
    for trial in range(40):
        n_a, n_b, n_c = rng.integers(2, 20), rng.integers(2, 20), 3
        # a slab of the channels: [c, b, a] order, the slice c, or a transposed slice (a steps a row)
        vol = rng.integers(0, 256, (n_c, n_b, n_a)).astype(np.uint8)
        vol[rng.random(vol.shape) < 0.3] = 0
        density = vol.reshape(-1)
        gm = rng.integers(0, 256, density.shape[0]).astype(np.uint8)
        gm[rng.random(gm.shape) < 0.2] = 0
        nrm = rng.integers(0, 65536, density.shape[0]).astype(np.uint16)
        c = int(rng.integers(0, n_c))
        strides = (1, int(n_a), int(n_a * n_b), 0)
        cbase = c * strides[2] + strides[3]
        ng = int(rng.choice([1, 4]))
        atab = rng.random((256, ng)) * (rng.random((256, 1)) < 0.6)
        ctab = rng.random((256, 3))
        alpha, color = lerp_tables(atab, ctab)
        shade = rng.random((65536, phong_cols)).astype(np.float32)
        H, W = 24, 40
        # an orthographic inverse map that puts the slice over the image, rotated and scaled at random
        ang, su, sv = rng.uniform(0, 2 * np.pi), rng.uniform(0.1, 0.8), rng.uniform(0.1, 0.8)
        i1, i2, i4, i5 = su * np.cos(ang), -su * np.sin(ang), sv * np.sin(ang), sv * np.cos(ang)
        uc, vc = rng.uniform(0, n_a), rng.uniform(0, n_b)      # the point the image's centre sees
        inv = (uc - W / 2 * i1 - H / 2 * i2, i1, i2, vc - W / 2 * i4 - H / 2 * i5, i4, i5, 0.0, 0.0)
        nca = (n_a + CELL - 1) // CELL
        mark = rng.integers(0, 16, nca * ((n_b + CELL - 1) // CELL)).astype(np.uint8)
        mark[rng.random(mark.shape) < 0.3] = 0
        every = bool(rng.random() < 0.3)
        a0, b0 = int(rng.integers(0, n_a)), int(rng.integers(0, n_b))
        u0, v0 = (-0.5 if a0 == 0 else float(a0)), (-0.5 if b0 == 0 else float(b0))
        u1, v1 = min(float(a0 + rng.integers(1, 17)), n_a - 0.5), min(float(b0 + rng.integers(1, 17)), n_b - 0.5)
        et = dtype(rng.choice([0.6, 0.99, 2.0]))
        img0 = (rng.random((H, W, 4)) * 0.7).astype(dtype)
        sat0 = (rng.random((H, W)) < 0.2).astype(np.uint8)
        tiles0 = np.zeros(((H + TILE - 1) // TILE, (W + TILE - 1) // TILE), np.int32)
        use_gm = bool(ng > 1)
        spans = [sorted(int(x) for x in rng.integers(0, W, 2)) for _ in range(H)]
        outs = []
        for simd in (False, True):
            img, sat, tiles = img0.copy(), sat0.copy(), tiles0.copy()
            counts = [0, 0]
            for y, (xa, xb) in enumerate(spans):
                args = (y, xa, xb, every, u0, u1, v0, v1, inv, cbase, mark, nca, density, gm, nrm, strides,
                        int(n_a), int(n_b), alpha, color, shade, use_gm, use_shade)
                d, n = _simd_row(*args, img, sat, tiles, et) if simd else _scalar_row(*args, geo, img, sat, tiles, et)
                counts[0] += d
                counts[1] += n
            outs.append((img, sat, tiles, counts))
        (i1, s1, t1, c1), (i2, s2, t2, c2) = outs
        assert np.array_equal(i1, i2), (trial, np.abs(i1.astype(float) - i2).max())
        assert np.array_equal(s1, s2) and np.array_equal(t1, t2) and c1 == c2, trial
        total += np.array(c1)
    assert total[0] > 100 and total[1] > 0      # samples composited, and pixels saturated, in both
    return int(total[0]), int(total[1])


# ---------------------------------------------------------------------------------------------------------------


def setup_for(overrides):
    """The real frame setup of the chest scene (examples/head.toml with ``overrides``)."""
    from isplat.frame import prepare
    from isplat.renderer import Renderer
    from isplat.scene import load_scene

    repo = Path(__file__).resolve().parents[1]
    r = Renderer(load_scene(repo / "examples" / "head.toml", overrides))
    setup = prepare(r.selection, r.views[0])
    return setup


def run_frame(kernel, setup):
    p = setup.plan
    H, W = setup.view.frame.height, setup.view.frame.width
    img = np.zeros((H, W, 4), setup.dtype)
    sat = np.zeros((H, W), np.uint8)
    tile_sat = np.zeros(((H + TILE - 1) // TILE, (W + TILE - 1) // TILE), np.int32)
    et = setup.dtype(setup.et)
    t = time.thread_time()
    n = kernel(np.ascontiguousarray(setup.view.order), p.whole, p.cls.alpha, p.cls.color, p.cls.shade,
               p.cls.use_gm, p.cls.use_shade, p.geo, img, sat, tile_sat, et)
    return time.thread_time() - t, n, img


def main(argv=None):
    from benchmarks.sampler import CASES, WORK, overrides

    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--cases", default="0,1,2")
    a = ap.parse_args(argv)
    for args in [(0, 2, np.float32), (1, 2, np.float32), (2, 6, np.float32), (2, 2, np.float64), (0, 6, np.float64)]:
        n, sat = check_rows(*args)
        print(f"rows check (shading {args[0]}, {args[1]} Phong columns, {args[2].__name__}): span8 = the per-pixel "
              f"loop bit for bit, {n:,} samples, {sat:,} pixels saturated", flush=True)
    data = sorted(WORK.glob("*/data"))
    if not data:
        sys.exit("no chest data under out/bench-sampler/*/data: run python -m benchmarks sampler first")
    d = data[0]
    files = {"chest": (d / "chest-512,512,133.aug.h5", d / "chest-512,512,133.idx.h5"),
             "head": (d / "head-default.aug.h5", d / "head-default.idx.h5")}
    for ci in map(int, a.cases.split(",")):
        name, tag, ov = CASES[ci]
        setup = setup_for(overrides(tag, files, ov, ['render.method="full"']))
        _, ns, img_s = run_frame(frame_scalar, setup)
        _, nv, img_v = run_frame(frame_simd, setup)
        same = np.array_equal(img_s, img_v)
        diff = float(np.abs(img_s.astype(np.float64) - img_v).max())
        ts, tv, ratios = [], [], []
        for i in range(a.rounds):
            pair = [(frame_scalar, ts), (frame_simd, tv)]
            for k, out in (pair if i % 2 == 0 else pair[::-1]):
                out.append(run_frame(k, setup)[0])
            ratios.append(tv[-1] / ts[-1])
        img = "bit for bit equal" if same else f"differ {diff:.3g}"
        print(f"{name}: samples scalar {ns:,} simd {nv:,}; images {img};"
              f" ns/sample scalar {1e9 * statistics.median(ts) / ns:.1f} simd {1e9 * statistics.median(tv) / nv:.1f};"
              f" simd/scalar per-round median {statistics.median(ratios):.3f}", flush=True)


if __name__ == "__main__":
    main()
