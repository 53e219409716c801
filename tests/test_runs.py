"""isplat.runs and the runs file (formats/runs.md): the keys, the positions' forms and the layout against slow,
obvious references; the file's round trip; the reader refuses corrupted bytes and bad tables, naming the file, the
dataset and the run; ``isplat index`` writes the file unless ``--no-runs``."""

import itertools
import re
import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.extra.numpy import arrays
import runs_reference as RR

from isplat import runs as R
from isplat.errors import IsplatError
from isplat.fileio import create_hdf5
from isplat.runsfile import open_runs, read_runs, runs_path, write_runs_arrays

from conftest import write_volume

SHA = "ab" * 32
CHECK = "cd" * 16


# ------------------------------------------------------------------------------------------------ references

def reference_key(density):
    """Per voxel, min and max over the voxels of its 3 x 3 x 3 cube (cut at the edge) that are not its corners:
    those it shares a quad with in some slice lattice."""
    lo, hi = np.empty_like(density), np.empty_like(density)
    for v in np.ndindex(density.shape):
        vals = []
        for d in itertools.product((-1, 0, 1), repeat=3):
            w = tuple(a + b for a, b in zip(v, d))
            if all(x != 0 for x in d) or any(not 0 <= x < n for x, n in zip(w, density.shape)):
                continue
            vals.append(density[w])
        lo[v], hi[v] = min(vals), max(vals)
    return lo, hi


def reference_encode(groups, version=2):
    """``groups``: a list of sorted place lists; bytes of each in turn (formats/runs.md §4), from a brick's bits
    as an array [dk, dj, di]: version 2, the planes' any() packed least significant first, then the rows' any()
    of the planes that have one, then the voxel bits of the rows that have one; version 1, <= 32 places as
    uint16 LE, else all 64 rows' bytes."""
    out = bytearray()
    for places in groups:
        if version == 1 and len(places) <= 32:
            out += b"".join(int(x).to_bytes(2, "little") for x in places)
            continue
        bits = np.zeros((8, 8, 8), dtype=np.uint8)
        p = np.asarray(places)
        bits[p // 64, p // 8 % 8, p % 8] = 1
        voxels = np.packbits(bits, axis=2, bitorder="little")[:, :, 0]          # [dk, dj]
        if version == 1:
            out += voxels.tobytes()
            continue
        rows = np.packbits(voxels != 0, axis=1, bitorder="little")[:, 0]        # [dk]
        out += np.packbits(rows != 0, bitorder="little").tobytes() + rows[rows != 0].tobytes() \
            + voxels[voxels != 0].tobytes()
    return np.frombuffer(bytes(out), dtype=np.uint8)


def reference_layout(density, cut):
    """Per run, the voxels (k, j, i) of its key's bins, by brick number then place."""
    lo, hi = reference_key(density)
    lo_bin = [max(n for n, c in enumerate(cut.lo) if c <= x) for x in range(256)]
    hi_bin = [max(n for n, c in enumerate(cut.hi) if c <= x) for x in range(256)]
    _, gj, gi = R.brick_grid(density.shape)
    per = {}
    for v in np.ndindex(density.shape):
        r = hi_bin[hi[v]] * len(cut.lo) + lo_bin[lo[v]]
        b = (v[0] // 8 * gj + v[1] // 8) * gi + v[2] // 8
        p = (v[0] % 8 * 8 + v[1] % 8) * 8 + v[2] % 8
        per.setdefault(r, []).append((b, p, v))
    return {r: sorted(x) for r, x in per.items()}


volumes = arrays(np.uint8, st.tuples(st.integers(1, 11), st.integers(1, 11), st.integers(1, 19)),
                 elements=st.sampled_from([0, 1, 40, 41, 90, 200, 255]))


def channels(density, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.integers(0, 65536, density.shape).astype(np.uint16),
            rng.integers(0, 256, density.shape).astype(np.uint8))


# ------------------------------------------------------------------------------------------------ kernels

@settings(max_examples=40, deadline=None)
@given(volumes)
def test_union_key_equals_the_reference(d):
    lo, hi = R.union_key(d)
    rlo, rhi = reference_key(d)
    assert np.array_equal(lo, rlo) and np.array_equal(hi, rhi)
    for k0, k1 in R.layers(d.shape):
        llo, lhi = R.layer_key(d, k0, k1)
        assert np.array_equal(llo, lo[k0:k1]) and np.array_equal(lhi, hi[k0:k1])


@settings(max_examples=80, deadline=None)
@given(st.lists(st.one_of(st.sets(st.integers(0, 511), min_size=1, max_size=512),
                          st.sets(st.integers(0, 511), min_size=1, max_size=12),
                          st.sets(st.sampled_from([3, 4, 70, 75, 77, 200, 511]), min_size=1)),
                min_size=1, max_size=6), st.sampled_from([1, 2]))
def test_positions_all_forms_equal_the_reference(groups, version):
    """Masks (version 2), lists and bitmaps (version 1): the reference encoding, its decoding and the compiled
    decoding (:func:`isplat.runsplace._places`), with the bytes a brick takes (:func:`_brick_bytes`)."""
    from isplat import runsplace

    groups = [sorted(g) for g in groups]
    counts = np.array([len(g) for g in groups])
    group = np.repeat(np.arange(len(groups)), counts)
    local = np.concatenate([np.array(g) for g in groups])
    enc = RR.encode_positions(group, local, counts, version=version)
    assert np.array_equal(enc, reference_encode(groups, version))
    assert np.array_equal(RR.decode_positions(counts, enc, version=version), local)
    if version == 2:
        planes, rows = ([len({p // n for p in g}) for g in groups] for n in (64, 8))
        assert R.position_bytes(planes, rows).sum() == enc.size
    q, buf, mask = 0, np.empty(520, np.int64), np.empty(8, np.uint64)
    for c, g in zip(counts.tolist(), groups):
        n = runsplace._brick_bytes(enc, q, enc.size, c, version)
        assert n == len(reference_encode([g], version))
        mask[:] = 12345
        assert runsplace._places(enc, q, c, buf, mask, version) == 0 and buf[:c].tolist() == g
        if version == 2 or c > 32:              # the places' bits, word p // 64, bit p % 64 (a list's: not made)
            bits = np.zeros(512, bool)
            bits[g] = True
            assert np.array_equal(mask, np.packbits(bits, bitorder="little").view("<u8"))
        q += n


def test_positions_refused():
    enc = reference_encode([[3, 7]], version=1)
    with pytest.raises(IsplatError, match="4 bytes of positions, the bricks' counts make more"):
        RR.decode_positions(np.array([3]), enc, version=1)
    with pytest.raises(IsplatError, match="4 bytes of positions, the bricks' counts make 2"):
        RR.decode_positions(np.array([1]), enc, version=1)
    with pytest.raises(IsplatError, match="strictly increasing"):
        RR.decode_positions(np.array([2]), reference_encode([[7, 3]], version=1), version=1)
    with pytest.raises(IsplatError, match="places below 512"):
        RR.decode_positions(np.array([1]), reference_encode([[600]], version=1), version=1)
    bm = reference_encode([list(range(40))], version=1).copy()
    bm[10] = 1
    with pytest.raises(IsplatError, match="its positions hold 41 voxels, its count says 40"):
        RR.decode_positions(np.array([40]), bm, version=1)
    masks = reference_encode([list(range(40))]).copy()     # plane 0: rows 0..4 each of 8 voxels
    assert masks.tolist() == [0x01, 0x1F] + [0xFF] * 5
    for at, byte, match in ((6, 0x7F, "its positions hold 39 voxels, its count says 40"),
                            (6, 0x00, r"row \(0, 4\) \(dk, dj\) is set in its masks but holds no voxel"),
                            (1, 0x0F, "7 bytes of positions, the bricks' masks make 6"),
                            (1, 0x3F, "7 bytes of positions, the bricks' masks make more"),
                            (0, 0x03, "7 bytes of positions, the bricks' masks make more")):
        bad = masks.copy()
        bad[at] = byte
        with pytest.raises(IsplatError, match=match):
            RR.decode_positions(np.array([40]), bad)
    with pytest.raises(IsplatError, match="plane 1 is set in its masks but holds no voxel"):
        RR.decode_positions(np.array([8]), np.array([0x03, 0x01, 0x00, 0xFF], np.uint8))
    with pytest.raises(IsplatError, match="outside the volume"):
        RR.flat_positions(np.array([0]), np.array([1]), np.array([511]), (7, 8, 8))
    with pytest.raises(IsplatError, match="beyond the 1 bricks"):
        RR.flat_positions(np.array([1]), np.array([1]), np.array([0]), (7, 8, 8))


@settings(max_examples=25, deadline=None)
@given(volumes, st.integers(1, 4), st.integers(1, 4))
def test_layout_equals_the_reference(d, n_lo, n_hi):
    lo, hi = R.union_key(d)
    cut = R.dp_cut(lo, hi, n_lo, n_hi)
    nrm, gm = channels(d)
    _, runs = R.build_runs(d, nrm, gm, cut)
    ref = reference_layout(d, cut)
    vp, bp = runs.run_voxel_ptr, runs.run_brick_ptr
    for r in range(R.n_runs(cut)):
        want = ref.get(r, [])
        assert vp[r + 1] - vp[r] == len(want)
        assert [int(x) for x in runs.density[vp[r]:vp[r + 1]]] == [int(d[v]) for _, _, v in want]
        assert [int(x) for x in runs.normal[vp[r]:vp[r + 1]]] == [int(nrm[v]) for _, _, v in want]
        assert runs.brick_number[bp[r]:bp[r + 1]].tolist() == sorted({b for b, _, _ in want})
    place = RR.decode_positions(runs.brick_voxel_count, runs.positions)
    flat = RR.flat_positions(runs.brick_number, runs.brick_voxel_count, place, d.shape)
    assert np.array_equal(RR.place(d.shape, flat, runs.gradient_magnitude), gm)


def test_best_bins_is_the_exhaustive_optimum():
    rng = np.random.default_rng(7)
    cost = rng.random((257, 257))
    cost[np.tril_indices(257)] = np.inf
    best = min((cost[0, a] + cost[a, b] + cost[b, 256], a, b) for a in range(1, 255) for b in range(a + 1, 256))
    assert R.best_bins(cost, 3).tolist() == [0, best[1], best[2]]


@settings(max_examples=15, deadline=None)
@given(volumes, st.integers(1, 12), st.integers(1, 12))
def test_dp_cut_by_layers_equals_the_whole_and_its_edges_are_valid(d, n_lo, n_hi):
    """The writer sums the keys' histogram layer by layer: the same cut as from the whole volume's keys, with
    edges the file can hold (from 0, strictly increasing, within 0..255), reading no more than uniform bins."""
    lo, hi = R.union_key(d)
    whole = R.dp_cut(lo, hi, n_lo, n_hi)
    h2 = sum(R.key_histogram(*R.layer_key(d, k0, k1)) for k0, k1 in R.layers(d.shape))
    by_layers = R.dp_cut_of(h2, n_lo, n_hi)
    assert whole.lo.tolist() == by_layers.lo.tolist() and whole.hi.tolist() == by_layers.hi.tolist()
    for e, n in ((whole.lo, n_lo), (whole.hi, n_hi)):
        assert len(e) == n and e[0] == 0 and e[-1] <= 255 and (np.diff(e) > 0).all()
    C, W = R.interval_weights(lo, hi)
    uniform = R.cut_cost(C, W, np.arange(n_lo) * 256 // n_lo, np.arange(n_hi) * 256 // n_hi)
    assert R.cut_cost(C, W, whole.lo, whole.hi) <= uniform * (1 + 1e-12)


def test_runs_meeting_is_the_rectangle_test():
    cut = R.Cut(np.array([0, 10, 100]), np.array([0, 50, 200]), "")
    got = R.runs_meeting([(60, 70)], cut)
    lo_first, hi_last = np.array([0, 10, 100] * 3), np.repeat([49, 199, 255], 3)
    assert got.tolist() == ((lo_first <= 70) & (hi_last >= 60) & (lo_first <= hi_last)).tolist()


# ------------------------------------------------------------------------------------------------ the file

def write_file(path, d, cut=None, runs=None, seed=0):
    nrm, gm = channels(d, seed)
    if runs is None:
        cut, runs = R.build_runs(d, nrm, gm, cut)
    with create_hdf5(path) as f:
        write_runs_arrays(f, d.shape, SHA, CHECK, cut, runs)
    return cut, runs, nrm, gm


@settings(max_examples=25, deadline=None)
@given(volumes, st.lists(st.tuples(st.integers(0, 255), st.integers(0, 255)).map(sorted), max_size=3))
def test_round_trip(tmp_path_factory, d, intervals):
    path = tmp_path_factory.mktemp("runs") / "v.runs.idx.h5"
    cut, _, nrm, gm = write_file(path, d)
    pos, dens, n, g, nbytes = read_runs(path, None, shape=d.shape, density_sha256=SHA,
                                        augmented_chunk_hash_check=CHECK)
    assert np.array_equal(np.sort(pos), np.arange(d.size)) and nbytes > 0
    assert np.array_equal(RR.place(d.shape, pos, dens), d)
    assert np.array_equal(RR.place(d.shape, pos, n), nrm)
    assert np.array_equal(RR.place(d.shape, pos, g), gm)
    pos, dens, n, g, _ = read_runs(path, intervals)
    lo, hi = R.union_key(d)
    meets = np.zeros(d.shape, bool)
    for t0, t1 in intervals:
        meets |= (lo <= t1) & (hi >= t0)
    assert np.isin(np.flatnonzero(meets.ravel()), pos).all()
    assert np.array_equal(dens, d.ravel()[pos]) and np.array_equal(n, nrm.ravel()[pos])


def test_tied_to_its_augmented_file(tmp_path):
    d = np.arange(60, dtype=np.uint8).reshape(3, 4, 5)
    write_file(tmp_path / "a.runs.idx.h5", d)
    for tie, what in ((dict(shape=(3, 4, 6)), "shape"), (dict(density_sha256="00" * 32), "density_sha256"),
                      (dict(augmented_chunk_hash_check="00" * 16), "augmented_chunk_hash_check")):
        with pytest.raises(IsplatError, match=f"attribute '{what}' .* the runs of another volume"):
            open_runs(tmp_path / "a.runs.idx.h5", **tie)


def _flip(path, dataset, at=0):
    with h5py.File(path, "r") as f:
        off = f[dataset].id.get_chunk_info(0).byte_offset + at
    with open(path, "r+b") as fh:
        fh.seek(off)
        b = fh.read(1)
        fh.seek(off)
        fh.write(bytes([b[0] ^ 0x5A]))


@pytest.mark.parametrize("name", ["run_voxel_ptr", "run_brick_ptr", "run_position_ptr", "brick_number",
                                  "brick_voxel_count", "positions", "density", "normal", "gradient_magnitude"])
def test_a_flipped_byte_is_refused_naming_the_dataset(tmp_path, name):
    d = np.random.default_rng(5).choice(np.array([0, 60, 61, 200], np.uint8), size=(9, 10, 11))
    path = tmp_path / "v.runs.idx.h5"
    write_file(path, d)
    _flip(path, f"runs/{name}")
    with pytest.raises(IsplatError) as exc:
        read_runs(path, None)
    msg = str(exc.value)
    assert str(path) in msg and f"runs/{name}" in msg and "\n" not in msg
    assert re.search(r"\(runs \d+\.\.\d+\)$|\(the offsets of runs \d+\.\.\d+\)$", msg), msg


def _rewrite(path, d, **change):
    """The runs of ``d`` with arrays changed, written with fresh (valid) hashes: only the structure's checks
    can refuse them."""
    nrm, gm = channels(d)
    cut, runs = R.build_runs(d, nrm, gm)
    runs = runs._replace(**{k: v(runs) for k, v in change.items()})
    with create_hdf5(path) as f:
        write_runs_arrays(f, d.shape, SHA, CHECK, cut, runs)


def _bumped(a, n, by):
    a = np.array(a)
    a[n] += by
    return a


@pytest.mark.parametrize("change, match", [
    (dict(run_voxel_ptr=lambda r: _bumped(r.run_voxel_ptr, slice(1, -1), 5)), r"'runs/run_voxel_ptr', run \d+"),
    (dict(run_voxel_ptr=lambda r: _bumped(r.run_voxel_ptr, 0, 1)), r"'runs/run_voxel_ptr', run 0: offsets 1"),
    (dict(run_brick_ptr=lambda r: r.run_brick_ptr[::-1].copy()), r"'runs/run_brick_ptr', run \d+: offsets"),
    (dict(run_position_ptr=lambda r: np.where(np.arange(r.run_position_ptr.size) == r.run_position_ptr.size // 2,
                                              -7, r.run_position_ptr)), r"'runs/run_position_ptr', run \d+"),
    (dict(brick_number=lambda r: r.brick_number[::-1].copy()), r"'runs/brick_number', run \d+: brick numbers not"),
    (dict(brick_number=lambda r: r.brick_number + 1000), r"'runs/brick_number', run \d+: brick number 10\d\d"),
    (dict(brick_voxel_count=lambda r: _bumped(r.brick_voxel_count, 0, 1)), r"'runs/brick_voxel_count', run \d+"),
    (dict(positions=lambda r: np.full_like(r.positions, 0xFF)), r"'runs/positions', run \d+"),
    (dict(density=lambda r: 255 - r.density), r"'runs/density', run \d+: a density outside"),
])
def test_bad_tables_are_refused_naming_dataset_and_run(tmp_path, change, match):
    d = np.random.default_rng(6).choice(np.array([0, 60, 61, 200], np.uint8), size=(9, 10, 11))
    path = tmp_path / "v.runs.idx.h5"
    _rewrite(path, d, **change)
    with pytest.raises(IsplatError, match=match) as exc:
        read_runs(path, None)
    assert str(path) in str(exc.value)


def test_a_voxel_in_two_runs_or_missing_is_refused(tmp_path):
    d = np.zeros((1, 1, 2), np.uint8)
    cut = R.Cut(np.array([0]), np.array([0]), "")
    one = R.Runs(np.array([0, 2]), np.array([0, 1]), np.array([0, 3]), np.array([0], np.uint32),
                 np.array([2], np.uint16), reference_encode([[0, 0]]).copy(), np.zeros(2, np.uint8),
                 np.zeros(2, np.uint16), np.zeros(2, np.uint8))      # (masks cannot hold a place twice)
    with create_hdf5(tmp_path / "a.h5") as f:
        write_runs_arrays(f, d.shape, SHA, CHECK, cut, one)
    with pytest.raises(IsplatError, match="its positions hold 1 voxels, its count says 2"):
        read_runs(tmp_path / "a.h5")
    cut2 = R.Cut(np.array([0]), np.array([0, 100]), "")
    two = R.Runs(np.array([0, 1, 2]), np.array([0, 1, 2]), np.array([0, 3, 6]), np.array([0, 0], np.uint32),
                 np.array([1, 1], np.uint16), reference_encode([[0], [0]]).copy(), np.array([0, 100], np.uint8),
                 np.zeros(2, np.uint16), np.zeros(2, np.uint8))
    with create_hdf5(tmp_path / "b.h5") as f:
        write_runs_arrays(f, d.shape, SHA, CHECK, cut2, two)
    with pytest.raises(IsplatError, match="voxel 0 \\(flat\\) lies in two runs"):
        read_runs(tmp_path / "b.h5")


@pytest.mark.parametrize("masks, match", [
    ([0x01, 0x03, 0xFF, 0x00], "brick 0 of the run: row (0, 1) (dk, dj) is set in its masks but holds no voxel"),
    ([0x01, 0x03, 0xFF, 0x7F], "brick 0 of the run: its positions hold 15 voxels, its count says 16"),
    ([0x01, 0x07, 0xFF, 0xFF], "4 bytes of positions, the bricks' masks make more"),
    ([0x01, 0x01, 0xFF, 0xFF], "4 bytes of positions, the bricks' masks make 3"),
    ([0x03, 0x03, 0xFF, 0xFF], "4 bytes of positions, the bricks' masks make more"),
])
def test_bad_masks_are_refused_by_the_compiled_reader(tmp_path, masks, match):
    """A brick of 16 voxels (rows 0 and 1 of shape (1, 2, 8)) whose masks are wrong, with valid hashes: the
    compiled placing (isplat.runsplace) refuses it, naming the dataset and the run, before it places anything."""
    good = reference_encode([list(range(16))])
    assert good.tolist() == [0x01, 0x03, 0xFF, 0xFF]
    runs = R.Runs(np.array([0, 16]), np.array([0, 1]), np.array([0, 4]), np.array([0], np.uint32),
                  np.array([16], np.uint16), np.array(masks, np.uint8), np.zeros(16, np.uint8),
                  np.zeros(16, np.uint16), np.zeros(16, np.uint8))
    with create_hdf5(tmp_path / "a.h5") as f:
        write_runs_arrays(f, (1, 2, 8), SHA, CHECK, R.Cut(np.array([0]), np.array([0]), ""), runs)
    with pytest.raises(IsplatError, match=r"a.h5: dataset 'runs/positions', run 0: " + re.escape(match)):
        read_runs(tmp_path / "a.h5")


def test_runs_tables_that_cannot_be_are_refused(tmp_path):
    """A voxel in a run whose lo bin starts above its hi bin's end; more bricks than voxels; too few position
    bytes for its bricks: refused at open, naming the table and the run."""
    cut = R.Cut(np.array([0, 128]), np.array([0, 128]), "")
    one = dict(brick_number=np.array([0], np.uint32), brick_voxel_count=np.array([1], np.uint16),
               positions=reference_encode([[0]]).copy(), density=np.array([200], np.uint8),
               normal=np.zeros(1, np.uint16), gradient_magnitude=np.zeros(1, np.uint8))
    for ptrs, match in ((([0, 0, 1, 1, 1], [0, 0, 1, 1, 1], [0, 0, 3, 3, 3]), r"'runs/run_voxel_ptr', run 1: 1 "),
                        (([0, 0, 0, 0, 1], [0, 0, 0, 0, 1], [0, 0, 0, 0, 2]), r"'runs/run_position_ptr', run 3"),
                        (([0, 0, 0, 0, 1], [0, 0, 0, 1, 1], [0, 0, 0, 3, 3]), r"'runs/run_brick_ptr', run 2")):
        runs = R.Runs(*(np.array(x) for x in ptrs), **one)
        if ptrs[2][-1] == 2:
            runs = runs._replace(positions=np.zeros(2, np.uint8))
        with create_hdf5(tmp_path / "x.h5") as f:
            write_runs_arrays(f, (1, 1, 1), SHA, CHECK, cut, runs)
        with pytest.raises(IsplatError, match=match):
            open_runs(tmp_path / "x.h5")


def test_bad_bin_edges_are_refused(tmp_path):
    d = np.arange(24, dtype=np.uint8).reshape(2, 3, 4)
    path = tmp_path / "v.runs.idx.h5"
    write_file(path, d)
    for bad in ([1, 5], [0, 5, 5], [0, 300], [0, 9, 3]):
        with h5py.File(path, "r+") as f:
            f.attrs["lo_first"] = np.asarray(bad, "<i8")
        with pytest.raises(IsplatError, match="'lo_first' .* expected 1 to 256 bin edges from 0, strictly"):
            open_runs(path)


# ------------------------------------------------------------------------------------------------ isplat index

def test_isplat_index_writes_the_runs_file_and_no_runs_leaves_it_out(tmp_path, capsys):
    from isplat.augfile import open_augmented
    from isplat.cli.main import main

    def run(*args):
        with pytest.raises(SystemExit) as exc:
            main([str(a) for a in args])
        return exc.value.code, capsys.readouterr().err

    rng = np.random.default_rng(11)
    dens = rng.choice(np.array([0, 120, 121, 200], np.uint8), size=(10, 9, 17))
    gm = rng.integers(0, 256, dens.shape).astype(np.uint8)
    nrm = rng.integers(0, 65536, dens.shape).astype(np.uint16)
    aug, _ = write_volume(tmp_path, dens, gm=gm, normal=nrm, index=False)
    out = tmp_path / "x.idx.h5"
    assert run("index", aug, "-o", out, "-q")[0] == 0
    rp = runs_path(out)
    assert rp == tmp_path / "x.runs.idx.h5" and rp.is_file()
    a = open_augmented(aug)
    pos, d, n, g, _ = read_runs(rp, None, shape=a.shape, density_sha256=a.density_sha256,
                                augmented_chunk_hash_check=a.attrs["chunk_hash_check"])
    assert np.array_equal(RR.place(dens.shape, pos, d), dens) and np.array_equal(RR.place(dens.shape, pos, n), nrm)
    assert np.array_equal(RR.place(dens.shape, pos, g), gm)
    code, err = run("index", aug, "-o", out, "-q")
    assert code != 0 and len(err.strip().splitlines()) == 1
    assert run("index", aug, "-o", out, "-q", "--force", "--no-runs")[0] == 0
    assert out.is_file() and not rp.exists()
    assert run("index", aug, "-o", tmp_path / "y.idx.h5", "-q", "--no-runs")[0] == 0
    assert not (tmp_path / "y.runs.idx.h5").exists() and (tmp_path / "y.values.idx.h5").exists()


# ------------------------------------------------------------------------------------------------ examples

EXAMPLES = Path(__file__).resolve().parents[1] / "formats" / "examples" / "runs"
NAMES = sorted(p.stem for p in EXAMPLES.glob("*.json"))
WRITTEN = [n for n in NAMES if json.loads((EXAMPLES / f"{n}.json").read_text()).get("format_version", 2) == 2]


def _example(name):
    import importlib.util

    spec = importlib.util.spec_from_file_location("runs_examples", EXAMPLES / "generate.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    return gen, json.loads((EXAMPLES / f"{name}.json").read_text())


def _flat_of(name, ex, shape):
    if "flat_positions" in ex:
        return ex["flat_positions"]
    nk, nj, ni = shape          # masks.json's rule: brick 0 (i 0..7), then brick 1 (i 8..9), each k, j, i nested
    return [i + ni * (j + nj * k) for lo, hi in ((0, 8), (8, ni)) for k in range(nk) for j in range(nj)
            for i in range(lo, hi)]


def test_examples_cover_every_form_and_the_older_version():
    assert set(WRITTEN) == {"tiny", "masks"} and set(NAMES) - set(WRITTEN) == {"v1-bitmap"}
    with h5py.File(EXAMPLES / "v1-bitmap.runs.idx.h5", "r") as f:
        assert int(f.attrs["format_version"]) == 1
    for name in WRITTEN:
        with h5py.File(EXAMPLES / f"{name}.runs.idx.h5", "r") as f:
            assert int(f.attrs["format_version"]) == 2


@pytest.mark.parametrize("name", WRITTEN)
def test_examples_writer_reproduces_the_json(name):
    gen, ex = _example(name)
    d, n, g = gen.channels(ex)
    if "lo_kji" in ex:
        lo, hi = R.union_key(d)
        assert lo.tolist() == ex["lo_kji"] and hi.tolist() == ex["hi_kji"]
    _, runs = R.build_runs(d, n, g, gen.cut(ex))
    for key in ("run_voxel_ptr", "run_brick_ptr", "run_position_ptr", "brick_number", "brick_voxel_count"):
        assert getattr(runs, key).tolist() == ex[key], key
    assert runs.positions.tobytes().hex() == ex["positions_hex"]
    flat = _flat_of(name, ex, d.shape)
    assert runs.density.tolist() == d.ravel()[flat].tolist() and runs.normal.tolist() == n.ravel()[flat].tolist()


@pytest.mark.parametrize("name", NAMES)
def test_committed_examples_read_back(name):
    from isplat.augfile import density_sha256

    gen, ex = _example(name)
    d, n, g = gen.channels(ex)
    path = EXAMPLES / f"{name}.runs.idx.h5"
    pos, dens, nrm, gm, _ = read_runs(path, None, shape=d.shape, density_sha256=density_sha256(d))
    assert pos.tolist() == _flat_of(name, ex, d.shape)
    assert np.array_equal(RR.place(d.shape, pos, dens), d) and np.array_equal(RR.place(d.shape, pos, nrm), n)
    assert np.array_equal(RR.place(d.shape, pos, gm), g)
    with h5py.File(path, "r") as f:
        assert f.attrs["lo_first"].tolist() == ex["lo_first"] and f.attrs["hi_first"].tolist() == ex["hi_first"]
        assert f["runs/positions"][...].tobytes().hex() == ex["positions_hex"]
        for key in ("run_voxel_ptr", "run_brick_ptr", "run_position_ptr", "brick_number", "brick_voxel_count"):
            assert f[f"runs/{key}"][...].tolist() == ex[key], key


@pytest.mark.parametrize("name", NAMES)
def test_committed_examples_chunk_hashes_as_the_spec_says(name):
    """formats/runs.md §2 followed by hand: the key K (formats/augmented.md §1.1's BLAKE2b over the file), then
    XXH3-128 seeded with K's first 8 bytes over path, NUL, offset and elements, per chunk of each dataset."""
    import hashlib

    import xxhash

    from isplat.runsfile import DATASETS, HASHED_ATTRS

    with h5py.File(EXAMPLES / f"{name}.runs.idx.h5", "r") as f:
        a = f.attrs
        h = hashlib.blake2b(digest_size=32, person=b"isplat-chunks")
        h.update(b"isplat chunk hashes 1\0" + bytes(a["density_sha256"]) + b"\0")
        for d in DATASETS:
            h.update(d.encode() + b"\0")
        h.update(b"\0")
        for _, attr in HASHED_ATTRS:
            v = a[attr]
            raw = bytes(v) if isinstance(v, bytes) else np.asarray(v).astype(np.asarray(v).dtype.newbyteorder("<"))\
                .tobytes()                                      # strings: fixed-length UTF-8, as stored
            h.update(f"@{attr}".encode() + b"\0" + b"\1" + len(raw).to_bytes(8, "little") + raw)
        key = h.digest()
        seed = int.from_bytes(key[:8], "little")
        for d in DATASETS:
            ds, table = f[d], f["chunk_hashes/" + d.replace("/", ".")][...]
            c = ds.chunks[0]
            data = ds[...].astype(ds.dtype.newbyteorder("<"))
            for r in range(table.shape[0]):
                piece = data[r * c:(r + 1) * c].tobytes()
                want = xxhash.xxh3_128(d.encode() + b"\0" + (r * c).to_bytes(8, "little") + piece, seed=seed).digest()
                assert bytes(table[r]) == want, (d, r)


def test_invalid_example_is_refused():
    path = EXAMPLES / "invalid-flipped-byte.runs.idx.h5"
    with pytest.raises(IsplatError, match=r"invalid-flipped-byte.runs.idx.h5: dataset 'runs/density', chunk at \(0\)"
                                          r".* \(runs 0..0\)"):
        read_runs(path, None)


def reference_layer_runs(run: np.ndarray, k0: int, shape, density: np.ndarray, normal: np.ndarray,
               gradient_magnitude: np.ndarray, n_run: int) -> R.Runs:
    """isplat.runs.layer_runs the slow, obvious way: a stable sort of the layer's voxels by (run, brick, place)."""
    nl, nj, ni = run.shape
    _, gj, gi = R.brick_grid(shape)
    k, j, i = (np.arange(n, dtype=np.int64) for n in run.shape)
    # (brick in the layer) * 512 + place, built from its three axes' parts (one int64 array of the layer)
    within = ((k % R.BRICK) * R.BRICK * R.BRICK)[:, None, None] + \
        ((j // R.BRICK) * gi * R.BRICK_VOXELS + (j % R.BRICK) * R.BRICK)[None, :, None] + \
        ((i // R.BRICK) * R.BRICK_VOXELS + i % R.BRICK)[None, None, :]
    order = np.argsort((run.astype(np.int64) * (gj * gi * R.BRICK_VOXELS) + within).ravel(), kind="stable")
    w = within.ravel()[order]
    del within
    r = run.ravel()[order]
    b, p = (k0 // R.BRICK) * gj * gi + w // R.BRICK_VOXELS, w % R.BRICK_VOXELS
    new = np.ones(r.size, dtype=bool)
    new[1:] = (r[1:] != r[:-1]) | (b[1:] != b[:-1])
    group = np.cumsum(new) - 1
    firsts = np.flatnonzero(new)
    counts = np.diff(np.append(firsts, r.size))
    pos = RR.encode_positions(group, p, counts)
    vptr = R._ptr(np.bincount(r, minlength=n_run))
    bptr = R._ptr(np.bincount(r[firsts], minlength=n_run))
    planes, rows = (np.array([len(np.unique(p[at:at + c] // n)) for at, c in zip(firsts, counts)]) for n in (64, 8))
    pptr = R._ptr(np.bincount(r[firsts], weights=R.position_bytes(planes, rows), minlength=n_run).astype(np.int64))
    return R.Runs(vptr, bptr, pptr, b[firsts].astype(np.uint32), counts.astype(np.uint16), pos,
                density.ravel()[order], normal.ravel()[order], gradient_magnitude.ravel()[order])


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 8), st.integers(1, 20), st.integers(1, 20), st.integers(1, 6), st.floats(0, 1),
       st.integers(0, 10 ** 6))
def test_layer_runs_equal_the_sorting_reference(nl, nj, ni, n_run, share, seed):
    """The counting sort against the stable sort, field by field, on layers of any shape (edge bricks cut),
    a brick's voxels of a run few or most (a run holding most of a brick)."""
    rng = np.random.default_rng(seed)
    run = np.where(rng.random((nl, nj, ni)) < share, 0, rng.integers(0, n_run, (nl, nj, ni))).astype(np.int32)
    d, g = (rng.integers(0, 256, run.shape).astype(np.uint8) for _ in range(2))
    nrm = rng.integers(0, 65536, run.shape).astype(np.uint16)
    shape = (8 + nl, nj, ni)                        # the layer is the volume's second (brick numbers offset)
    got = R.layer_runs(run, 8, shape, d, nrm, g, n_run)
    want = reference_layer_runs(run, 8, shape, d, nrm, g, n_run)
    for name, a, b in zip(R.Runs._fields, got, want):
        assert np.array_equal(a, b) and a.dtype == b.dtype, name
