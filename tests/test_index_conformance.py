"""The hand-derived examples of formats/examples/index/: the writer produces exactly their bytes, and the
committed .idx.h5 files decode back to their voxels."""

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from isplat.augfile import density_sha256
from isplat.index import build_index, open_index, write_index

EXAMPLES = Path(__file__).resolve().parents[1] / "formats" / "examples" / "index"
NAMES = sorted(p.stem for p in EXAMPLES.glob("*.json"))


def load(name):
    ex = json.loads((EXAMPLES / f"{name}.json").read_text())
    if "values_kji" in ex:
        vol = np.asarray(ex["values_kji"], dtype=np.uint8)
    else:
        vol = np.full(ex["shape"], ex["background"], dtype=np.uint8)
        for k, j, i, d in ex["voxels_kjid"]:
            vol[k, j, i] = d
    return ex, vol


def slice_of(vol, axis, s):
    """Slice ``s`` perpendicular to ``axis`` as a 2-D array [b, a] (docs/design.md table)."""
    return vol[s] if axis == "k" else vol[:, s, :] if axis == "j" else vol[:, :, s]


def expected_tables(spec):
    """The stored arrays of one axis, assembled from the JSON blocks (density-major)."""
    blocks = sorted(spec["blocks"], key=lambda b: (b["density"], b["slice"]))
    ptr = np.zeros(257, np.int64)
    for b in blocks:
        ptr[b["density"] + 1:] += 1
    data = [bytes.fromhex(b["hex"]) for b in blocks]
    off = np.cumsum([0] + [len(x) for x in data]).astype(np.int64)
    return {
        "density_entry_ptr": ptr,
        "entry_slice": np.array([b["slice"] for b in blocks], np.uint32),
        "entry_voxel_count": np.array([b["count"] for b in blocks], np.uint32),
        "entry_byte_offset": off,
        "bytes": np.frombuffer(b"".join(data), np.uint8),
    }


def test_examples_exist():
    assert {"gaps", "wide", "row2048", "full"} <= set(NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_writer_produces_the_example_bytes(name):
    ex, vol = load(name)
    ranges = [tuple(r) for r in ex["density_ranges"]]
    index = build_index(vol, "".join(ex["axes"]), ranges)
    for axis, spec in ex["axes"].items():
        ax = index[axis]
        assert (ax.n_slices, ax.n_a, ax.n_b, ax.escape_width) == \
            (spec["n_slices"], spec["n_a"], spec["n_b"], spec["escape_width"])
        for b in spec["blocks"]:
            assert ax.block(b["density"], b["slice"]).hex() == b["hex"], (axis, b)
        for key, want in expected_tables(spec).items():
            got = getattr(ax, key)
            assert got.dtype == want.dtype and np.array_equal(got, want), (axis, key)


@pytest.mark.parametrize("name", NAMES)
def test_committed_file_matches_and_decodes(name, tmp_path):
    ex, vol = load(name)
    assert np.array_equal(np.load(EXAMPLES / f"{name}.npy"), vol)
    path = EXAMPLES / f"{name}.idx.h5"
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == b"isplat-index" and f.attrs["format_version"] == np.int64(7)
        assert "values" not in f                                     # since version 6: in the values file (§9)
        assert f.attrs["format_version"].dtype == np.dtype("<i8")
        assert f.attrs["density_sha256"].decode() == density_sha256(vol)
        assert f.id.get_create_plist().get_version()[0] >= 2       # superblock with checksums
        assert np.array_equal(f.attrs["density_ranges"], ex["density_ranges"])
        for axis, spec in ex["axes"].items():
            g = f["axes"][axis]
            assert g.attrs["escape_width"] == spec["escape_width"]
            for key, want in expected_tables(spec).items():
                ds = g[key]
                assert_sized_chunks(ds, whole=key == "density_entry_ptr")
                assert ds.dtype.str in ("<i8", "<u4", "|u1") and np.array_equal(ds[()], want), (axis, key)
    idx = open_index(path)
    for axis, spec in ex["axes"].items():
        loaded = idx.load_axis(axis, [tuple(r) for r in ex["density_ranges"]])
        assert loaded.bytes_read == idx.nbytes(axis, ex["density_ranges"])
        for s in range(spec["n_slices"]):
            sl = slice_of(vol, axis, s).ravel()
            r0, r1 = loaded.slice_block_ptr[s], loaded.slice_block_ptr[s + 1]
            dens = [d for d in np.unique(sl) if any(lo <= d <= hi for lo, hi in ex["density_ranges"])]
            assert list(loaded.block_density[r0:r1]) == dens
            for r in range(r0, r1):
                got = loaded.positions[loaded.block_voxel_ptr[r]:loaded.block_voxel_ptr[r + 1]]
                assert np.array_equal(got, np.flatnonzero(sl == loaded.block_density[r]))
    check_values(ex, vol, EXAMPLES / f"{name}.values.idx.h5", path)
    # regenerating gives the same file content
    out = tmp_path / "x.idx.h5"
    write_index(out, build_index(vol, "".join(ex["axes"]), [tuple(r) for r in ex["density_ranges"]]),
                vol.shape, density_sha256(vol), [tuple(r) for r in ex["density_ranges"]])
    with h5py.File(out, "r") as a, h5py.File(path, "r") as b:
        for axis in ex["axes"]:
            for key in expected_tables(ex["axes"][axis]):
                assert np.array_equal(a["axes"][axis][key][()], b["axes"][axis][key][()])


def assert_sized_chunks(ds, whole=False):
    """A version-7 dataset (formats/index.md §1): chunked without filters, its chunks of the size §1 gives (the
    pointer tables whole), allocated when written (HDF5's chunk index not needed: chunk n at the first chunk's
    address + n chunks)."""
    from isplat.index.store import chunk_rows

    assert ds.chunks is not None and not ds.fletcher32 and ds.compression is None
    assert ds.id.get_create_plist().get_nfilters() == 0
    n = ds.shape[0]
    assert ds.chunks[0] == (n if whole else chunk_rows(n, ds.dtype.itemsize))
    nc = ds.id.get_num_chunks()
    assert nc == -(-n // ds.chunks[0])
    first = ds.id.get_chunk_info(0).byte_offset
    step = ds.chunks[0] * ds.dtype.itemsize
    assert all(ds.id.get_chunk_info(c).byte_offset == first + c * step for c in range(nc))


def test_chunk_rows_follow_the_dataset_size():
    """§1: the power of two nearest below sqrt(bytes) / 2, within 256 B .. 64 KiB, at most the rows."""
    from isplat.index.store import chunk_rows

    assert chunk_rows(10, 4) == 10                 # fewer rows than a 256-byte chunk holds
    assert chunk_rows(20931, 4) == 64              # 83,724 B: sqrt / 2 = 144 -> 256 B (the minimum)
    assert chunk_rows(1858, 16) == 16              # a hash table of 29,728 B: sqrt / 2 = 86 -> 256 B
    assert chunk_rows(7_608_714, 1) == 1024        # sqrt / 2 = 1,379 -> 1 KiB
    assert chunk_rows(3_520 * 2048, 2) == 512      # 14.4 MB: sqrt / 2 = 1,898 -> 1 KiB: 512 normals
    assert chunk_rows(1 << 40, 1) == 1 << 16       # the maximum


@pytest.mark.parametrize("name", ["gaps", "full"])
def test_version_6_pair_is_read(name):
    """NAME.v6.idx.h5 with NAME.v6.values.idx.h5 (format version 6, as isplat wrote them before version 7:
    Fletcher-32 chunks of fixed sizes): still read, with the same blocks and values as the version-7 pair."""
    ex, vol = load(name)
    old, new = open_index(EXAMPLES / f"{name}.v6.idx.h5"), open_index(EXAMPLES / f"{name}.idx.h5")
    assert old.version == 6 and old.values_source == "values file" and old.values_file.version == 6
    for axis in ex["axes"]:
        a, b = old.load_axis(axis, ex["density_ranges"]), new.load_axis(axis, ex["density_ranges"])
        assert np.array_equal(a.positions, b.positions) and np.array_equal(a.block_density, b.block_density)
    x, y = (i.read_values(["normal", "gradient_magnitude"], ex["density_ranges"]) for i in (old, new))
    assert np.array_equal(x[0], y[0]) and all(np.array_equal(x[1][c], y[1][c]) for c in x[1])
    check_values(ex, vol, EXAMPLES / f"{name}.v6.values.idx.h5", EXAMPLES / f"{name}.v6.idx.h5")


def test_values_file_of_another_version_is_refused(tmp_path):
    """A version-6 values file beside a version-7 index is refused (it belongs to another build)."""
    import shutil

    from isplat.errors import IsplatError

    shutil.copy(EXAMPLES / "gaps.idx.h5", tmp_path / "gaps.idx.h5")
    shutil.copy(EXAMPLES / "gaps.v6.values.idx.h5", tmp_path / "gaps.values.idx.h5")
    with pytest.raises(IsplatError, match=r"format version 6 beside an index of version 7; rebuild both"):
        open_index(tmp_path / "gaps.idx.h5").read_values(["normal"], [(1, 255)])


def augmented_channels(vol):
    """The example volume augmented as generate.py does (spacing 1, window 0..255: densities = values)."""
    from isplat.augment import augment_array

    return augment_array(vol, (1.0, 1.0, 1.0), (0.0, 255.0))


def check_values(ex, vol, path, index_path=None):
    """/values (formats/index.md §9) of ``path`` (a version-4 index, or the values file of ``index_path``): rows by
    density then flat position, exactly the JSON's hand-derived order, the values of the augmented channels at
    those positions, and a pointer table counting each density."""
    aug = augmented_channels(vol)
    inside = np.zeros(256, bool)
    for lo, hi in ex["density_ranges"]:
        inside[lo:hi + 1] = True
    d = vol.ravel()
    flat = np.flatnonzero(inside[d])
    reference = flat[np.lexsort((flat, d[flat]))]                 # by density, then position
    assert reference.tolist() == ex["values_flat_order"]
    want_ptr = np.r_[0, np.cumsum(np.where(inside, np.bincount(d, minlength=256), 0))]
    with h5py.File(path, "r") as f:
        g = f["values"]
        for name in ("density_voxel_ptr", "gradient_magnitude", "normal"):
            ds = g[name]
            if index_path is not None and f.attrs["format_version"] == 7:
                assert_sized_chunks(ds, whole=name == "density_voxel_ptr")
            else:
                assert ds.chunks is not None and ds.fletcher32 and ds.compression is None
        assert g["density_voxel_ptr"].dtype.str == "<i8" and np.array_equal(g["density_voxel_ptr"][()], want_ptr)
        assert g["normal"].dtype.str == "<u2" and g["gradient_magnitude"].dtype.str == "|u1"
        assert np.array_equal(g["normal"][()], aug["normal"].ravel()[reference])
        assert np.array_equal(g["gradient_magnitude"][()], aug["gradient_magnitude"].ravel()[reference])
        assert tuple(g.attrs["spacing_ijk"]) == (1.0, 1.0, 1.0)
        assert g.attrs["gradient_magnitude_scale"] == aug["gradient_magnitude_scale"]
        if index_path is not None:          # the values file: its root attributes and its index's identity
            with h5py.File(index_path, "r") as fi:
                assert f.attrs["format"] == b"isplat-index-values"
                assert f.attrs["format_version"] == fi.attrs["format_version"]
                assert f.attrs["format_version"].dtype == np.dtype("<i8") and "axes" not in f
                assert f.attrs["index_chunk_hash_check"] == fi.attrs["chunk_hash_check"]
                for a in ("shape", "density_sha256", "density_ranges"):
                    assert np.array_equal(f.attrs[a], fi.attrs[a]), a
    idx = open_index(index_path or path)
    assert idx.version in ((6, 7) if index_path else (4,)) and idx.has_values
    assert idx.values_source == ("values file" if index_path else "index")
    assert idx.values_meta.n_voxels == reference.size
    ptr, vals = idx.read_values(["normal", "gradient_magnitude"], ex["density_ranges"])
    assert np.array_equal(vals["normal"], aug["normal"].ravel()[reference])


@pytest.mark.parametrize("name", ["gaps", "full"])
def test_version_4_with_values_inside_is_read(name):
    """NAME.v4.idx.h5 (format version 4, as isplat wrote it before version 6: the channel values inside, in
    ``/values``): still read; its blocks and values equal the version-6 pair's, and §9's checks hold for it."""
    ex, vol = load(name)
    old, new = open_index(EXAMPLES / f"{name}.v4.idx.h5"), open_index(EXAMPLES / f"{name}.idx.h5")
    assert old.version == 4 and old.values_source == "index" and old.values_file is None
    assert new.version == 7 and new.values_source == "values file"
    for axis in ex["axes"]:
        a, b = old.load_axis(axis, ex["density_ranges"]), new.load_axis(axis, ex["density_ranges"])
        assert np.array_equal(a.positions, b.positions) and np.array_equal(a.block_density, b.block_density)
    for x, y in zip(old.read_values(["normal", "gradient_magnitude"], ex["density_ranges"]),
                    new.read_values(["normal", "gradient_magnitude"], ex["density_ranges"])):
        for u, v in (zip(x.values(), y.values()) if isinstance(x, dict) else [(x, y)]):
            assert np.array_equal(u, v)
    check_values(ex, vol, EXAMPLES / f"{name}.v4.idx.h5")


def test_index_without_its_values_file_is_read(tmp_path):
    """gaps.idx.h5 alone (no values file beside it, as `isplat index --no-values` writes it): its blocks load, and
    asking it for values names the missing file and the command that writes it."""
    import shutil

    from isplat.errors import IsplatError

    ex, vol = load("gaps")
    shutil.copy(EXAMPLES / "gaps.idx.h5", tmp_path / "gaps.idx.h5")
    alone, pair = open_index(tmp_path / "gaps.idx.h5"), open_index(EXAMPLES / "gaps.idx.h5")
    assert not alone.has_values and alone.values_source == "none" and pair.has_values
    for axis in ex["axes"]:
        a, b = alone.load_axis(axis, ex["density_ranges"]), pair.load_axis(axis, ex["density_ranges"])
        assert np.array_equal(a.positions, b.positions) and np.array_equal(a.block_density, b.block_density)
    with pytest.raises(IsplatError, match=r"has no values file .*gaps.values.idx.h5; rebuild it: isplat index "):
        alone.read_values(["normal"], [(1, 255)])


@pytest.mark.parametrize("name,version", [("gaps.v2.idx.h5", 2)])
def test_old_versions_are_refused_with_the_rebuild_command(name, version):
    """Files of versions 2 and 3 (no chunk hashes) are refused, naming the command that rebuilds them."""
    from isplat.errors import IsplatError

    with pytest.raises(IsplatError, match=rf"'format_version' is {version}, this isplat reads versions 4, 5, 6, 7; "
                                          rf"files of version {version} lack this version's checksums, rebuild it: "
                                          r"isplat index"):
        open_index(EXAMPLES / name)
