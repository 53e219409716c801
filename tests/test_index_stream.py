"""``isplat index`` streams (isplat.index.store.build_index_file): the density is read in k-slabs and each axis's
bytes and the values are written in windows of a bounded budget, and the file holds exactly the datasets and
attributes of the in-memory build (``write_index(build_index(...), values=order_values(...))``), whatever the
budget, the slab size, the axes and the density ranges."""

import tempfile
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import fuzzlab
from isplat.augfile import density_sha256, open_augmented, write_augmented
from isplat.index import build_index, build_index_file, write_index
from isplat.index import codec, store
from isplat.index.build import order_values

SETTINGS = settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
SPACING, GSCALE = (1.0, 2.0, 0.5), 0.25


def contents(path) -> dict:
    """Every object of an HDF5 file: attributes, and for datasets dtype, shape, chunks, filters and values."""
    out = {}

    def attrs(obj):
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in obj.attrs.items() if k != "created_by"}

    with h5py.File(path, "r") as f:
        out["/"] = attrs(f)

        def visit(name, obj):
            entry = {"attrs": attrs(obj)}
            if isinstance(obj, h5py.Dataset):
                entry.update(dtype=obj.dtype.str, shape=obj.shape, chunks=obj.chunks, fletcher32=obj.fletcher32,
                             maxshape=obj.maxshape, data=obj[...].tobytes())
            out[name] = entry
        f.visititems(visit)
    return out


def in_memory_file(path, dens, gm, nrm, axes, ranges):
    write_index(path, build_index(dens, axes, ranges), dens.shape, density_sha256(dens), ranges,
                values=order_values(dens, gm, nrm, ranges, SPACING, GSCALE))


@st.composite
def volumes(draw):
    shape = draw(st.one_of(st.tuples(st.integers(1, 7), st.integers(1, 6), st.integers(1, 7)),
                           st.sampled_from([(3, 2, 300), (2, 260, 3), (1, 1, 600), (4, 3, 257)])))
    r = np.random.default_rng(draw(st.integers(0, 2**31)))
    kind = draw(st.sampled_from(["few", "sparse", "any"]))
    n = int(np.prod(shape))
    if kind == "few":
        levels = np.array(sorted(set(draw(st.lists(st.integers(0, 255), min_size=1, max_size=5)))), np.uint8)
        dens = r.choice(levels, size=n)
    elif kind == "sparse":      # long gaps: escapes
        dens = np.where(r.random(n) < 0.03, r.integers(1, 256, n), 0)
    else:
        dens = r.integers(0, 256, n)
    dens = dens.astype(np.uint8).reshape(shape)
    return dens, r.integers(0, 256, shape, dtype=np.uint8), r.integers(0, 65536, shape, dtype=np.uint16)


ranges_st = st.one_of(st.none(), st.lists(st.tuples(st.integers(0, 255), st.integers(0, 255))
                                          .map(lambda t: (min(t), max(t))), min_size=1, max_size=3))


@SETTINGS
@given(volumes(), ranges_st, st.sampled_from(["ijk", "k", "ij", "i", "jk"]), st.integers(1, 400),
       st.integers(1, 80))
def test_streamed_file_equals_the_in_memory_build(vol, ranges, axes, budget, slab_voxels):
    dens, gm, nrm = vol
    with tempfile.TemporaryDirectory() as t:
        t = Path(t)
        write_augmented(t / "a.h5", dens, gm, nrm, SPACING, (0.0, 255.0), GSCALE)
        build_index_file(t / "a.h5", t / "streamed.h5", axes=axes, ranges=ranges, budget=budget,
                         slab_voxels=slab_voxels)
        in_memory_file(t / "memory.h5", dens, gm, nrm, axes, ranges)
        for streamed, memory in ((t / "streamed.h5", t / "memory.h5"),       # the index, and its values file
                                 (t / "streamed.h5.values.idx.h5", t / "memory.h5.values.idx.h5")):
            got, want = contents(streamed), contents(memory)
            assert got.keys() == want.keys()
            for name in want:
                assert got[name] == want[name], name
        assert "values/normal" in contents(t / "streamed.h5.values.idx.h5")


@pytest.mark.parametrize("version", [4, 6])
def test_working_arrays_stay_within_the_budget(tmp_path, monkeypatch, version):
    """Spy on the kernels: every slab handed over is a few k-planes (from a bricked file, format 6, whole layers of
    bricks, which it reads whole), every window of bytes at most the budget, every window of values at most a third
    of it (3 bytes a row), and many windows are needed."""
    r = np.random.default_rng(7)
    shape = (24, 20, 18)
    dens = r.choice(np.array([0, 40, 41, 200, 255], np.uint8), size=shape)
    gm = r.integers(0, 256, shape, dtype=np.uint8)
    nrm = r.integers(0, 65536, shape, dtype=np.uint16)
    write_augmented(tmp_path / "a.h5", dens, gm, nrm, SPACING, (0.0, 255.0), GSCALE, version=version)
    aug = open_augmented(tmp_path / "a.h5")
    slab = 3 if version == 4 else 8                    # 3 planes asked for; a layer of 8^3 bricks in format 6
    assert aug.bricked == (version == 6)
    seen = {"planes": [], "window": [], "values": []}
    enc, scat = codec.encode_slab, codec.scatter_values

    def encode_spy(planes, k0, coef, indexed, n_a, ew, prev, cursor, out, o0):
        seen["planes"].append(planes.shape[0])
        seen["window"].append(out.size)
        return enc(planes, k0, coef, indexed, n_a, ew, prev, cursor, out, o0)

    def scatter_spy(d, g, n, indexed, cursor, r0, r1, gm_out, nrm_out):
        seen["values"].append(gm_out.nbytes + nrm_out.nbytes)
        seen["planes"].append(d.size // (shape[1] * shape[2]))
        return scat(d, g, n, indexed, cursor, r0, r1, gm_out, nrm_out)

    monkeypatch.setattr(codec, "encode_slab", encode_spy)
    monkeypatch.setattr(codec, "scatter_values", scatter_spy)
    budget, plane = 999, shape[1] * shape[2]
    build_index_file(tmp_path / "a.h5", tmp_path / "s.h5", budget=budget, slab_voxels=3 * plane)
    assert max(seen["planes"]) == slab and max(seen["window"]) <= budget and max(seen["values"]) <= budget
    assert len(set(seen["window"])) > 1                                         # several windows of bytes
    slabs = store._slabs_of(aug, 3 * plane)
    assert len(slabs) == -(-shape[0] // slab) and len(seen["values"]) > len(slabs)   # values: passes over slabs
    in_memory_file(tmp_path / "m.h5", dens, gm, nrm, "ijk", None)
    assert contents(tmp_path / "s.h5") == contents(tmp_path / "m.h5")


def test_along_k_a_window_reads_only_the_planes_of_its_blocks(tmp_path, monkeypatch):
    """Axis k: a block lies in one k-plane, so a window of its bytes reads the planes of its blocks only."""
    dens = np.zeros((16, 8, 8), np.uint8)
    dens[:, :4] = 100
    write_augmented(tmp_path / "a.h5", dens, np.zeros_like(dens), np.zeros(dens.shape, np.uint16), SPACING,
                    (0.0, 255.0), GSCALE)
    calls = []
    enc = codec.encode_slab

    def spy(planes, k0, *rest):
        calls.append(k0)
        return enc(planes, k0, *rest)
    monkeypatch.setattr(codec, "encode_slab", spy)
    build_index_file(tmp_path / "a.h5", tmp_path / "s.h5", axes="k", values=False, budget=40, slab_voxels=64)
    # 16 planes, 1 byte per voxel (offsets of 1) + 1 escape-free start: 32 + 32 bytes per plane, 40-byte windows
    assert len(calls) < 2 * 16 * 2
    in_memory = tmp_path / "m.h5"
    write_index(in_memory, build_index(dens, "k"), dens.shape, density_sha256(dens))
    assert contents(tmp_path / "s.h5") == contents(in_memory)


# ---------------------------------------------------------------------------------- loading a slab's blocks

@SETTINGS
@given(volumes(), ranges_st, st.data())
def test_a_slab_load_is_the_whole_load_cut_to_its_slices(vol, ranges, data):
    """load_axis(..., slices=) decodes exactly the blocks of those slices (the whole load restricted to them,
    isplat.slabs.restrict_loaded), reads no more than the whole load, and less when it skips blocks."""
    from isplat.index import normalize_ranges, open_index
    from isplat.slabs import restrict_loaded

    dens = vol[0]
    norm = normalize_ranges(ranges)
    with tempfile.TemporaryDirectory() as t:
        path = Path(t) / "v.idx.h5"
        write_index(path, build_index(dens, "ijk", ranges), dens.shape, "0" * 64, ranges)
        idx = open_index(path)
        lo, hi = data.draw(st.sampled_from(norm))
        a = data.draw(st.integers(lo, hi))
        ivs = [(a, data.draw(st.integers(a, hi)))]
        for axis in "ijk":
            n = idx.n_slices(axis)
            slices = data.draw(st.lists(st.integers(0, n - 1), max_size=n + 2))
            whole = idx.load_axis(axis, ivs)
            want = restrict_loaded(whole, slices)
            for verify in (False, True):
                got = idx.load_axis(axis, ivs, verify_offsets=verify, slices=slices)
                for key in ("slice_block_ptr", "block_density", "block_voxel_ptr", "positions"):
                    x, y = getattr(got, key), getattr(want, key)
                    assert x.dtype == y.dtype and np.array_equal(x, y), (axis, key)
                if not verify:      # at most two end offsets per run of rows, as per interval
                    assert got.bytes_read <= whole.bytes_read + 16 * got.n_blocks


def test_a_slab_load_reads_its_own_blocks(tmp_path):
    """One slice of 40 along each axis reads a small part of what the whole load reads."""
    from isplat.index import open_index

    dens = np.random.default_rng(5).choice(np.array([0, 90, 91, 200], np.uint8), size=(40, 40, 40))
    path = tmp_path / "v.idx.h5"
    write_index(path, build_index(dens, "ijk"), dens.shape, "0" * 64)
    idx = open_index(path)
    for axis in "ijk":
        whole = idx.load_axis(axis, [(80, 220)])
        one = idx.load_axis(axis, [(80, 220)], slices=range(17, 18))
        assert one.n_voxels == whole.slice_positions(17).size > 0
        assert one.bytes_read < whole.bytes_read / 10


def test_a_slab_load_checks_the_slices_it_searches(tmp_path):
    """entry_slice is checked (below n_slices, increasing per density) before a slab's rows are picked from it,
    and a slab outside the axis is refused, each with one line naming the file."""
    import pytest

    from isplat.errors import IsplatError
    from isplat.index import open_index

    dens = np.arange(4 * 5 * 6, dtype=np.uint8).reshape(4, 5, 6) % 7
    path = tmp_path / "v.idx.h5"
    write_index(path, build_index(dens, "k"), dens.shape, "0" * 64)
    with pytest.raises(IsplatError, match="outside 0..3"):
        open_index(path).load_axis("k", [(0, 6)], slices=[2, 4])
    for bad, msg in ((lambda s: s[::-1].copy(), "not increasing"), (lambda s: s + 9, "not below n_slices")):
        p = tmp_path / f"bad{msg[:7].replace(' ', '')}.idx.h5"
        write_index(p, build_index(dens, "k"), dens.shape, "0" * 64)
        with h5py.File(p, "r+") as f:
            ds = f["axes/k/entry_slice"]
            n = int(f["axes/k/density_entry_ptr"][1])          # density 0's rows
            ds[:n] = bad(ds[:n])
        fuzzlab.rehash(p)         # an editor who recomputes the chunk hashes: the checks behind them
        with pytest.raises(IsplatError, match=f"{p}: axis k, density 0, slice .*{msg}"):
            open_index(p).load_axis("k", [(0, 6)], slices=[1, 2])
