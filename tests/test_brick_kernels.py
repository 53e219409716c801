"""The brick store's compiled kernels (isplat.brickstore) against slow, obvious references written here: the one
pass that checks and places bricks (``check_place``), the brick ranges (``brick_minmax``), post's bricks of
interest (``mark_reach``) and the memory pages bricks fill (``pages_touched``)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fuzzlab import brick_hash
from isplat import brickstore


def _store(rng, grid, e, dtype):
    """A random brick store of ``grid`` bricks of ``e``^3 elements (bytes [rows, size]) and its true hashes."""
    nb = int(np.prod(grid))
    data = rng.integers(0, np.iinfo(dtype).max + 1, (nb, e, e, e)).astype(dtype)
    raw = data.view(np.uint8).reshape(nb, -1)
    return raw, data


def _reference_place(raw, dtype, e, stored, r0, rows, pick, seed, offs, ext, lo, out, want_mm):
    """check_place, element by element: each picked brick hashed from its bytes (formats/augmented.md §2.3, in
    plain Python), skipped when its hash is not the stored one, else ranged and copied voxel by voxel where it
    lies inside the volume and the block."""
    bad = -1
    mm = np.zeros((rows.shape[0] if want_mm else 0, 2), np.uint8)
    for b in pick:
        w = rows[b] - r0
        if brick_hash(raw[w].tobytes(), int(rows[b]), int(seed)) != int(stored[w]):
            bad = b if bad < 0 else min(bad, b)
            continue
        vals = raw[w].view(dtype).reshape(e, e, e)
        if want_mm:
            part = vals[:ext[b, 0], :ext[b, 1], :ext[b, 2]]
            mm[b] = part.min(), part.max()
        for z in range(ext[b, 0]):
            for y in range(ext[b, 1]):
                for x in range(ext[b, 2]):
                    at = (offs[b, 0] + z - lo[0], offs[b, 1] + y - lo[1], offs[b, 2] + x - lo[2])
                    if all(0 <= a < n for a, n in zip(at, out.shape)):
                        out[at] = vals[z, y, x]
    return bad, mm


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.sampled_from([4, 8]), st.sampled_from([np.uint8, np.uint16]),
       st.tuples(st.integers(1, 19), st.integers(1, 19), st.integers(1, 19)), st.floats(0.0, 1.0),
       st.integers(0, 3), st.integers(0, 2 ** 64 - 1))
def test_check_place_is_the_reference(seed, e, dtype, shape, share, corrupt, key):
    """Any store, bricks, block (a box of the volume), window of the store and corrupted hashes: the same block,
    ranges and first bad brick as the reference; a brick whose hash differs is never placed."""
    rng = np.random.default_rng(seed)
    grid = tuple(-(-n // e) for n in shape)
    raw, data = _store(rng, grid, e, dtype)
    rows_all = np.arange(raw.shape[0], dtype=np.int64)
    hashes = brickstore.hash_bricks(raw.view("<u8"), rows_all, np.uint64(key))
    rows = rows_all[rng.random(rows_all.size) < share]
    rng.shuffle(rows)
    r0 = int(rows.min()) if rows.size else 0
    r1 = int(rows.max()) + 1 if rows.size else 0
    stored = hashes[r0:r1].copy()
    for _ in range(corrupt if rows.size else 0):         # a changed hash: its brick must be refused
        stored[int(rng.integers(0, stored.size))] ^= np.uint64(1 << int(rng.integers(0, 64)))
    bricks = np.stack(np.unravel_index(rows, grid), axis=1).astype(np.int64)
    offs = bricks * e
    ext = np.minimum(e, np.asarray(shape, dtype=np.int64) - offs)
    lo = np.asarray([int(rng.integers(0, n)) for n in shape], dtype=np.int64)
    hi = [int(rng.integers(x + 1, n + 1)) for x, n in zip(lo, shape)]
    pick = np.argsort(rows, kind="stable")
    want_mm = dtype == np.uint8
    window = raw[r0:r1]
    got_out = np.zeros([h - l for l, h in zip(lo, hi)], dtype)
    ref_out = got_out.copy()
    got_mm = np.zeros((rows.size if want_mm else 0, 2), np.uint8)
    got = brickstore.check_place(window.view(dtype).reshape(-1, e, e, e), window.view("<u8"), stored, r0, rows, pick,
                                 np.uint64(key), offs, ext, lo, got_out, got_mm)
    ref, ref_mm = _reference_place(window, dtype, e, stored, r0, rows, pick, np.uint64(key), offs, ext, lo, ref_out,
                                   want_mm)
    assert got == ref
    assert np.array_equal(got_out, ref_out)
    assert np.array_equal(got_mm, ref_mm)
    if corrupt == 0 and rows.size:                          # every hash right: the block is the volume's bricks
        vol = np.zeros([g * e for g in grid], dtype)
        for b, (k, j, i) in enumerate(bricks):
            vol[k * e:(k + 1) * e, j * e:(j + 1) * e, i * e:(i + 1) * e] = data[rows[b]]
        assert got == -1 and np.array_equal(got_out, vol[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]])


def test_check_place_refuses_a_row_outside_its_window():
    raw = np.zeros((2, 64), np.uint8)
    out = np.zeros((4, 4, 8), np.uint8)
    got = brickstore.check_place(raw.reshape(2, 4, 4, 4), raw.view("<u8"), np.zeros(2, np.uint64), 5,
                                 np.array([7], np.int64), np.array([0], np.int64), np.uint64(0),
                                 np.zeros((1, 3), np.int64), np.full((1, 3), 4, np.int64), np.zeros(3, np.int64), out,
                                 np.zeros((0, 2), np.uint8))
    assert got == -2 and not out.any()


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.sampled_from([4, 8]), st.integers(1, 9))
def test_brick_minmax_is_the_reference(seed, e, n):
    rng = np.random.default_rng(seed)
    data = rng.integers(0, 256, (n, e, e, e)).astype(np.uint8)
    ext = rng.integers(1, e + 1, (n, 3))
    ext[rng.random(n) < 0.5] = e                            # whole bricks and cut ones
    got = brickstore.brick_minmax(data, ext)
    for r in range(n):
        part = data[r, :ext[r, 0], :ext[r, 1], :ext[r, 2]]
        assert got[r].tolist() == [int(part.min()), int(part.max())]


def _reference_reach(shape, edge, dims, c, a0, b0, back, ahead):
    """Every brick holding a voxel of each cell's reach, voxel by voxel."""
    out = np.zeros([-(-n // b) for n, b in zip(shape, edge)], bool)
    n = [shape[d] for d in dims]
    for q in range(c.size):
        for a in range(max(a0[q] - back, 0), min(a0[q] + ahead, n[1] - 1) + 1):
            for b in range(max(b0[q] - back, 0), min(b0[q] + ahead, n[2] - 1) + 1):
                at = [0, 0, 0]
                at[dims[0]], at[dims[1]], at[dims[2]] = c[q], a, b
                out[tuple(x // e for x, e in zip(at, edge))] = True
    return out


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.tuples(st.integers(1, 30), st.integers(1, 30), st.integers(1, 30)),
       st.sampled_from([4, 8]), st.sampled_from([(0, 2, 1), (1, 2, 0), (2, 1, 0)]), st.integers(0, 40),
       st.sampled_from([(3, 6), (1, 4), (0, 0)]))
def test_mark_reach_is_the_reference(seed, shape, e, dims, cells, reach):
    rng = np.random.default_rng(seed)
    n = [shape[d] for d in dims]
    c, a0, b0 = (rng.integers(0, m, cells).astype(np.int64) for m in n)
    out = np.zeros([-(-s // e) for s in shape], bool)
    step = np.asarray(out.strides, dtype=np.int64)[list(dims)]
    got = brickstore.mark_reach(out.reshape(-1), c, a0, b0, np.asarray(n, np.int64), *reach,
                                np.full(3, e, np.int64), step)
    assert got == -1
    assert np.array_equal(out, _reference_reach(shape, (e, e, e), dims, c, a0, b0, *reach))
    if cells:                                               # a cell outside the volume: refused, nothing marked
        q = int(rng.integers(0, cells))
        which = int(rng.integers(0, 3))
        (c, a0, b0)[which][q] = n[which] if rng.random() < 0.5 else -1
        out[...] = False
        assert brickstore.mark_reach(out.reshape(-1), c, a0, b0, np.asarray(n, np.int64), *reach,
                                     np.full(3, e, np.int64), step) == q


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.tuples(st.integers(1, 40), st.integers(1, 40), st.integers(1, 70)),
       st.sampled_from([4, 8]), st.sampled_from([1, 2]), st.floats(0.0, 1.0), st.sampled_from([6, 12]))
def test_pages_touched_is_the_reference(seed, shape, e, itemsize, share, shift):
    """The pages of every element the bricks cover within the block, element by element."""
    rng = np.random.default_rng(seed)
    page = 1 << shift
    grid = [-(-n // e) for n in shape]
    want = rng.random(grid) < share
    lo = [int(rng.integers(0, n)) for n in shape]
    hi = [int(rng.integers(x + 1, n + 1)) for x, n in zip(lo, shape)]
    mask = np.kron(want, np.ones((e, e, e), bool))[:shape[0], :shape[1], :shape[2]][lo[0]:hi[0], lo[1]:hi[1],
                                                                                    lo[2]:hi[2]]
    flat = np.flatnonzero(mask.reshape(-1))
    ref = np.unique(np.concatenate([flat * itemsize // page, (flat * itemsize + itemsize - 1) // page])).size
    block = np.asarray([h - l for l, h in zip(lo, hi)], np.int64)
    got = brickstore.pages_touched(np.argwhere(want).astype(np.int64), np.full(3, e, np.int64),
                                   np.asarray(lo, np.int64), block, itemsize, shift)
    assert got == ref


def test_store_windows_give_the_rows_aligned_wherever_the_store_lies(tmp_path, monkeypatch):
    """augfile._store_windows: every row asked, in windows of at most STORE_WINDOW bytes, with its stored hash, as
    8-byte-aligned arrays even when the store and its table lie at odd offsets of the file (copied then)."""
    import isplat.augfile as augfile

    rng = np.random.default_rng(5)
    size, nb = 64, 40
    for d_off, h_off in ((8, 8 + size * nb), (3, 5 + size * nb)):
        raw = rng.integers(0, 256, (nb, size)).astype(np.uint8)
        table = rng.integers(0, 2 ** 63, nb).astype("<u8")
        path = tmp_path / f"store-{d_off}.bin"
        blob = bytearray(h_off + 8 * nb)
        blob[d_off:d_off + raw.nbytes] = raw.tobytes()
        blob[h_off:h_off + table.nbytes] = table.tobytes()
        path.write_bytes(bytes(blob))
        rows = rng.permutation(nb)[:25]
        monkeypatch.setattr(augfile, "STORE_WINDOW", 3 * size)
        seen = []
        for r0, pick, data, stored in augfile._store_windows(path, d_off, h_off, size, rows):
            assert data.ctypes.data % 8 == 0 and stored.ctypes.data % 8 == 0 and data.shape[0] <= 3
            for b in pick:
                assert np.array_equal(data[rows[b] - r0], raw[rows[b]]) and stored[rows[b] - r0] == table[rows[b]]
                seen.append(int(b))
        assert sorted(seen) == list(range(rows.size))
