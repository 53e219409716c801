"""`isplat index` on good and bad input: one error line on stderr, non-zero exit, no partial file."""

import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

import fuzzlab

from isplat.augfile import write_augmented
from isplat.cli.main import main
from isplat.errors import IsplatError
from isplat.index import open_index


def make_aug(path, shape=(4, 5, 6), seed=0):
    rng = np.random.default_rng(seed)
    d = rng.integers(0, 256, shape).astype(np.uint8)
    write_augmented(path, d, d, np.zeros(shape, np.uint16), (1, 1, 1), (0, 255), 1.0)
    return d


def run(capsys, *args):
    with pytest.raises(SystemExit) as exc:
        main(["index", *map(str, args)])
    cap = capsys.readouterr()
    return exc.value.code, cap.out, cap.err


def leftovers(folder):
    return sorted(p.name for p in Path(folder).iterdir() if p.name.endswith(".part"))


@pytest.fixture
def aug(tmp_path):
    p = tmp_path / "v.aug.h5"
    make_aug(p)
    return p


def test_index_ok(tmp_path, aug, capsys):
    out = tmp_path / "v.idx.h5"
    code, stdout, err = run(capsys, aug, "-o", out, "--densities", "10:20,15:40,200", "--axes", "kj")
    assert code == 0 and stdout == ""
    idx = open_index(out)
    assert idx.axes == "jk" and idx.density_ranges == [(10, 40), (200, 200)]
    with h5py.File(aug, "r") as f:
        assert idx.density_sha256 == f.attrs["density_sha256"].decode()
        d = f["density"][()]
    want = np.bincount(d.ravel(), minlength=256)
    want[~np.isin(np.arange(256), list(range(10, 41)) + [200])] = 0
    assert np.array_equal(idx.voxel_counts("k"), want) and np.array_equal(idx.voxel_counts("j"), want)
    code, _, err = run(capsys, aug, "-o", out, "-q")
    assert code == 2 and err.startswith("isplat: error: ") and "exists" in err and err.count("\n") == 1
    code, _, err = run(capsys, aug, "-o", out, "-q", "--force")
    assert code == 0 and err == ""
    assert open_index(out).axes == "ijk" and open_index(out).density_ranges == [(0, 255)]


@pytest.mark.parametrize("densities, msg", [
    ("0:300", "0..255"), ("-1:5", "not LO:HI"), ("10:5", "reversed"), ("a:b", "not LO:HI"),
    ("1:2:3", "not LO:HI"), ("", "empty"), ("5,", "not LO:HI"), ("1.5:3", "not LO:HI"),
])
def test_bad_densities(tmp_path, aug, capsys, densities, msg):
    out = tmp_path / "o.h5"
    code, stdout, err = run(capsys, aug, "-o", out, "--densities", densities)
    assert code != 0 and stdout == ""
    assert err.startswith("isplat: error: ") and msg in err and err.count("\n") == 1, err
    assert not out.exists() and leftovers(tmp_path) == []


@pytest.mark.parametrize("axes, msg", [("ijx", "unknown axis letter 'x'"), ("", "non-empty"), ("kk", "repeated")])
def test_bad_axes(tmp_path, aug, capsys, axes, msg):
    code, _, err = run(capsys, aug, "-o", tmp_path / "o.h5", "--axes", axes)
    assert code == 2 and err.startswith("isplat: error: ") and msg in err and err.count("\n") == 1


def _set_attr(path, key, value):
    with h5py.File(path, "r+") as f:
        f.attrs[key] = value


@pytest.mark.parametrize("case", ["format", "version", "truncated", "missing", "not_hdf5", "index_file"])
def test_bad_augmented(tmp_path, aug, capsys, case):
    if case == "format":
        _set_attr(aug, "format", "isplat-something")
    elif case == "version":
        _set_attr(aug, "format_version", np.int64(7))
    elif case == "truncated":
        data = aug.read_bytes()
        aug.write_bytes(data[: len(data) // 2])
    elif case == "missing":
        aug.unlink()
    elif case == "not_hdf5":
        aug.write_text("hello\n")
    elif case == "index_file":   # an index given where an augmented file is expected
        main_out = tmp_path / "first.idx.h5"
        make_aug(tmp_path / "other.aug.h5")
        with pytest.raises(SystemExit):
            main(["index", str(tmp_path / "other.aug.h5"), "-o", str(main_out), "-q"])
        capsys.readouterr()
        shutil.copy(main_out, aug)
    out = tmp_path / "o.idx.h5"
    code, stdout, err = run(capsys, aug, "-o", out)
    assert code == 2 and stdout == "" and err.startswith("isplat: error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    assert not out.exists() and leftovers(tmp_path) == []


def test_output_folder_missing(tmp_path, aug, capsys):
    code, _, err = run(capsys, aug, "-o", tmp_path / "nope" / "o.h5")
    assert code == 2 and "does not exist" in err


def test_subprocess_end_to_end(tmp_path, aug):
    exe = Path(sys.executable).with_name("isplat")
    out = tmp_path / "o.idx.h5"
    r = subprocess.run([str(exe), "index", str(aug), "-o", str(out), "-q"], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout == "" and r.stderr == ""
    r = subprocess.run([str(exe), "index", str(aug), "-o", str(out), "--axes", "q"], capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.startswith("isplat: error: ") and r.stderr.count("\n") == 1


# ------------------------------------------------------------------ corrupt index files on load

@pytest.fixture
def index_file(tmp_path, aug, capsys):
    out = tmp_path / "v.idx.h5"
    run(capsys, aug, "-o", out, "-q")
    return out


def _edit(path, axis, name, fn, rehash=True):
    """Edit a table through HDF5; by default recompute the chunk hashes too (an editor who knows the format), so
    the structural checks behind them are tested (without: the hash of the chunk refuses it first)."""
    with h5py.File(path, "r+") as f:
        ds = f["axes"][axis][name]
        arr = ds[()]
        fn(arr)
        ds[...] = arr
    if rehash:
        fuzzlab.rehash(path)


def _first_entry(path, axis):
    with h5py.File(path, "r") as f:
        ptr = f["axes"][axis]["density_entry_ptr"][()]
        d = int(np.flatnonzero(np.diff(ptr))[0])
        return d, int(f["axes"][axis]["entry_slice"][ptr[d]])


CORRUPTIONS = {
    "ptr_decreasing": ("density_entry_ptr", lambda a: a.__setitem__(5, a[6] + 1), "density_entry_ptr"),
    "ptr_past_end": ("density_entry_ptr", lambda a: a.__setitem__(256, a[256] + 3), "density_entry_ptr"),
    "slice_too_big": ("entry_slice", lambda a: a.__setitem__(0, 999), "n_slices"),
    "slices_not_increasing": ("entry_slice", "same_density_pair", "increasing"),
    "count_zero": ("entry_voxel_count", lambda a: a.__setitem__(0, 0), "entry_voxel_count"),
    "count_huge": ("entry_voxel_count", lambda a: a.__setitem__(0, 2**32 - 1), "entry_voxel_count"),
    "count_plus_one": ("entry_voxel_count", lambda a: a.__setitem__(0, a[0] + 1), "does not fit its voxel count"),
    "offset_past_bytes": ("entry_byte_offset", lambda a: a.__setitem__(slice(2, None), a[2:] + 10**9), "entry_byte_offset"),
    "offset_negative": ("entry_byte_offset", lambda a: a.__setitem__(1, -5), "entry_byte_offset"),
    "bytes_escape_truncated": ("bytes", lambda a: a.__setitem__(0, 0), "corrupt block"),
    "bytes_position_outside": ("bytes", lambda a: a.__setitem__(0, 255), "corrupt block"),
}


HARMLESS_WITHOUT_VERIFY = {"offset_negative"}   # an inner offset the default load never reads


@pytest.mark.parametrize("verify", [True, False])
@pytest.mark.parametrize("case", sorted(CORRUPTIONS))
def test_corrupt_index_on_load(index_file, case, verify):
    name, fn, msg = CORRUPTIONS[case]
    axis = "i"
    good = open_index(index_file).load_axis(axis, [(0, 255)])
    d, s = _first_entry(index_file, axis)
    if fn == "same_density_pair":
        with h5py.File(index_file, "r") as f:
            ptr = f["axes"][axis]["density_entry_ptr"][()]
        r = int(ptr[np.flatnonzero(np.diff(ptr) >= 2)[0]])

        def fn(a):
            a[r + 1] = a[r]
    _edit(index_file, axis, name, fn)
    if not verify and case in HARMLESS_WITHOUT_VERIFY:
        got = open_index(index_file).load_axis(axis, [(0, 255)])
        assert np.array_equal(got.positions, good.positions)
        return
    with pytest.raises(IsplatError) as exc:
        open_index(index_file).load_axis(axis, [(0, 255)], verify_offsets=verify)
    text = str(exc.value)
    assert text.startswith(f"{index_file}: axis {axis}") and "\n" not in text, text
    if verify:
        assert msg in text, text
    if msg in ("corrupt block", "does not fit its voxel count") and verify:
        assert f"axis {axis}, density {d}, slice {s}" in text


def test_corrupt_escape_coordinates(tmp_path):
    from isplat.augfile import density_sha256
    from isplat.index import build_index, write_index
    vol = np.zeros((1, 2, 300), np.uint8)
    vol[0, 1, 299] = 7
    path = tmp_path / "w.idx.h5"
    write_index(path, build_index(vol, "k", [(7, 7)]), vol.shape, density_sha256(vol), [(7, 7)])
    _edit(path, "k", "bytes", lambda a: a.__setitem__(2, 9))      # a = 0x092b >= n_a = 300
    for verify in (False, True):
        with pytest.raises(IsplatError, match="axis k, density 7, slice 0: corrupt block: an escape coordinate"):
            open_index(path).load_axis("k", [(7, 7)], verify_offsets=verify)


@pytest.mark.parametrize("case", ["version", "format", "shape", "escape_width", "dtype", "truncated", "no_axes"])
def test_bad_index_header(index_file, case):
    if case == "version":
        _set_attr(index_file, "format_version", np.int64(5))
    elif case == "format":
        _set_attr(index_file, "format", "isplat-augmented")
    elif case == "shape":
        _set_attr(index_file, "shape", np.array([4, 5, 7], "<i8"))
    elif case == "escape_width":
        with h5py.File(index_file, "r+") as f:
            f["axes"]["k"].attrs["escape_width"] = np.int64(2)
    elif case == "dtype":
        with h5py.File(index_file, "r+") as f:
            g = f["axes"]["j"]
            data = g["entry_slice"][()]
            del g["entry_slice"]
            g.create_dataset("entry_slice", data=data.astype(">u4"))
    elif case == "truncated":
        data = index_file.read_bytes()
        index_file.write_bytes(data[: len(data) // 3])
    elif case == "no_axes":
        with h5py.File(index_file, "r+") as f:
            for a in "ijk":
                del f["axes"][a]
    with pytest.raises(IsplatError) as exc:
        idx = open_index(index_file)
        idx.axis_info("j")          # an axis's datasets are checked on its first use (formats/index.md §1)
    assert str(index_file) in str(exc.value)


@pytest.mark.parametrize("hexbytes, count, n_a, n_b, ew, code", [
    ("0101", 1, 4, 4, 1, 1),          # too many voxels
    ("01", 2, 4, 4, 1, 2),            # too few
    ("0100", 2, 4, 4, 1, 3),          # escape truncated
    ("000102", 1, 4, 2, 1, 4),        # escape a=1, b=2 >= n_b=2
    ("000200", 1, 2, 2, 1, 4),        # escape a=2 >= n_a=2
    ("02000000", 2, 4, 4, 1, 5),      # escape back to 0 after 1: not increasing
    ("ff", 1, 4, 4, 1, 6),            # position 254 >= 16
    ("0000000100", 1, 300, 2, 2, 0),  # ok: a=0, b=1 -> 300
    ("000000020001", 1, 300, 2, 2, 4),  # b=2 >= n_b (ew 2)
])
def test_decoder_error_codes(hexbytes, count, n_a, n_b, ew, code):
    from isplat.index.codec import decode_blocks
    buf = np.frombuffer(bytes.fromhex(hexbytes), np.uint8)
    guard = np.full(count + 4, -9, np.int32)
    status, e = decode_blocks(buf, np.array([0]), np.array([buf.size]), np.array([count]), np.array([2]),
                              n_a, n_b, ew, guard)
    assert status == code and (e == 0 if code else e == -1)
    assert guard[0] == -9 and guard[1] == -9 and np.all(guard[2 + count:] == -9)   # nothing written outside


@pytest.mark.parametrize("hexbytes, counts, code, e", [
    ("0101", [1], 1, 0),              # a byte left over after the last block
    ("01", [2], 2, 0),                # runs out
    ("0102", [1, 1], 0, -1),          # two blocks, implied boundary
    ("010001", [1, 1], 3, 1),         # second block's escape truncated
    ("0201", [1, 1], 0, -1),
    ("0101", [2, 1], 2, 1),           # too few for the second block
])
def test_stream_decoder(hexbytes, counts, code, e):
    from isplat.index.codec import decode_stream
    buf = np.frombuffer(bytes.fromhex(hexbytes), np.uint8)
    cnt = np.array(counts, np.int64)
    dest = np.concatenate([[0], np.cumsum(cnt)[:-1]]).astype(np.int64) + 1
    out = np.full(cnt.sum() + 2, -9, np.int32)
    status, got_e = decode_stream(buf, cnt, dest, 4, 4, 1, out)
    assert (status, got_e) == (code, e)
    assert out[0] == -9 and out[-1] == -9
