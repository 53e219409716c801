"""benchmarks.bricks: the brick counts and the packed in-memory prototype hold every voxel post's quads read."""

import numpy as np
from hypothesis import given, settings, strategies as st

from benchmarks.bricks import SHAPES, apron, count, lookup, pack_bricks, touched
from isplat.stats import interest_mask, quad_footprint_per_slice


@settings(max_examples=30, deadline=None)
@given(st.tuples(st.integers(1, 20), st.integers(1, 20), st.integers(1, 20)), st.integers(0, 2 ** 32 - 1),
       st.sampled_from(list(SHAPES.values())))
def test_packed_bricks_hold_the_apron_of_every_voxel_of_interest(shape, seed, brick):
    rng = np.random.default_rng(seed)
    d = np.where(rng.random(shape) < 0.05, 200, rng.integers(0, 150, shape)).astype(np.uint8)
    ivs = [(180, 255)]
    grown = apron(interest_mask(ivs)[d])
    # the apron holds every voxel post's quads read, for a view along any axis
    for axis in "ijk":
        assert int(quad_footprint_per_slice(d, ivs, axis).sum()) <= int(grown.sum())
    table, packed = pack_bricks({"density": d}, touched(grown, brick), brick)
    for k, j, i in np.argwhere(grown):
        assert lookup(table, packed["density"], brick, k, j, i) == d[k, j, i]
    # the counted bytes: the bricks packed, 4 B per voxel and 12 B of checksums each
    name = next(n for n, s in SHAPES.items() if s == brick)
    c = count(d, ivs, "k")["shapes"][name]
    assert c["post_bricks"] == packed["density"].shape[0]
    assert c["post_read"] == c["post_bricks"] * (int(np.prod(brick)) * 4 + 12)
