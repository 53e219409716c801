"""The channel values in the index (format version 3, formats/index.md §9): the values a selection reads equal
the position-ordered channels at the selected voxels, for random volumes, density ranges and intervals; the
bytes HDF5 reads for them (counted at the file object) stay within the stated bound; old and mismatched files."""

import tempfile
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import fuzzlab
from conftest import write_volume
from isplat import fileio
from isplat.augfile import density_sha256, write_augmented
from isplat.errors import IsplatError
from isplat.index import build_index, build_index_file, open_index, write_index
from isplat.index import store
from isplat.index.build import order_values
from isplat.selection import gather_channels, gather_from_index, select_from_files, value_order

SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def reference_order(density, ranges):
    """Flat positions of the indexed voxels by density, then position: a plain lexsort."""
    d = density.ravel()
    inside = np.zeros(256, bool)
    for lo, hi in ranges:
        inside[lo:hi + 1] = True
    flat = np.flatnonzero(inside[d])
    return flat[np.lexsort((flat, d[flat]))]


def positions_to_flat(la, shape):
    """Flat [k, j, i] index of each loaded voxel, from its slice and in-slice position (no shared code)."""
    out = np.empty(la.n_voxels, np.int64)
    n_k, n_j, n_i = shape
    for s in range(la.n_slices):
        r0, r1 = la.slice_block_ptr[s], la.slice_block_ptr[s + 1]
        v0, v1 = la.block_voxel_ptr[r0], la.block_voxel_ptr[r1]
        a, b = la.positions[v0:v1] % la.n_a, la.positions[v0:v1] // la.n_a
        k, j, i = {"k": (s, b, a), "j": (b, s, a), "i": (b, a, s)}[la.axis]
        out[v0:v1] = (np.asarray(k) * n_j + j) * n_i + i
    return out


@st.composite
def volumes(draw):
    shape = tuple(draw(st.integers(1, 7)) for _ in range(3))
    seed = draw(st.integers(0, 2**31))
    levels = np.array(sorted(set(draw(st.lists(st.integers(0, 255), min_size=1, max_size=6)))), np.uint8)
    r = np.random.default_rng(seed)
    dens = r.choice(levels, size=shape)
    gm = r.integers(0, 256, shape, dtype=np.uint8)
    nrm = r.integers(0, 65536, shape, dtype=np.uint16)
    lo = draw(st.integers(0, 255))
    ranges = [(lo, draw(st.integers(lo, 255)))]
    if draw(st.booleans()):
        ranges = [(0, 255)]
    a = draw(st.integers(ranges[0][0], ranges[0][1]))
    b = draw(st.integers(a, ranges[0][1]))
    return dens, gm, nrm, ranges, [(a, b)]


@SETTINGS
@given(volumes(), st.integers(1, 40), st.integers(1, 60), st.booleans())
def test_values_read_equal_the_channels_at_the_loaded_voxels(v, budget, slab_voxels, inside):
    """The writer (in windows of ``budget`` bytes, k-slabs of about ``slab_voxels``), the reader and the
    per-axis reordering against lexsort and plain indexing of the position-ordered channels; the slab gathering
    agrees. ``inside``: the values in the index (``/values`` of version 4), else in its values file (version 6)."""
    dens, gm, nrm, ranges, ivs = v
    with tempfile.TemporaryDirectory() as t:
        t = Path(t)
        aug = t / "a.h5"
        write_augmented(aug, dens, gm, nrm, (1.0, 2.0, 0.5), (0.0, 255.0), 0.25)
        idx_path = t / "i.idx.h5"
        from isplat.augfile import open_augmented
        a = open_augmented(aug)
        with fileio.create_hdf5(idx_path) as f:
            store._write_root(f, dens.shape, a.density_sha256, ranges, version=4 if inside else 7)
            if inside:
                store.copy_values(f, a, dens, ranges, budget=budget, slab_voxels=slab_voxels)
            for ax, ai in build_index(dens, "ijk", ranges).items():
                store._write_axis(f, ai)
            store.finish_index(f)
            check = f.attrs["chunk_hash_check"].decode()
        if not inside:
            with fileio.create_hdf5(t / "i.values.idx.h5") as f:
                store._write_values_root(f, dens.shape, a.density_sha256, ranges, check)
                store.copy_values(f, a, dens, ranges, budget=budget, slab_voxels=slab_voxels)
                store.finish_index(f)
        idx = open_index(idx_path)
        assert idx.version == (4 if inside else 7) and idx.values_source == ("index" if inside else "values file")
        ref = reference_order(dens, ranges)
        ptr, vals = idx.read_values(["normal", "gradient_magnitude"], ranges)
        assert np.array_equal(vals["normal"], nrm.ravel()[ref])
        assert np.array_equal(vals["gradient_magnitude"], gm.ravel()[ref])
        mem = order_values(dens, gm, nrm, ranges)
        assert np.array_equal(mem.density_voxel_ptr, ptr) and np.array_equal(mem.normal, vals["normal"])
        loaded = {ax: idx.load_axis(ax, ivs) for ax in "ijk"}
        got = gather_from_index(idx.read_values(["normal", "gradient_magnitude"], ivs), loaded,
                                ["normal", "gradient_magnitude"], dens.shape)
        old = gather_channels(lambda ch, k0, k1: {"normal": nrm, "gradient_magnitude": gm}[ch][k0:k1], loaded,
                              ["normal", "gradient_magnitude"], dens.shape)
        for ax, la in loaded.items():
            flat = positions_to_flat(la, dens.shape)
            assert np.array_equal(got[ax]["normal"], nrm.ravel()[flat]), ax
            assert np.array_equal(got[ax]["gradient_magnitude"], gm.ravel()[flat]), ax
            assert np.array_equal(old[ax]["normal"], got[ax]["normal"])
            # value_order is the (density, position) order of the loaded voxels
            dv = np.repeat(la.block_density, np.diff(la.block_voxel_ptr))
            perm = value_order(la, dens.shape)
            key = dv.astype(np.int64) * dens.size + flat
            assert np.all(np.diff(key[perm]) > 0)


@pytest.fixture
def make_scene(make_scene):
    """These tests are about the channel values a selection gathers for its voxels of interest, which the
    pre-classified kernel reads (post-classification reads the whole channels)."""
    def make(aug, idx, overrides=(), **sections):
        return make_scene(aug, idx, overrides=('render.classification="pre"', *overrides), **sections)
    return make


def _scene(make_scene, aug, idx, shading=True):
    return make_scene(aug, idx, image="width = 12\nheight = 12",
                      transfer="opacity = [[100, 0], [110, 1], [255, 1]]",
                      shading=f"enabled = {'true' if shading else 'false'}",
                      views="list = [{azimuth = 0}, {azimuth = 90}, {azimuth = 0, elevation = 90}]")


def _selected_flat(s, shape):
    """Flat index of every selected voxel of AxisSelection ``s``, from its slice and in-slice coordinates."""
    n_k, n_j, n_i = shape
    c, a, b = s.coordinates()
    k, j, i = {"k": (c, b, a), "j": (b, c, a), "i": (b, a, c)}[s.axis]
    return (np.asarray(k) * n_j + j) * n_i + i


def test_selection_reads_only_the_values_and_they_are_right(tmp_path, make_scene):
    """End to end: every selected voxel's normal and gradient magnitude (gathered from /values) equals the
    augmented channels at its position; the augmented channels are not read; a version-2 index gives the same
    selection by gathering slabs."""
    r = np.random.default_rng(3)
    shape = (9, 11, 13)
    dens = r.choice(np.array([0, 50, 105, 180, 250], np.uint8), size=shape)
    gm = r.integers(0, 256, shape, dtype=np.uint8)
    nrm = r.integers(0, 65536, shape, dtype=np.uint16)
    aug, idx = write_volume(tmp_path, dens, gm=gm, normal=nrm)
    scene = make_scene(aug, idx, image="width = 12\nheight = 12",
                       transfer="opacity = [[100, 0], [110, 1], [255, 1]]\n"
                                "gradient_opacity = [[0, 0.5], [255, 1]]")
    sel = select_from_files(scene, "ijk")
    assert sel.report.values_from == "values file" and sel.report.augmented_bytes == 0
    assert sel.report.values_bytes > 0 and sel.report.values_file_bytes >= sel.report.values_bytes
    assert set(sel.report.channels) == {"normal", "gradient_magnitude"}
    want = int(((dens >= 101) & (dens <= 255)).sum())
    assert sel.report.voxels_of_interest == want
    for ax, s in sel.axes.items():
        flat = _selected_flat(s, shape)
        assert np.array_equal(s.normal, nrm.ravel()[flat]) and np.array_equal(s.gradient_magnitude, gm.ravel()[flat])
        assert np.array_equal(s.density, dens.ravel()[flat])
    # the same index without a values file: the same selection, gathered from the augmented file's slabs
    v2 = tmp_path / "v2.idx.h5"
    write_index(v2, build_index(dens), shape, density_sha256(dens))
    old = select_from_files(make_scene(aug, v2, image="width = 12\nheight = 12",
                                       transfer="opacity = [[100, 0], [110, 1], [255, 1]]\n"
                                                "gradient_opacity = [[0, 0.5], [255, 1]]"), "ijk")
    assert old.report.values_from == "augmented bricks" and old.report.augmented_bytes > 0
    assert old.report.index_format_version == 7 and sel.report.index_format_version == 7
    assert old.report.values_bytes == 0 == old.report.values_file_bytes
    for ax in "ijk":
        for a, b in zip(old.axes[ax].arrays(), sel.axes[ax].arrays()):
            assert np.array_equal(a, b)


class _Trace:
    """Record every read HDF5 makes through isplat's counting file object (offset, size)."""

    def __init__(self, monkeypatch):
        self.reads = []
        orig = fileio._CountingRaw.readinto

        def readinto(raw, buf):
            pos = raw._f.tell()
            n = orig(raw, buf)
            self.reads.append((pos, n))
            return n
        monkeypatch.setattr(fileio._CountingRaw, "readinto", readinto)


def _chunks(path, name):
    """(offset, size) of every stored chunk of dataset ``name``, in row order."""
    with h5py.File(path, "r") as f:
        ds = f[name]
        return ds.chunks[0], [(ds.id.get_chunk_info(n).byte_offset, ds.id.get_chunk_info(n).size)
                              for n in range(ds.id.get_num_chunks())]


META_BOUND = 8 << 10       # a range read's HDF5 metadata: the dataset's and its hash table's object headers


@SETTINGS
@given(st.integers(0, 255), st.integers(0, 255), st.sampled_from(["normal", "gradient_magnitude"]))
def test_bytes_read_for_an_interval_are_its_chunks_and_little_metadata(big_index, lo, hi, channel):
    """Read counts from the HDF5 layer: an interval's values cost exactly the chunks that hold its rows (at most
    one partial chunk at each end), plus at most META_BOUND of metadata and hash-table rows."""
    path, trace = big_index
    lo, hi = min(lo, hi), max(lo, hi)
    idx = open_index(path).values_file          # the values file (format version 7)
    with idx.session():
        ptr = idx.value_ptr()
        trace.reads.clear()
        before = idx.io.bytes
        _, vals = idx.read_values([channel], [(lo, hi)])
        read = idx.io.bytes - before
    r0, r1 = int(ptr[lo]), int(ptr[hi + 1])
    rows_per_chunk, chunks = _chunks(store.values_path(path), f"values/{channel}")
    touched = range(r0 // rows_per_chunk, -(-r1 // rows_per_chunk)) if r1 > r0 else range(0)
    chunk_bytes = sum(chunks[c][1] for c in touched)
    inside = {chunks[c][0] for c in touched}
    data = sum(n for pos, n in trace.reads if pos in inside)
    item = 2 if channel == "normal" else 1
    assert data == chunk_bytes                            # whole chunks, each read once
    assert chunk_bytes <= (r1 - r0) * item + 2 * rows_per_chunk * item     # no checksums (format 7)
    with h5py.File(store.values_path(path), "r") as f:     # the rest: metadata and the chunks' hash rows
        per = f[f"chunk_hashes/values.{channel}"].chunks[0]
    assert read - data <= META_BOUND + 16 * (len(touched) + 2 * per)
    assert vals[channel].size == r1 - r0


@pytest.fixture(scope="module")
def big_index(tmp_path_factory):
    """A 40 x 48 x 64 volume of smooth densities (so intervals are long row ranges over many chunks)."""
    t = tmp_path_factory.mktemp("big")
    k, j, i = np.meshgrid(np.arange(40), np.arange(48), np.arange(64), indexing="ij")
    dens = ((k * 3 + j * 2 + i) % 256).astype(np.uint8)
    r = np.random.default_rng(0)
    aug, idx = write_volume(t, dens, gm=r.integers(0, 256, dens.shape, dtype=np.uint8),
                            normal=r.integers(0, 65536, dens.shape, dtype=np.uint16))
    mp = pytest.MonkeyPatch()
    yield idx, _Trace(mp)
    mp.undo()


def test_selection_bytes_read_against_needed(tmp_path, make_scene):
    """The report's figures: bytes needed = voxels of interest x 2 B of normal + the index blocks and tables
    requested + the 257-row pointer table of the values file; bytes read (HDF5 layer) cover at least what was
    requested, from the index and its values file."""
    dens = np.random.default_rng(5).choice(np.array([0, 120, 200], np.uint8), size=(20, 24, 28))
    aug, idx = write_volume(tmp_path, dens)
    sel = select_from_files(_scene(make_scene, aug, idx), "k")
    rep = sel.report
    voi = int((dens >= 101).sum())
    assert rep.voxels_of_interest == voi and rep.values_from == "values file"
    assert rep.index_bytes == rep.index_block_bytes and rep.values_bytes == 2 * voi + 257 * 8
    assert rep.bytes_needed == 2 * voi + rep.index_block_bytes + 257 * 8 == rep.index_bytes + rep.values_bytes
    assert rep.index_file_bytes >= rep.index_bytes and rep.values_file_bytes >= rep.values_bytes
    assert rep.file_bytes == rep.index_file_bytes + rep.values_file_bytes + rep.augmented_file_bytes
    assert rep.read_ratio == rep.file_bytes / rep.bytes_needed


def test_values_from_another_augmentation_are_refused(tmp_path, make_scene):
    """Same densities, other spacing: the index's values belong to another augmented file."""
    dens = np.random.default_rng(6).choice(np.array([0, 200], np.uint8), size=(5, 6, 7))
    aug, idx = write_volume(tmp_path, dens)
    aug2, _ = write_volume(tmp_path, dens, spacing=(1.0, 1.0, 2.0), name="other", index=False)
    with pytest.raises(IsplatError, match=r"channel values were copied from an augmented file with spacing_ijk "
                                          r"\(1.0, 1.0, 1.0\).*rebuild it: isplat index .*other.aug.h5 -o .*v.idx.h5 "
                                          r"--force"):
        select_from_files(_scene(make_scene, aug2, idx), "k")


@pytest.mark.parametrize("case, msg", [
    ("ptr", "density_voxel_ptr is not non-decreasing from 0 to the"),
    ("count", "/values holds 149 voxels of density 199, the blocks of axis k 0: corrupt index"),
    ("missing", "group '/values' is missing"),
    ("length", "gradient_magnitude: length 149, expected 150"),
    ("attr", "attribute 'gradient_magnitude_scale' has type int64, expected float64"),
])
def test_corrupt_values_are_refused_with_one_line(tmp_path, make_scene, case, msg):
    dens = np.zeros((5, 6, 7), np.uint8)
    dens[:, :, :5] = 200
    aug, idx = write_volume(tmp_path, dens, index=False)
    build_index_file(aug, idx, ranges=[(150, 255)])
    vfile = store.values_path(idx)
    with h5py.File(vfile, "r+") as f:
        g = f["values"]
        if case == "ptr":
            p = g["density_voxel_ptr"][()]
            p[100] = 7
            g["density_voxel_ptr"][...] = p
        elif case == "count":
            p = g["density_voxel_ptr"][()]
            p[200] = p[201] - 1
            g["density_voxel_ptr"][...] = p
        elif case == "missing":
            del f["values"]
        elif case == "length":
            data = g["gradient_magnitude"][:-1]
            del g["gradient_magnitude"]
            fileio.create_hashed_dataset(g, "gradient_magnitude", data.shape, "|u1", data, chunks=data.shape)
        elif case == "attr":
            g.attrs["gradient_magnitude_scale"] = np.int64(1)
    if case != "missing":   # an editor who recomputes the chunk hashes: the structural checks behind them
        fuzzlab.rehash(vfile)
    scene = make_scene(aug, idx, image="width = 12\nheight = 12", transfer="opacity = [[150, 0], [160, 1], [255, 1]]")
    with pytest.raises(IsplatError) as exc:
        select_from_files(scene, "k")
    text = str(exc.value)
    assert msg in text and str(vfile) in text and "\n" not in text, text


def test_index_cli_on_a_sample_volume(tmp_path, capsys):
    """`isplat sample`, `isplat augment`, `isplat index`: the file holds every voxel's values in density order."""
    from isplat.augfile import open_augmented
    from isplat.cli.main import main

    npy, out = tmp_path / "engine.npy", tmp_path / "engine.aug.h5"
    for args in (["sample", "engine", "--shape", "24,20,12", "-o", npy, "-q"], ["augment", npy, "-o", out, "-q"],
                 ["index", out, "-o", tmp_path / "e.idx.h5", "-q"]):
        with pytest.raises(SystemExit) as exc:
            main([str(a) for a in args])
        assert exc.value.code == 0, capsys.readouterr().err
    a = open_augmented(out)
    dens, nrm = a.read("density"), a.read("normal")
    idx = open_index(tmp_path / "e.idx.h5")
    _, vals = idx.read_values(["normal"], [(0, 255)])
    assert np.array_equal(vals["normal"], nrm.ravel()[reference_order(dens, [(0, 255)])])
    assert idx.axes == "ijk" and idx.version == 7 and idx.values_source == "values file"
    assert (tmp_path / "e.values.idx.h5").is_file()


def test_stats_of_an_index_without_values_file_say_where_values_come_from(tmp_path, make_scene):
    """`isplat stats` on an index without its values file: the values come from the augmented file, and the
    command that writes them is named."""
    from isplat.stats import collect, format_table

    dens = np.random.default_rng(7).choice(np.array([0, 120, 200], np.uint8), size=(6, 7, 8))
    aug, _ = write_volume(tmp_path, dens, index=False)
    v2 = tmp_path / "v2.idx.h5"
    write_index(v2, build_index(dens), dens.shape, density_sha256(dens))
    scene = tmp_path / "s.toml"
    scene.write_text(f'version = 1\n[data]\naugmented = "{aug}"\nindex = "{v2}"\n[image]\nwidth = 8\nheight = 8\n'
                     '[transfer]\nopacity = [[100, 0], [110, 1], [255, 1]]\n')
    s = collect(aug, v2, scene=scene)
    assert s["index"]["format_version"] == 7 and s["index"]["values"] is None
    ld = s["scene"]["loaded"]
    assert ld["values_from"] == "augmented bricks" and ld["augmented_bytes"] == 2 * dens.size
    assert ld["bytes_needed"] == 2 * int((dens >= 101).sum()) + ld["index_bytes"]
    table = format_table(s)
    assert "no values file (isplat index --no-values)" in table and "the bricks that hold a voxel of interest" in table
    assert "isplat index AUG.h5 -o IDX.h5 --force writes it" in table


def _pre_scene(make_scene, aug, idx):
    return make_scene(aug, idx, image="width = 12\nheight = 12", transfer="opacity = [[100, 0], [110, 1], [255, 1]]")


def test_without_the_values_file_pre_gathers_from_the_augmented_file_and_says_so(tmp_path, make_scene, caplog):
    """Version 6 without its values file: the same selection, gathered from the augmented file's k-slabs, and one
    log line naming the missing file and the command that writes it."""
    import logging

    r = np.random.default_rng(8)
    dens = r.choice(np.array([0, 120, 200], np.uint8), size=(7, 8, 9))
    nrm = r.integers(0, 65536, dens.shape, dtype=np.uint16)
    aug, idx = write_volume(tmp_path, dens, normal=nrm)
    with_values = select_from_files(_pre_scene(make_scene, aug, idx), "ijk")
    store.values_path(idx).unlink()
    with caplog.at_level(logging.INFO, logger="isplat"):
        without = select_from_files(_pre_scene(make_scene, aug, idx), "ijk")
    assert with_values.report.values_from == "values file" and without.report.values_from == "augmented bricks"
    said = [m for m in caplog.messages if "has no values file" in m]
    assert len(said) == 1 and "v.values.idx.h5" in said[0] and f"isplat index {aug} -o {idx} --force" in said[0]
    for ax in "ijk":
        for a, b in zip(with_values.axes[ax].arrays(), without.axes[ax].arrays()):
            assert np.array_equal(a, b)


def test_values_file_of_another_index_is_refused_naming_both_files(tmp_path, make_scene):
    """A values file from another volume, or from another index of the same volume (other density ranges), is
    refused in one line naming both files and the rebuild command; so is a version-6 index with '/values'."""
    dens = np.random.default_rng(9).choice(np.array([0, 120, 200], np.uint8), size=(5, 6, 7))
    aug, idx = write_volume(tmp_path, dens)
    _, other = write_volume(tmp_path, dens[::-1].copy(), name="o")            # another volume
    part = tmp_path / "p.idx.h5"
    build_index_file(aug, part, ranges=[(100, 255)])                             # same volume, other ranges
    for stranger in (store.values_path(other), store.values_path(part)):
        store.values_path(idx).write_bytes(stranger.read_bytes())
        with pytest.raises(IsplatError) as exc:
            select_from_files(_pre_scene(make_scene, aug, idx), "k")
        text = str(exc.value)
        assert f"{store.values_path(idx)}: the channel values of another index than {idx}" in text, text
        assert f"isplat index AUG.h5 -o {idx} --force" in text and "\n" not in text
    with h5py.File(idx, "r+") as f:                                             # version 7 with /values inside
        f.create_group("values")
    with pytest.raises(IsplatError, match=r"a version-7 index has no '/values' \(its channel values are in "
                                          r"v.values.idx.h5, beside it\); rebuild it: isplat index"):
        open_index(idx)


def test_index_cli_values_file_no_values_and_force(tmp_path, capsys):
    """`isplat index` writes NAME.values.idx.h5 beside NAME.idx.h5; an existing one is not overwritten without
    --force (and the index is not written either); --no-values writes none and, with --force, removes a stale one."""
    from isplat.cli.main import main

    def run(*args):
        with pytest.raises(SystemExit) as exc:
            main([str(a) for a in args])
        return exc.value.code, capsys.readouterr().err

    dens = np.random.default_rng(10).choice(np.array([0, 120, 200], np.uint8), size=(5, 6, 7))
    aug, _ = write_volume(tmp_path, dens, index=False)
    out, vals = tmp_path / "x.idx.h5", tmp_path / "x.values.idx.h5"
    vals.write_bytes(b"someone else's file")
    code, err = run("index", aug, "-o", out, "-q")
    assert code != 0 and str(vals) in err and "--force" in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists() and vals.read_bytes() == b"someone else's file"
    assert run("index", aug, "-o", out, "-q", "--force")[0] == 0
    assert open_index(out).values_source == "values file"
    from isplat.stats import collect, format_table

    s = collect(aug, out)
    assert s["index"]["values"]["path"] == str(vals) and s["index"]["values"]["file_bytes"] == vals.stat().st_size
    assert s["index"]["file_bytes_per_voxel"] == pytest.approx(out.stat().st_size / (3 * dens.size))
    table = format_table(s)
    assert str(vals) in table
    assert "read by pre-classification only" in table and "B per indexed voxel per axis (format 7)" in table
    assert run("index", aug, "-o", out, "-q", "--force", "--no-values")[0] == 0
    assert out.is_file() and not vals.exists() and open_index(out).values_source == "none"
    assert run("index", aug, "-o", tmp_path / "y.idx.h5", "-q", "--no-values")[0] == 0
    assert not (tmp_path / "y.values.idx.h5").exists()


def test_pre_images_from_the_values_file_equal_those_from_values_inside(tmp_path, make_scene):
    """The same index with its values inside (format 4, as isplat wrote it before) and in the values file (format
    6): pre's images are bit for bit the same, and so are its bytes needed."""
    from isplat.renderer import Renderer

    r = np.random.default_rng(11)
    dens = r.choice(np.array([0, 120, 180, 250], np.uint8), size=(10, 12, 14))
    aug, idx = write_volume(tmp_path, dens, gm=r.integers(0, 256, dens.shape, dtype=np.uint8),
                            normal=r.integers(0, 65536, dens.shape, dtype=np.uint16))
    v4 = tmp_path / "old.idx.h5"
    with fileio.create_hdf5(v4) as f, h5py.File(idx, "r") as i, h5py.File(store.values_path(idx), "r") as v:
        store._write_root(f, tuple(i.attrs["shape"]), i.attrs["density_sha256"].decode(),
                          [tuple(x) for x in i.attrs["density_ranges"]], version=4)
        g = v["values"]                         # version 4's layout (Fletcher-32 chunks), the same content
        _, dsets = store._values_group(f, g["density_voxel_ptr"][()], g.attrs["spacing_ijk"],
                                       g.attrs["gradient_magnitude_scale"])
        for ds, ch in zip(dsets, store.VALUE_CHANNELS):
            ds[...] = g[ch][()]
        for a, ai in build_index(dens).items():
            store._write_axis(f, ai)
        store.finish_index(f)
    images = {}
    for name, path in (("v6", idx), ("v4", v4)):
        scene = make_scene(aug, path, image="width = 24\nheight = 20",
                           transfer="opacity = [[100, 0], [110, 0.6], [255, 0.9]]\n"
                                    "gradient_opacity = [[0, 0.5], [255, 1]]",
                           views="list = [{azimuth = 30, elevation = 20}]")
        rend = Renderer(scene)
        images[name] = (np.asarray(rend.render_view(0)[0]), rend.report)
    assert images["v6"][1].values_from == "values file" and images["v4"][1].values_from == "index"
    assert open_index(v4).version == 4
    assert np.array_equal(images["v6"][0], images["v4"][0]) and images["v6"][0].any()
    assert images["v6"][1].bytes_needed == images["v4"][1].bytes_needed


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**16), axis=st.sampled_from("ijk"), cut=st.tuples(st.integers(0, 69), st.integers(1, 70)))
def test_values_gathered_from_bricks_are_the_channels_at_the_voxels(tmp_path_factory, seed, axis, cut):
    """gather_bricks (a bricked file without a values file, or a slab): the normal and gradient magnitude of every
    loaded voxel, as the channels hold them at its position, over several layers of bricks and for slabs whose
    bounds are not on brick edges; only the bricks holding a voxel are read."""
    from isplat.augfile import open_augmented
    from isplat.index import open_index
    from isplat.selection import _slab_box, gather_bricks
    from isplat.splat.select import flat_indices
    from isplat import grid

    rng = np.random.default_rng(seed)
    shape = (70, 11, 9)                                   # k spans nine layers of 8^3 bricks
    dens = np.where(rng.random(shape) < 0.05, rng.integers(150, 256, shape), 0).astype(np.uint8)
    gm = rng.integers(0, 256, shape).astype(np.uint8)
    nrm = rng.integers(0, 65536, shape).astype(np.uint16)
    aug, idx = write_volume(tmp_path_factory.mktemp("b"), dens, gm=gm, normal=nrm)
    a = open_augmented(aug)
    assert a.bricked
    n = shape[2 - "ijk".index(axis)]
    c0, c1 = sorted((min(cut[0], n - 1), min(cut[1], n)))
    slices = np.arange(c0, max(c1, c0 + 1))
    ix = open_index(idx)
    with ix.session():
        la = ix.load_axis(axis, [(150, 255)], slices=slices)
    box = _slab_box(a, axis, slices)
    got = gather_bricks(a, {axis: la}, ["normal", "gradient_magnitude"], shape, box)[axis]
    fi = flat_indices(la.slice_block_ptr, la.block_voxel_ptr, la.positions, la.n_a, grid.flat_strides(shape, axis))
    assert fi.size == int((np.moveaxis(dens, 2 - "ijk".index(axis), 0)[slices] >= 150).sum())
    assert np.array_equal(got["normal"], nrm.ravel()[fi]) and np.array_equal(got["gradient_magnitude"], gm.ravel()[fi])
    assert a.bytes_read <= 3 * (np.unique(np.stack(np.unravel_index(fi, shape), 1) // 8, axis=0).shape[0] * 512)
