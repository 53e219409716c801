"""A packed pool (isplat.runsplace.pack_rows, as isplat.runsfile.RunsFile.place packs the runs' rows): rows that
share places, checked place by place; the pool read back through its packing (selection._unpool, _PoolVolume,
WholeChannels.value_deltas) equal to the rows' layout."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from isplat import grid
from isplat.runsplace import BRICK_VOXELS, pack_rows, unpool
from isplat.selection import WholeChannels, _PoolVolume, _unpool, _unpooled
from isplat.splat.post import held_quads


def random_loaded(seed: int, rows: int, kind: str) -> np.ndarray:
    """uint64 words, 8 a row, row 0 none: each row's loaded places, full, empty, a shell-like band of layers or
    random at a random density."""
    rng = np.random.default_rng(seed)
    bits = np.zeros((rows, BRICK_VOXELS), bool)
    for r in range(1, rows):
        form = kind if kind != "mixed" else rng.choice(["full", "empty", "band", "random", "sparse"])
        if form == "full":
            bits[r] = True
        elif form == "band":
            lo = rng.integers(0, 8)
            bits[r, 64 * lo:64 * rng.integers(lo + 1, 9)] = True
        elif form == "random":
            bits[r] = rng.random(BRICK_VOXELS) < rng.random()
        elif form == "sparse":
            bits[r, rng.integers(0, BRICK_VOXELS, rng.integers(1, 4))] = True
    return np.packbits(bits.reshape(-1), bitorder="little").view("<u8")


def reference_places(loaded, bases):
    """Every loaded voxel's packed place, row by row (a slow, obvious decoding of the bits)."""
    bits = np.unpackbits(loaded.view(np.uint8), bitorder="little").reshape(-1, BRICK_VOXELS)
    return {(r, int(p)): int(bases[r]) + int(p) for r in range(bits.shape[0]) for p in np.flatnonzero(bits[r])}


def packed_channel(rows, loaded, bases, places):
    """A channel of rows (512 places a row) packed the slow way: each loaded voxel at its row's base plus its
    place, zeros elsewhere (what the runs' placing writes)."""
    out = np.zeros(places, rows.dtype)
    for (r, p), q in reference_places(loaded, bases).items():
        out[q] = rows[r * BRICK_VOXELS + p]
    return out


kinds = st.sampled_from(["mixed", "full", "band", "random", "sparse", "empty"])


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2 ** 20), rows=st.integers(1, 40), kind=kinds, window=st.sampled_from([0, 1, 8, 256]))
def test_packed_rows_share_no_loaded_place(seed, rows, kind, window):
    loaded = random_loaded(seed, rows, kind)
    bases, places = pack_rows(loaded, window)
    assert bases.shape == (rows,) and bases[0] == 0
    assert np.all(bases % 64 == 0) and np.all(bases >= 0)
    assert np.all(bases + BRICK_VOXELS <= places) and places >= BRICK_VOXELS
    got = reference_places(loaded, bases)
    assert len(set(got.values())) == len(got)                   # no place holds two rows' voxels
    assert np.all(bases[1:] <= (np.arange(1, rows) - 1) * BRICK_VOXELS)     # (so pack_channel moves rows down)
    # no larger than the rows laid one after the other (row 0 holds nothing: not counted)
    assert places <= max(BRICK_VOXELS, (rows - 1) * BRICK_VOXELS)


def test_full_rows_are_not_shared_and_sparse_rows_fill_the_gaps():
    """Rows of one layer each at each of the eight layers pack into one row's places; full rows into a row each."""
    bits = np.zeros((9, BRICK_VOXELS), bool)
    for r in range(1, 9):
        bits[r, 64 * (r - 1):64 * r] = True
    loaded = np.packbits(bits.reshape(-1), bitorder="little").view("<u8")
    assert pack_rows(loaded)[1] == BRICK_VOXELS
    full = np.full(8 * 4, np.uint64(2 ** 64 - 1))
    full[:8] = 0
    bases, places = pack_rows(full)
    assert places == 3 * BRICK_VOXELS and list(bases) == [0, 0, 512, 1024]


def test_bits_not_in_rows_of_eight_words_are_refused():
    loaded = random_loaded(1, 4, "random")
    with pytest.raises(ValueError):
        pack_rows(loaded[:5])
    with pytest.raises(ValueError):
        pack_rows(loaded.view(np.int64))


def packed_pool(shape, seed):
    """A pool of random bricks of ``shape``'s grid with random loaded voxels (zeros elsewhere), as rows and as
    the same rows packed: (rows' channel, table, loaded bits, packed WholeChannels)."""
    rng = np.random.default_rng(seed)
    e = grid.POOL_EDGE
    g = [-(-n // e) for n in shape]
    used = rng.random(int(np.prod(g))) < 0.6
    table = np.zeros(used.size, np.uint32)
    table[used] = np.arange(1, int(used.sum()) + 1)
    n = int(used.sum()) + 1
    loaded = random_loaded(seed, n, "mixed")
    bits = np.unpackbits(loaded.view(np.uint8), bitorder="little").astype(bool)
    rows = np.where(bits, rng.integers(1, 256, n * e ** 3), 0).astype(np.uint8)
    bases, places = pack_rows(loaded)
    packed = packed_channel(rows, loaded, bases, places)
    w = WholeChannels(packed, packed[:0], packed[:0].view(np.uint16), table=table, shape=tuple(shape), bases=bases,
                      loaded=loaded)
    return rows, table, loaded, w


@settings(max_examples=40, deadline=None)
@given(shape=st.tuples(*(st.integers(1, 21) for _ in range(3))), seed=st.integers(0, 2 ** 16), data=st.data())
def test_a_packed_pool_reads_back_as_its_rows(shape, seed, data):
    rows, table, loaded, w = packed_pool(shape, seed)
    whole = _unpool(rows, table, shape).reshape(shape)
    assert np.array_equal(w.flat()[0].reshape(shape), whole)
    box = [tuple(sorted(data.draw(st.tuples(st.integers(0, n), st.integers(0, n))))) for n in shape]
    v = _PoolVolume(w.density, table, shape, box, (w.bases, w.loaded))
    assert np.array_equal(v[0:v.shape[0]], whole[tuple(slice(a, b) for a, b in box)])


@settings(max_examples=30, deadline=None)
@given(shape=st.tuples(*(st.integers(1, 21) for _ in range(3))), seed=st.integers(0, 2 ** 16))
def test_the_value_deltas_find_every_loaded_voxel(shape, seed):
    """The sampler's place of a voxel (flat brick-major index plus its brick's value delta, modulo 2^64) holds
    its value wherever it is loaded; the rows' layout (``deltas``) is the held bits'."""
    rows, table, loaded, w = packed_pool(shape, seed)
    flat = np.arange(table.size * BRICK_VOXELS, dtype=np.uint64)
    brick = (flat >> np.uint64(grid.POOL_SHIFT)).astype(np.int64)
    row_place = (flat + w.deltas()[brick]).astype(np.int64)
    assert np.array_equal(row_place, table[brick].astype(np.int64) * BRICK_VOXELS + (flat % 512).astype(np.int64))
    bits = np.unpackbits(loaded.view(np.uint8), bitorder="little").astype(bool)
    held = bits[row_place]
    place = (flat + w.value_deltas()[brick]).astype(np.int64)
    assert np.all((place >= 0) & (place < w.density.size))
    assert np.array_equal(w.density[place[held]], rows[row_place[held]])


@settings(max_examples=40, deadline=None)
@given(shape=st.tuples(*(st.integers(1, 21) for _ in range(3))), seed=st.integers(0, 2 ** 16))
def test_a_pool_placed_whole_shape_holds_its_rows_loaded_voxels(shape, seed):
    """isplat.runsplace.unpool (selection._unpooled): a packed pool, and the same rows laid one after the other
    with every place loaded, placed whole-shape equal numpy's unpooling (selection._unpool) of the rows; the
    bits of the voxels held are the rows' loaded bits in the whole-shape layout."""
    rows, table, loaded, w = packed_pool(shape, seed)
    want = _unpool(rows, table, shape)
    outs, words = unpool(table, w.bases, loaded, shape, w.arrays())
    assert np.array_equal(outs[0], want) and outs[1].size == outs[2].size == 0
    held = _unpool(np.unpackbits(loaded.view(np.uint8), bitorder="little"), table, shape)
    n = int(np.prod(shape))
    assert np.array_equal(np.unpackbits(words.view(np.uint8), bitorder="little")[:n], held)
    assert not np.unpackbits(words.view(np.uint8), bitorder="little")[n:].any()
    laid = WholeChannels(rows, rows[:0], rows[:0].view(np.uint16), table=table, shape=tuple(shape))
    flat, bits = _unpooled(laid, ("i", "k"))
    assert not flat.pooled and np.array_equal(flat.density, want) and sorted(bits) == ["i", "k"]
    read = np.ones(rows.size, np.uint8)
    read[:BRICK_VOXELS] = 0                         # row 0: the bricks not read
    assert np.array_equal(bits["k"], held_quads(_unpool(read, table, shape), shape, "k"))


def test_a_pool_whose_tables_disagree_is_refused():
    rows, table, loaded, w = packed_pool((9, 10, 11), 3)
    with pytest.raises(ValueError, match="does not fit"):
        unpool(table, w.bases, loaded[:-8], (9, 10, 11), w.arrays())        # a row's bits missing
    with pytest.raises(ValueError, match="does not fit"):
        unpool(table[:-1], w.bases, loaded, (9, 10, 11), w.arrays())        # a brick missing
    with pytest.raises(ValueError, match="does not fit"):
        unpool(table, w.bases, loaded, (9, 10, 11), [w.density[:100], *w.arrays()[1:]])   # rows beyond the pool
