"""benchmarks/range_runs.py: the range keys, today's sampler's read set and the runs' counts against slow, obvious
references on tiny volumes; the superset properties the layout relies on."""

import itertools

import numpy as np
from hypothesis import given, settings, strategies as st

from benchmarks.range_runs import (Cut, _best_bins, _equal_count, cut_cost, dp_cut, footprint, group_stats,
                                   interval_weights, range_key, resolve, run_bins, run_of, runs_meeting,
                                   sampler_reads)

AXIS_DIM = {"k": 0, "j": 1, "i": 2}          # the array dimension of [k, j, i] a slice axis is


def cell_window(a: int, n: int) -> set:
    """The voxels along one dimension of the 4-voxel cells (from 0) whose sampled quads read voxel ``a``: a cell
    at a0 has quads a0 - 1 .. a0 + 3 sampled (its own and its neighbour's last), reading a0 - 1 .. a0 + 4."""
    out = set()
    for a0 in range(0, n, 4):
        if a0 - 1 <= a <= a0 + 4:
            out |= set(range(a0, min(a0 + 4, n)))
    return out


def neighbourhood(v, shape, kind, axis):
    """The voxels whose density enters voxel ``v``'s key, one by one."""
    axes = [axis] if kind in ("axis", "cells-axis") else ["k", "j", "i"]
    out = set()
    for ax in axes:
        d = AXIS_DIM[ax]
        per = []
        for e in range(3):
            if e == d:
                per.append([v[e]])
            elif kind.startswith("cells"):
                per.append(sorted(cell_window(v[e], shape[e])))
            else:
                per.append([x for x in (v[e] - 1, v[e], v[e] + 1) if 0 <= x < shape[e]])
        out |= set(itertools.product(*per))
    return out


def reference_key(density, kind, axis):
    lo = np.empty_like(density)
    hi = np.empty_like(density)
    for v in np.ndindex(density.shape):
        vals = [density[w] for w in neighbourhood(v, density.shape, kind, axis)]
        lo[v], hi[v] = min(vals), max(vals)
    return lo, hi


def reference_sampler(interest, axis):
    """The voxels today's sampler reads on ``axis``'s slices: per 4 x 4 cell holding a voxel of interest, its 16
    quads, the last column of the cell before along a, the last row of the one before along b, and the corner
    quad (isplat.splat.post._mark_cells); quad (qa, qb) reads qa, min(qa + 1, n_a - 1) by qb, min(qb + 1, n_b - 1)."""
    d = AXIS_DIM[axis]
    da, db = [e for e in range(3) if e != d]
    n_a, n_b = interest.shape[da], interest.shape[db]
    out = np.zeros_like(interest)
    for c in range(interest.shape[d]):
        def at(a, b):
            idx = [0, 0, 0]
            idx[d], idx[da], idx[db] = c, a, b
            return tuple(idx)
        for a0 in range(0, n_a, 4):
            for b0 in range(0, n_b, 4):
                cell = [(a, b) for a in range(a0, min(a0 + 4, n_a)) for b in range(b0, min(b0 + 4, n_b))]
                if not any(interest[at(a, b)] for a, b in cell):
                    continue
                for qa in range(a0 - 1, min(a0 + 4, n_a)):
                    for qb in range(b0 - 1, min(b0 + 4, n_b)):
                        if qa < 0 or qb < 0:
                            continue
                        for a in (qa, min(qa + 1, n_a - 1)):
                            for b in (qb, min(qb + 1, n_b - 1)):
                                out[at(a, b)] = True
    return out


def reference_groups(g, n_groups):
    vox = np.bincount(g.ravel(), minlength=n_groups)
    spans = np.zeros(n_groups, np.int64)
    rows = np.zeros(n_groups, np.int64)
    bricks = {}
    nk, nj, ni = g.shape
    for k in range(nk):
        for j in range(nj):
            for x in set(g[k, j].tolist()):
                rows[x] += 1
            for i in range(ni):
                if i == 0 or g[k, j, i] != g[k, j, i - 1]:
                    spans[g[k, j, i]] += 1
                bricks.setdefault(g[k, j, i], {}).setdefault((k // 8, j // 8, i // 8), []).append((k, j, i))
    adaptive = [sum(4 + min(64, 2 * len(v)) for v in bricks.get(x, {}).values()) for x in range(n_groups)]
    return dict(vox=vox, spans=spans, rows=rows, adaptive=np.array(adaptive),
                bricks=np.array([len(bricks.get(x, ())) for x in range(n_groups)]))


volumes = st.tuples(st.integers(1, 10), st.integers(1, 10), st.integers(1, 10), st.integers(0, 2 ** 32 - 1))


def _volume(v):
    nk, nj, ni, seed = v
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (nk, nj, ni)).astype(np.uint8), rng


def _intervals(rng):
    a, b = sorted(rng.integers(1, 256, 2))
    return [(int(a), int(b))] + ([(int(b) + 1, 255)] if b < 250 and rng.random() < 0.5 else [])


@settings(max_examples=30, deadline=None)
@given(volumes, st.sampled_from(["union", "axis", "cells", "cells-axis"]), st.sampled_from("kji"))
def test_range_key_equals_the_neighbourhood_reference(v, kind, axis):
    d, _ = _volume(v)
    lo, hi = range_key(d, kind, axis)
    rlo, rhi = reference_key(d, kind, axis)
    assert np.array_equal(lo, rlo) and np.array_equal(hi, rhi)


@settings(max_examples=30, deadline=None)
@given(volumes, st.sampled_from("kji"))
def test_sampler_reads_equal_the_cell_by_cell_reference(v, axis):
    d, _ = _volume(v)
    interest = d >= 200
    assert np.array_equal(sampler_reads(interest, axis), reference_sampler(interest, axis))


@settings(max_examples=40, deadline=None)
@given(volumes, st.sampled_from([1, 2, 4, 8, 16, 64, (1, 8), (4, 32), (64, 2), ("q", 64, 16), ("dp", 64, 16),
                                  ("q", 3, 5), ("dp", 32, 32), ("dp", 7, 3)]))
def test_read_sets_hold_what_post_needs(v, bins):
    """The union key's runs hold every axis's footprint; the cells key's every axis's sampler reads (bins cut by
    each key's own data too)."""
    d, rng = _volume(v)
    ivs = _intervals(rng)
    interest = np.zeros(d.shape, bool)
    for a, b in ivs:
        interest |= (d >= a) & (d <= b)
    sel = runs_meeting(ivs, bins) if not isinstance(bins[0] if isinstance(bins, tuple) else 0, str) else None
    lo, hi = range_key(d, "union")
    cut = resolve(bins, lo, hi)
    union = runs_meeting(ivs, cut)[run_of(lo, hi, cut)]
    lo, hi = range_key(d, "cells")
    cut = resolve(bins, lo, hi)
    cells = runs_meeting(ivs, cut)[run_of(lo, hi, cut)]
    for axis in "kji":
        assert not (footprint(interest, axis) & ~union).any()
        assert not (sampler_reads(interest, axis) & ~cells).any()
        lo, hi = range_key(d, "axis", axis)
        cut = resolve(bins, lo, hi)
        axis_only = runs_meeting(ivs, cut)[run_of(lo, hi, cut)]
        assert not (footprint(interest, axis) & ~axis_only).any()
    if sel is not None:
        assert np.array_equal(sel, runs_meeting(ivs, bins))


def _codes_of(first, b):
    """The codes of bin ``b`` of bins starting at ``first``."""
    return range(int(first[b]), int(first[b + 1]) if b + 1 < len(first) else 256)


def test_runs_meeting_is_the_exact_rectangle_test():
    """A run is read exactly when some (lo, hi) of its bins, lo <= hi, meets an interval."""
    cuts = [Cut(np.array([0, 3, 90, 200]), np.array([0, 1, 100, 120, 254]), ""),
            Cut(np.array([0]), np.array([0, 171]), ""), Cut(np.array([0, 52, 82]), np.array([0, 51, 81, 111]), "")]
    for bins in (1, 4, 16, (1, 8), (4, 2), (16, 4), *cuts):
        if isinstance(bins, Cut):
            lf, hf = bins.lo, bins.hi
        else:
            nl, nh = bins if isinstance(bins, tuple) else (bins, bins)
            lf, hf = np.arange(nl) * (256 // nl), np.arange(nh) * (256 // nh)
        lb, hb = run_bins(bins)
        for ivs in ([(170, 255)], [(51, 81), (111, 255)], [(3, 3)]):
            want = [any(lo <= b and hi >= a for lo in _codes_of(lf, l) for hi in _codes_of(hf, h)
                        if lo <= hi for a, b in ivs) for l, h in zip(lb, hb)]
            assert runs_meeting(ivs, bins).tolist() == want


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(0, 1000), min_size=256, max_size=256), st.integers(1, 64))
def test_equal_count_gives_n_bins(h, n):
    first = _equal_count(np.array(h), n)
    assert first[0] == 0 and len(first) == n and np.all(np.diff(first) > 0) and first[-1] <= 255


def test_equal_count_of_a_flat_histogram_is_uniform():
    for n in (1, 2, 16, 64, 256):
        assert np.diff(np.append(_equal_count(np.ones(256, np.int64), n), 256)).tolist() == [256 // n] * n


def reference_cut_cost(lo, hi, lo_first, hi_first):
    """Sum over every interval [t0, t1] (1 <= t0 <= t1 <= 255) of the voxels the cut's runs meeting it hold,
    divided by the voxels with lo <= t1 and hi >= t0 (at least 1/1000 of the volume, and 1), interval by
    interval."""
    cut = Cut(np.asarray(lo_first), np.asarray(hi_first), "")
    runs = run_of(lo, hi, cut)
    per_run = np.bincount(runs.ravel(), minlength=len(lo_first) * len(hi_first))
    total = 0.0
    for t0 in range(1, 256):
        for t1 in range(t0, 256):
            ideal = int(((lo <= t1) & (hi >= t0)).sum())
            total += per_run[runs_meeting([(t0, t1)], cut)].sum() / max(ideal, max(1.0, lo.size / 1000))
    return total


@settings(max_examples=4, deadline=None)
@given(volumes, st.integers(1, 9), st.integers(1, 9))
def test_cut_cost_equals_the_interval_by_interval_count(v, n_lo, n_hi):
    d, rng = _volume(v)
    lo, hi = range_key(d, "union")
    lf = np.unique(np.concatenate([[0], rng.integers(1, 256, n_lo - 1)]))
    hf = np.unique(np.concatenate([[0], rng.integers(1, 256, n_hi - 1)]))
    C, W = interval_weights(lo, hi)
    assert abs(cut_cost(C, W, lf, hf) - reference_cut_cost(lo, hi, lf, hf)) <= 1e-9 * max(1.0, cut_cost(C, W, lf, hf))


def test_best_bins_is_the_exhaustive_optimum():
    rng = np.random.default_rng(7)
    cost = rng.random((257, 257))
    cost[np.tril_indices(257)] = np.inf                 # a bin [a, b) needs a < b
    first = _best_bins(cost, 1)
    assert first.tolist() == [0]
    first = _best_bins(cost, 3)
    best = min((cost[0, a] + cost[a, b] + cost[b, 256], a, b) for a in range(1, 255) for b in range(a + 1, 256))
    assert first.tolist() == [0, best[1], best[2]]


@settings(max_examples=10, deadline=None)
@given(volumes, st.sampled_from([(4, 4), (8, 2), (16, 16), (64, 16)]))
def test_dp_cut_reads_no_more_than_uniform_bins(v, n):
    d, _ = _volume(v)
    lo, hi = range_key(d, "union")
    C, W = interval_weights(lo, hi)
    dp = dp_cut(lo, hi, *n)
    uniform = cut_cost(C, W, np.arange(n[0]) * 256 // n[0], np.arange(n[1]) * 256 // n[1])
    assert len(dp.lo) == n[0] and len(dp.hi) == n[1] and dp.lo[0] == 0 and dp.hi[0] == 0
    assert cut_cost(C, W, dp.lo, dp.hi) <= uniform * (1 + 1e-12)


@settings(max_examples=30, deadline=None)
@given(st.tuples(st.integers(1, 12), st.integers(1, 12), st.integers(1, 20), st.integers(0, 2 ** 32 - 1)),
       st.integers(1, 5))
def test_group_stats_equal_the_reference(v, n_groups):
    nk, nj, ni, seed = v
    g = np.random.default_rng(seed).integers(0, n_groups, (nk, nj, ni)).astype(np.int32)
    got, want = group_stats(g, n_groups), reference_groups(g, n_groups)
    for name in ("vox", "spans", "rows", "bricks", "adaptive"):
        assert got[name].tolist() == want[name].tolist(), name


@settings(max_examples=30, deadline=None)
@given(volumes, st.sampled_from([4, 16, 64, (1, 16)]))
def test_quads_reading_a_voxel_left_out_are_transparent(v, bins):
    """A voxel today's sampler reads but the union key's runs leave out is read only by quads whose corners'
    range misses every interval: their bilinear field has zero opacity, whatever the sampler does with them."""
    d, rng = _volume(v)
    ivs = _intervals(rng)
    interest = np.zeros(d.shape, bool)
    for a, b in ivs:
        interest |= (d >= a) & (d <= b)
    kept = runs_meeting(ivs, bins)[run_of(*range_key(d, "union"), bins)]
    for axis in "kji":
        da, db = [e for e in range(3) if e != AXIS_DIM[axis]]
        for v0 in np.argwhere(sampler_reads(interest, axis) & ~kept):
            for sa in (-1, 0):
                for sb in (-1, 0):
                    corners = []
                    for ea in (0, 1):
                        for eb in (0, 1):
                            w = v0.copy()
                            w[da] = min(max(v0[da] + sa + ea, 0), d.shape[da] - 1)
                            w[db] = min(max(v0[db] + sb + eb, 0), d.shape[db] - 1)
                            corners.append(int(d[tuple(w)]))
                    lo, hi = min(corners), max(corners)
                    assert not any(lo <= b and hi >= a for a, b in ivs)
