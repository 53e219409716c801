"""Bytes needed per technique (docs/stats.md): post's quad footprint and both techniques' bytes against slow,
obvious numpy references on small volumes."""

import numpy as np
from hypothesis import given, settings, strategies as st

from isplat.scene import parse_scene
from isplat.selection import Selection
from isplat.stats import quad_footprint_per_slice

# slice axis -> (a, b, c) as dimensions of the [k, j, i] array
DIMS = {"k": (2, 1, 0), "j": (2, 0, 1), "i": (1, 0, 2)}


def reference_footprint(density, intervals, axis) -> np.ndarray:
    """Per slice of ``axis``: the voxels read by the quads a voxel of interest belongs to, one quad at a time.
    Quad (qa, qb), 0 <= qa < n_a, 0 <= qb < n_b, reads voxels qa, min(qa + 1, n_a - 1) by qb, min(qb + 1,
    n_b - 1) (isplat.splat.post._sample: the step is 0 at the volume's edge); it is sampled when one of them is
    of interest."""
    da, db, dc = DIMS[axis]
    d = np.transpose(density, (dc, da, db))           # [c, a, b]
    interest = np.zeros(d.shape, dtype=bool)
    for lo, hi in intervals:
        interest |= (d >= lo) & (d <= hi)
    n_c, n_a, n_b = d.shape
    out = np.zeros(n_c, dtype=np.int64)
    for c in range(n_c):
        read = set()
        for qa in range(n_a):
            for qb in range(n_b):
                corners = {(a, b) for a in (qa, min(qa + 1, n_a - 1)) for b in (qb, min(qb + 1, n_b - 1))}
                if any(interest[c, a, b] for a, b in corners):
                    read |= corners
        out[c] = len(read)
    return out


volumes = st.tuples(st.integers(1, 6), st.integers(1, 6), st.integers(1, 6), st.integers(0, 2 ** 32 - 1),
                    st.floats(0.0, 1.0))


def _volume(shape_seed):
    nk, nj, ni, seed, p = shape_seed
    rng = np.random.default_rng(seed)
    d = np.where(rng.random((nk, nj, ni)) < p, rng.integers(150, 256, (nk, nj, ni)),
                 rng.integers(0, 150, (nk, nj, ni))).astype(np.uint8)
    return d, rng


@settings(max_examples=60, deadline=None)
@given(volumes, st.sampled_from("ijk"))
def test_quad_footprint_equals_quad_by_quad_reference(v, axis):
    d, _ = _volume(v)
    ivs = [(150, 200), (230, 255)]
    assert np.array_equal(quad_footprint_per_slice(d, ivs, axis), reference_footprint(d, ivs, axis))


def test_quad_footprint_across_the_dilation_slabs(monkeypatch):
    """Volumes taller than the k-slabs the footprint is counted in: slab edges change nothing."""
    import isplat.stats as stats

    monkeypatch.setattr(stats, "FOOTPRINT_SLAB", 2)
    d, _ = _volume((7, 4, 5, 3, 0.2))
    for axis in "ijk":
        want = reference_footprint(d, [(150, 255)], axis)
        assert np.array_equal(quad_footprint_per_slice(d, [(150, 255)], axis), want)


def _scene(technique, shaded):
    return parse_scene(f'version = 4\n[transfer]\nopacity = [[150, 0], [151, 0.8], [255, 0.8]]\n[shading]\nenabled = '
                       f'{"true" if shaded else "false"}\n[render]\nclassification = "{technique}"', ".", "t",
                       data_required=False)


@settings(max_examples=25, deadline=None)
@given(volumes, st.sampled_from(["pre", "post"]), st.booleans(), st.sampled_from(["i", "k", "ijk"]))
def test_bytes_needed_per_technique(v, technique, shaded, axes):
    d, rng = _volume(v)
    nrm = rng.integers(0, 65536, d.shape).astype(np.uint16)
    gm = rng.integers(0, 256, d.shape).astype(np.uint8)
    sel = Selection.from_arrays(d, _scene(technique, shaded), normal=nrm, gradient_magnitude=gm,
                                gradient_magnitude_scale=1.0, spacing=(1.0, 1.0, 1.0), window=(0.0, 255.0), axes=axes)
    rep = sel.report
    ivs = [(151, 255)]
    voi = int((d >= 151).sum())
    assert rep.technique == technique and rep.voxels_of_interest == voi
    if technique == "pre":      # the voxels of interest x their normal (2 B) when shaded; density is the index's
        assert rep.needed_voxels == voi and rep.needed_axis == ""
        assert rep.bytes_needed == voi * (2 if shaded else 0) + rep.index_bytes_needed
        return
    per_axis = {a: int(reference_footprint(d, ivs, a).sum()) for a in axes}
    want = max(per_axis.values()) if voi else voi
    assert rep.needed_voxels == want                  # the axis where the quads read most
    if voi:
        assert per_axis[rep.needed_axis] == want
    per_voxel = 1 + (3 if shaded else 0)              # density, + normal 2 B and gradient magnitude 1 B
    assert rep.bytes_needed == want * per_voxel + rep.index_bytes_needed


def test_worker_report_pickles_its_count_not_the_density():
    import pickle

    d, rng = _volume((12, 12, 12, 1, 0.3))
    sel = Selection.from_arrays(d, _scene("post", False), spacing=(1.0, 1.0, 1.0), window=(0.0, 255.0), axes="k")
    blob = pickle.dumps(sel.report)
    want = int(reference_footprint(d, [(151, 255)], "k").sum())
    assert len(blob) < d.size and pickle.loads(blob).needed_voxels == want


@settings(max_examples=200, deadline=None)
@given(st.lists(st.one_of(
    st.tuples(st.just("read"), st.integers(0, 60000), st.integers(0, 9000)),
    st.tuples(st.just("rows"), st.integers(0, 9000), st.integers(1, 5000),
              st.lists(st.integers(0, 40), max_size=6)),
    st.just(("mark",))), max_size=12))
def test_read_counter_pages_are_the_set_of_pages_read(ops):
    """ReadCounter's pages (a flag per page, marks as copies) against the set of every page of every read."""
    from isplat.fileio import PAGE, ReadCounter

    c, seen, marks = ReadCounter(), set(), []
    for op in ops:
        if op[0] == "read":
            c.touch(op[1], op[2])
            seen |= set(range(op[1] // PAGE, (op[1] + op[2] - 1) // PAGE + 1)) if op[2] else set()
        elif op[0] == "rows":
            _, off, size, rows = op
            c.touch_rows(off, size, np.array(rows, dtype=np.int64))
            for r in rows:
                seen |= set(range((off + r * size) // PAGE, (off + (r + 1) * size - 1) // PAGE + 1))
        else:
            marks.append((c.mark(), set(seen)))
    assert c.page_bytes() == len(seen) * PAGE
    for m, before in marks:
        assert c.page_bytes(m) == len(seen - before) * PAGE


def test_read_counter_pages_of_reads_and_rows():
    """A read's pages, rows of a table, and the reads after a mark; unknown once a read was not seen."""
    from isplat.fileio import PAGE, ReadCounter

    c = ReadCounter()
    c.touch(4000, 200)                   # pages 0 and 1
    m = c.mark()
    c.touch_rows(8192, 100, np.array([0, 1, 50]))     # rows 0, 1: page 2; row 50 (5000..5099 from 8192): page 3
    c.touch(0, 0)
    assert c.page_bytes() == 4 * PAGE and c.page_bytes(m) == 2 * PAGE
    c.pages_known = False
    assert c.page_bytes() == -1
