"""selection._PoolVolume: a pool's channel read as a [k, j, i] volume a few planes at a time (post's footprint
count at any size), against the whole volume unpooled at once (selection._unpool)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from isplat import grid
from isplat.selection import _PoolVolume, _unpool
from isplat.stats import quad_footprint_per_slice


def _pool(shape, seed, share):
    """A pool of random bricks of ``shape``'s grid (about ``share`` of them read) and its table."""
    rng = np.random.default_rng(seed)
    e = grid.POOL_EDGE
    g = [-(-n // e) for n in shape]
    used = rng.random(int(np.prod(g))) < share
    table = np.zeros(used.size, np.uint32)
    table[used] = np.arange(1, int(used.sum()) + 1)
    pool = rng.integers(0, 256, (int(used.sum()) + 1) * e ** 3).astype(np.uint8)
    pool[:e ** 3] = 0                       # row 0: zeros
    return pool, table


shapes = st.tuples(*(st.integers(1, 21) for _ in range(3)))


@settings(max_examples=60, deadline=None)
@given(shape=shapes, seed=st.integers(0, 2 ** 16), share=st.sampled_from([0.0, 0.4, 1.0]), data=st.data())
def test_pool_volume_reads_what_the_unpooled_volume_holds(shape, seed, share, data):
    pool, table = _pool(shape, seed, share)
    whole = _unpool(pool, table, shape).reshape(shape)
    box = [tuple(sorted(data.draw(st.tuples(st.integers(0, n), st.integers(0, n))))) for n in shape]
    v = _PoolVolume(pool, table, shape, box)
    cut = whole[tuple(slice(a, b) for a, b in box)]
    assert v.shape == cut.shape
    k0, k1 = sorted(data.draw(st.tuples(st.integers(0, v.shape[0]), st.integers(0, v.shape[0]))))
    assert np.array_equal(v[k0:k1], cut[k0:k1])


@settings(max_examples=25, deadline=None)
@given(shape=st.tuples(st.integers(1, 40), st.integers(1, 12), st.integers(1, 12)), seed=st.integers(0, 2 ** 16),
       axis=st.sampled_from("ijk"))
def test_footprint_through_a_pool_volume_equals_the_whole_volume(shape, seed, axis):
    """Across the count's k-slabs (isplat.stats.FOOTPRINT_SLAB, with their halo) too: shapes up to 40 planes."""
    pool, table = _pool(shape, seed, 0.6)
    whole = _unpool(pool, table, shape).reshape(shape)
    ivs = [(100, 180), (230, 255)]
    v = _PoolVolume(pool, table, shape, [(0, n) for n in shape])
    assert np.array_equal(quad_footprint_per_slice(v, ivs, axis), quad_footprint_per_slice(whole, ivs, axis))
