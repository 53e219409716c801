"""Property tests: the compiled encoder/decoder against a slow, obvious reference (paper §2.3)."""

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from isplat.index import build_index, escape_width, normalize_ranges, open_index, write_index
from isplat.index.codec import decode_blocks

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# ------------------------------------------------------------------ reference (pure Python, no numpy tricks)

def ref_slice(vol, axis, s):
    """Slice s as [b, a]: k -> (j, i), j -> (k, i), i -> (k, j)."""
    n_k, n_j, n_i = vol.shape
    if axis == "k":
        return [[int(vol[s, j, i]) for i in range(n_i)] for j in range(n_j)]
    if axis == "j":
        return [[int(vol[k, s, i]) for i in range(n_i)] for k in range(n_k)]
    return [[int(vol[k, j, s]) for j in range(n_j)] for k in range(n_k)]


def ref_encode(positions, n_a, n_b):
    ew = 1 if (n_a <= 256 and n_b <= 256) else 2
    out = bytearray()
    prev = -1
    for p in positions:
        off = p - prev
        if 1 <= off <= 255:
            out.append(off)
        else:
            out.append(0)
            out += (p % n_a).to_bytes(ew, "little") + (p // n_a).to_bytes(ew, "little")
        prev = p
    return bytes(out)


def ref_decode(data, n_a, n_b):
    ew = 1 if (n_a <= 256 and n_b <= 256) else 2
    out, prev, c = [], -1, 0
    while c < len(data):
        if data[c]:
            p = prev + data[c]
            c += 1
        else:
            a = int.from_bytes(data[c + 1:c + 1 + ew], "little")
            b = int.from_bytes(data[c + 1 + ew:c + 1 + 2 * ew], "little")
            p = a + b * n_a
            c += 1 + 2 * ew
        out.append(p)
        prev = p
    return out


def ref_index(vol, axis, ranges):
    """Reference tables of one axis: density-major entries."""
    slices = {"k": vol.shape[0], "j": vol.shape[1], "i": vol.shape[2]}[axis]
    ptr, sl, cnt, off, data = [0], [], [], [0], b""
    for d in range(256):
        if any(lo <= d <= hi for lo, hi in ranges):
            for s in range(slices):
                rows = ref_slice(vol, axis, s)
                n_b, n_a = len(rows), len(rows[0])
                pos = [a + b * n_a for b in range(n_b) for a in range(n_a) if rows[b][a] == d]
                if pos:
                    blk = ref_encode(pos, n_a, n_b)
                    assert ref_decode(blk, n_a, n_b) == pos
                    sl.append(s)
                    cnt.append(len(pos))
                    data += blk
                    off.append(len(data))
        ptr.append(len(sl))
    return ptr, sl, cnt, off, data


# ------------------------------------------------------------------ strategies

shapes = st.one_of(
    st.tuples(st.integers(1, 5), st.integers(1, 5), st.integers(1, 6)),
    st.sampled_from([(3, 2, 300), (2, 260, 3), (1, 1, 600), (2, 3, 257)]),
)


@st.composite
def volumes(draw):
    shape = draw(shapes)
    n = int(np.prod(shape))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    kind = draw(st.sampled_from(["few", "sparse", "any"]))
    if kind == "few":        # a handful of densities: long blocks, mostly one-byte offsets
        vals = rng.choice(np.array(draw(st.lists(st.integers(0, 255), min_size=1, max_size=4)), np.uint8), n)
    elif kind == "sparse":   # background 0 with rare voxels: long gaps, escapes
        vals = np.where(rng.random(n) < draw(st.floats(0.0, 0.05)), rng.integers(1, 256, n), 0)
    else:
        vals = rng.integers(0, 256, n)
    return vals.astype(np.uint8).reshape(shape)


intervals = st.lists(st.tuples(st.integers(0, 255), st.integers(0, 255)).map(lambda t: (min(t), max(t))),
                     min_size=1, max_size=3)


# ------------------------------------------------------------------ properties

@SETTINGS
@given(volumes(), st.one_of(st.none(), intervals))
def test_encoder_matches_reference_byte_for_byte(vol, ranges):
    norm = normalize_ranges(ranges)
    index = build_index(vol, "ijk", ranges)
    for axis, ax in index.items():
        ptr, sl, cnt, off, data = ref_index(vol, axis, norm)
        assert ax.density_entry_ptr.tolist() == ptr
        assert ax.entry_slice.tolist() == sl
        assert ax.entry_voxel_count.tolist() == cnt
        assert ax.entry_byte_offset.tolist() == off
        assert ax.bytes.tobytes() == data
        assert ax.escape_width == escape_width(ax.n_a, ax.n_b)


@SETTINGS
@given(volumes(), st.one_of(st.none(), intervals), st.data())
def test_loaded_positions_equal_flatnonzero(vol, ranges, data):
    norm = normalize_ranges(ranges)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "v.idx.h5"
        write_index(path, build_index(vol, "ijk", ranges), vol.shape, "0" * 64, ranges)
        idx = open_index(path)
        # load a random sub-interval of an indexed range
        lo, hi = data.draw(st.sampled_from(norm))
        a = data.draw(st.integers(lo, hi))
        b = data.draw(st.integers(a, hi))
        for axis in "ijk":
            loaded = idx.load_axis(axis, [(a, b)])
            assert loaded.bytes_read == idx.nbytes(axis, [(a, b)])
            strict = idx.load_axis(axis, [(a, b)], verify_offsets=True)
            assert strict.bytes_read == idx.nbytes(axis, [(a, b)], verify_offsets=True)
            for key in ("slice_block_ptr", "block_density", "block_voxel_ptr", "positions"):
                assert np.array_equal(getattr(strict, key), getattr(loaded, key))
            assert loaded.positions.dtype == np.int32
            for s in range(loaded.n_slices):
                sl = np.asarray(ref_slice(vol, axis, s)).ravel()
                r0, r1 = loaded.slice_block_ptr[s], loaded.slice_block_ptr[s + 1]
                dens = loaded.block_density[r0:r1]
                assert np.all(np.diff(dens.astype(int)) > 0)
                want = [d for d in range(a, b + 1) if np.any(sl == d)]
                assert dens.tolist() == want
                for r in range(r0, r1):
                    got = loaded.positions[loaded.block_voxel_ptr[r]:loaded.block_voxel_ptr[r + 1]]
                    assert np.array_equal(got, np.flatnonzero(sl == loaded.block_density[r]))
        counts = idx.voxel_counts("k")
        for d in range(256):
            want = int(np.sum(vol == d)) if any(lo <= d <= hi for lo, hi in norm) else 0
            assert counts[d] == want


@SETTINGS
@given(st.lists(st.integers(0, 2047 + 2048 * 3), unique=True, min_size=1, max_size=50).map(sorted))
def test_decoder_matches_reference_2048_wide(pos):
    n_a, n_b = 2048, 4
    blk = ref_encode(pos, n_a, n_b)
    buf = np.frombuffer(blk, np.uint8)
    out = np.full(len(pos), -7, np.int32)
    status, e = decode_blocks(buf, np.array([0]), np.array([len(buf)]), np.array([len(pos)]), np.array([0]),
                              n_a, n_b, 2, out)
    assert status == 0 and out.tolist() == pos == ref_decode(blk, n_a, n_b)


def test_unindexed_density_is_refused(tmp_path):
    vol = np.arange(24, dtype=np.uint8).reshape(2, 3, 4)
    write_index(tmp_path / "x.h5", build_index(vol, "k", [(0, 9), (20, 30)]), vol.shape, "0" * 64, [(0, 9), (20, 30)])
    idx = open_index(tmp_path / "x.h5")
    assert idx.load_axis("k", [(0, 3), (21, 25)]).n_voxels == 4 + 3
    from isplat.errors import IsplatError
    with pytest.raises(IsplatError, match="density 10 .*not indexed"):
        idx.load_axis("k", [(5, 12)])
    with pytest.raises(IsplatError, match="axis 'j' is not in this index"):
        idx.load_axis("j", [(0, 3)])
