"""Post reads only the bricks its quads touch (augmented format 6, isplat's brick store, formats/augmented.md §2.3,
and format 5, bricks as HDF5 chunks, §2.2): the image is bit for bit the image of the whole channels (the same
volume written as version 4), for views along every axis, orthographic and perspective, shaded and not, the cubic
between thick slices, slab by slab; corrupted bricks are refused, and the bytes read are the bricks read."""

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import write_volume
from isplat.augfile import open_augmented, write_augmented
from isplat.errors import IsplatError

SHAPE = (37, 34, 41)        # (k, j, i): not multiples of 8, so edge bricks are partial


def _shell(shape, centre, radius, width, rng):
    k, j, i = np.meshgrid(*[np.arange(n) for n in shape], indexing="ij")
    r = np.sqrt((k - centre[0]) ** 2 + (j - centre[1]) ** 2 + (i - centre[2]) ** 2)
    d = np.clip(220 - np.abs(r - radius) * (180 / width), 0, 255) + rng.normal(0, 6, shape)
    return np.clip(d, 0, 255).astype(np.uint8)


def _pair(tmp, density, spacing, rng, name="v", v5=False):
    """The volume as version 6 (with its index) and as version 4 (whole channels): (v6, v4, index); ``v5``: + the
    volume as version 5 (last)."""
    from isplat.normals import encode

    gm = rng.integers(0, 256, density.shape).astype(np.uint8)
    nrm = encode(rng.normal(size=density.shape + (3,)))
    aug, idx = write_volume(tmp, density, spacing=spacing, gm=gm, normal=nrm, gscale=0.5, name=name)
    old = tmp / f"{name}.v4.aug.h5"
    write_augmented(old, density, gm, nrm, spacing, (0.0, 255.0), 0.5, version=4)
    if not v5:
        return aug, old, idx
    five = tmp / f"{name}.v5.aug.h5"
    write_augmented(five, density, gm, nrm, spacing, (0.0, 255.0), 0.5, version=5)
    return aug, old, idx, five


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    rng = np.random.default_rng(7)
    tmp = tmp_path_factory.mktemp("bricks")
    dens = _shell(SHAPE, (15, 17, 22), 9, 2.5, rng)
    iso = _pair(tmp, dens, (1.0, 1.0, 1.0), rng, "iso", v5=True)
    thick = _pair(tmp, dens, (0.8, 0.8, 4.0), rng, "thick", v5=True)   # k 5x the finest: the cubic between slices
    return {"iso": iso[:3], "thick": thick[:3], "iso5": (iso[3],) + iso[1:3], "thick5": (thick[3],) + thick[1:3]}


def _scene(make_scene, aug, idx, proj, cam, shaded, lo=150, spacing=(1.0, 1.0, 1.0)):
    cam = _inside(spacing) if cam == "INSIDE" else cam
    return make_scene(aug, idx, image="width = 40\nheight = 36", camera=f'projection = "{proj}"\n{cam}',
                      transfer=f"opacity = [[{lo - 10}, 0.0], [{lo}, 0.6], [255, 0.9]]",
                      shading=f"enabled = {'true' if shaded else 'false'}",
                      render='method = "indexed"\nthreads = 1\nclassification = "post"')


CAMS = [("orthographic", "azimuth = 0\nelevation = 10"), ("orthographic", "azimuth = 80\nelevation = 20"),
        ("orthographic", "azimuth = 30\nelevation = 75"), ("perspective", "azimuth = 200\nelevation = -30"),
        ("perspective", "INSIDE")]


def _inside(spacing):
    """An eye at the shell's centre (inside the volume), looking along +j and a little down."""
    c = (np.asarray([22, 17, 15]) - (np.asarray(SHAPE[::-1]) - 1) / 2) * np.asarray(spacing)   # world: centred
    return f'mode = "look_at"\nposition = {c.tolist()}\nlook_at = {(c + [3, 20, -4]).tolist()}'


SPACING = {"iso": (1.0, 1.0, 1.0), "thick": (0.8, 0.8, 4.0), "iso5": (1.0, 1.0, 1.0), "thick5": (0.8, 0.8, 4.0)}


@pytest.mark.parametrize("kind", ["iso", "thick", "iso5", "thick5"])
@pytest.mark.parametrize("proj,cam", CAMS)
@pytest.mark.parametrize("shaded", [True, False])
def test_bricks_render_the_image_of_the_whole_channels(make_scene, files, kind, proj, cam, shaded):
    from isplat.renderer import Renderer

    aug, old, idx = files[kind]
    new_r, old_r = Renderer(_scene(make_scene, aug, idx, proj, cam, shaded, spacing=SPACING[kind])), \
        Renderer(_scene(make_scene, old, idx, proj, cam, shaded, spacing=SPACING[kind]))
    got, st_new = new_r.render_view(0)
    want, st_old = old_r.render_view(0)
    assert st_old.drawn > 0 and np.array_equal(got, want)
    rep, whole = new_r.report, old_r.report
    assert rep.values_from.startswith("bricks") and whole.values_from == "whole channels"
    assert rep.augmented_bytes < whole.augmented_bytes
    assert rep.needed_voxels == whole.needed_voxels


def test_a_composite_scene_pools_its_bricks_and_an_intensity_projection_does_not(make_scene, files):
    """Post's bricks from a format 6 file are held as a pool behind a brick table for a composite scene (a third
    to a quarter of the memory of whole channels, docs/design.md "The brick pool"); an intensity projection of
    the same file and transfer function reads whole-shape channels, since its kernels index by strides and a pool
    made whole at its first frame would touch every page of the volume. The mode is in the request, so the two
    never share a selection; each draws what it drew from whole channels."""
    from isplat.renderer import Renderer

    aug, old, idx = files["iso"]
    render = 'method = "indexed"\nthreads = 1\nclassification = "post"'
    comp, comp_old = (Renderer(_scene(make_scene, a, idx, "orthographic", CAMS[0][1], True)) for a in (aug, old))
    mip, mip_old = (Renderer(make_scene(a, idx, image="width = 40\nheight = 36", render=render + '\nmode = "mip"',
                                        transfer="opacity = [[140, 0.0], [150, 0.6], [255, 0.9]]"))
                    for a in (aug, old))
    for r, whole in ((comp, comp_old), (mip, mip_old)):
        got, _ = r.render_view(0)
        assert np.array_equal(got, whole.render_view(0)[0])
    assert comp.request != mip.request and comp.request.mode == "composite" and mip.request.mode == "mip"
    assert comp.selection.whole.pooled and comp.report.values_from.startswith("bricks")
    assert not mip.selection.whole.pooled and not mip.selection.whole._flat
    pool = comp.selection.whole
    assert pool.held_bytes() == sum(a.nbytes for a in pool.arrays()) + pool.table.nbytes + pool.deltas().nbytes


def test_thick_scene_uses_the_cubic(files):
    from isplat.splat.post import between_slices

    assert between_slices((0.8, 0.8, 4.0), "j")[0] != 0 and between_slices((0.8, 0.8, 4.0), "i")[0] != 0


def test_the_bytes_read_are_the_bricks_read(make_scene, files):
    from isplat.renderer import Renderer
    from isplat.selection import post_bricks

    aug, _, idx = files["iso"]
    r = Renderer(_scene(make_scene, aug, idx, *CAMS[0], True))
    r.render_view(0)
    rep = r.report
    a = open_augmented(aug)
    e = a.edge
    bricks = np.argwhere(post_bricks(r.selection, (e, e, e)))
    n = len(bricks)
    sizes = [np.prod([min(e, s - g * e) for g, s in zip(b, SHAPE)]) for b in bricks]
    assert rep.augmented_bytes == int(sum(sizes)) * 4                          # density + gm + 2-byte normal
    assert rep.augmented_file_bytes >= n * (e ** 3 * 4 + 24)                   # whole bricks + their hashes
    grid = [-(-s // e) for s in SHAPE]
    assert a.bricked and rep.values_from == f"bricks ({n:,} of {int(np.prod(grid)):,})"
    # the pages: those of the bricks and their hashes, each once (the obvious count), + the opening's
    rows = np.ravel_multi_index(tuple(bricks.T), grid)
    want = set()
    for ch in rep.channels:
        d_off, h_off, dt, _ = a.store[ch]
        size = e ** 3 * np.dtype(dt).itemsize
        for r_ in rows:
            for off, n_ in ((d_off + r_ * size, size), (h_off + r_ * 8, 8)):
                want |= set(range(off // 4096, (off + n_ - 1) // 4096 + 1))
    opening = open_augmented(aug)
    opening.read_bricks("density", np.zeros((0, 3), np.int64))
    got = rep.augmented_file_pages // 4096
    assert len(want) <= got <= len(want) + opening.io.page_bytes() // 4096 and got * 4096 == rep.augmented_file_pages
    assert rep.file_pages == rep.augmented_file_pages + rep.index_file_pages + rep.values_file_pages > 0


@pytest.mark.parametrize("share", [1.0, 0.0])
def test_slabs_read_their_bricks_and_draw_the_one_pass_frame(make_scene, files, monkeypatch, share):
    """Each slab reads its own slices' bricks (share 1: bricks however many are needed), or its slices' whole
    channels (share 0): the one-pass frame of the whole channels either way."""
    from isplat import selection as S
    from isplat.renderer import Renderer
    from isplat.slabs import render_streamed

    monkeypatch.setattr(S, "BRICK_SHARE", share)

    for kind in ("iso", "thick"):
        aug, old, idx = files[kind]
        for proj, cam in (CAMS[1], CAMS[4]):
            want = Renderer(_scene(make_scene, old, idx, proj, cam, True, spacing=SPACING[kind])).render_view(0)[0]
            r = Renderer(_scene(make_scene, aug, idx, proj, cam, True, spacing=SPACING[kind]))
            for k in (2, 3, 5):
                got, _, report = render_streamed(r.request, r.views[0], k)
                assert np.array_equal(got, want) and want[..., 3].any(), (kind, cam, k)
                # (the first slab's source; a slab needing no brick reads none either way)
                assert report.values_from.startswith("bricks") == (share == 1.0) or \
                    report.values_from.startswith("bricks (0 of")


@pytest.mark.slow
def test_dask_slabs_draw_the_one_pass_frame(make_scene, files, tmp_path):
    pytest.importorskip("distributed")
    from isplat.renderer import Renderer

    aug, old, idx = files["iso"]
    # (Dask's slabs differ from the one-pass frame by float rounding (< 0.01) for version 4 files too: compare
    # the slab workers' frames of the bricks with theirs of the whole channels)
    want = Renderer(_scene(make_scene, old, idx, *CAMS[1], True), slabs=3, scheduler="local:2").render_view(0)[0]
    r = Renderer(_scene(make_scene, aug, idx, *CAMS[1], True), slabs=3, scheduler="local:2")
    got = r.render_view(0)[0]
    assert np.array_equal(got, want) and want[..., 3].any()


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.integers(0, 2 ** 31), st.integers(40, 230), st.sampled_from(CAMS), st.booleans(),
       st.sampled_from([(1.0, 1.0, 1.0), (1.0, 0.9, 4.5), (4.2, 1.0, 1.0)]))
def test_random_volumes_render_alike_from_bricks(make_scene, tmp_path_factory, seed, lo, cam, shaded, spacing):
    """Random small volumes (random blobs, edge bricks, any transfer-function threshold): bricks or whole,
    the same image."""
    from isplat import selection as S
    from isplat.renderer import Renderer

    rng = np.random.default_rng(seed)
    shape = tuple(int(n) for n in rng.integers(9, 26, 3))
    dens = _shell(shape, [rng.uniform(0, n) for n in shape], rng.uniform(2, 8), rng.uniform(1, 3), rng)
    from isplat import augfile

    edge = augfile.BRICK_EDGE
    augfile.BRICK_EDGE = int(rng.choice([4, 8]))     # format 6 at either edge a file may have
    try:
        aug, old, idx = _pair(tmp_path_factory.mktemp("h"), dens, spacing, rng)
    finally:
        augfile.BRICK_EDGE = edge
    share = S.BRICK_SHARE
    S.BRICK_SHARE = 1.0                         # bricks however many are needed
    try:
        r = Renderer(_scene(make_scene, aug, idx, *cam, shaded, lo, spacing))
        got = r.render_view(0)[0]
    finally:
        S.BRICK_SHARE = share
    want = Renderer(_scene(make_scene, old, idx, *cam, shaded, lo, spacing)).render_view(0)[0]
    assert np.array_equal(got, want)
    assert r.report.values_from.startswith("bricks") or r.selection.empty


def _copy(src, dst):
    dst.write_bytes(src.read_bytes())
    return dst


def test_an_edited_brick_is_refused_not_rendered(make_scene, files, tmp_path):
    """Format 6: one byte of a brick flipped in the file (a density inside the shell), or a brick's bytes copied
    over its neighbour's: refused in one line naming file, channel and brick; the range table edited with its
    hashes recomputed: refused by the density's range check."""
    from isplat import chunkhash
    from isplat.augfile import hashed_attributes, hashed_datasets
    from isplat.renderer import Renderer

    aug, _, idx = files["iso"]
    a = open_augmented(aug)
    e = a.edge
    row = np.ravel_multi_index((15 // e, 17 // e, 31 // e), a.brick_range.shape[:3])
    start = a.store["density"][0] + row * e ** 3                   # brick `row`; the one before it is copied over it
    at = start + (15 % e) * e * e + (17 % e) * e + 31 % e
    raw = bytearray(aug.read_bytes())
    assert raw[at] == a.read("density")[15, 17, 31] and raw[at] > 0
    corner = r"\(" + ", ".join(str(x // e * e) for x in (15, 17, 31)) + r"\)"
    for what, edit in (("byte", lambda b: b.__setitem__(at, b[at] ^ 0x10)),
                       ("moved", lambda b: b.__setitem__(slice(start, start + e ** 3), b[start - e ** 3:start]))):
        bad = tmp_path / f"{what}.aug.h5"
        b = bytearray(raw)
        edit(b)
        bad.write_bytes(b)
        with pytest.raises(IsplatError, match=rf"{what}\.aug\.h5: dataset 'density', brick {row} at {corner}: its "
                                              rf"content does not match its hash in /brick_hashes/density .*rebuild"):
            Renderer(_scene(make_scene, bad, idx, *CAMS[0], True)).render_view(0)
    ranged = _copy(aug, tmp_path / "ranged.aug.h5")    # the range table edited, hashes recomputed
    with h5py.File(ranged, "a") as f:
        f["brick_range"][15 // e, 17 // e, 31 // e, 0] = 1
        del f["chunk_hashes"]
        del f.attrs["chunk_hash_check"]
        ds = hashed_datasets(False, 6)
        chunkhash.write_tables(f, a.density_sha256, ds, chunkhash.attributes_of(f, hashed_attributes(6)),
                               tables=["brick_range"])
    with pytest.raises(IsplatError, match=rf"brick at {corner}: densities .* /brick_range says 1\.\."):
        Renderer(_scene(make_scene, ranged, idx, *CAMS[0], True)).render_view(0)


def test_the_range_table_is_read_and_checked_on_first_use(files, tmp_path):
    """``/brick_range`` is read when a density brick is (post), not at open (pre does not need it): its bytes
    counted then, and a table whose smallest density exceeds its largest refused then, before any brick is
    checked against it (hashes recomputed, so only the rows' check can find it)."""
    from isplat import chunkhash
    from isplat.augfile import hashed_attributes, hashed_datasets

    aug = files["iso"][0]
    a = open_augmented(aug)
    opening = a.io.bytes
    assert a.bricked and a._brick_range is None
    with h5py.File(aug, "r") as f:
        stored = f["brick_range"].id.get_storage_size()
    a.read("density", 0, 8)
    assert a._brick_range is not None and a.io.bytes - opening >= stored + a.edge ** 3 * a.brick_grid[1] * \
        a.brick_grid[2]                                 # the table and a layer of bricks
    bad = _copy(aug, tmp_path / "minmax.aug.h5")
    with h5py.File(bad, "a") as f:
        f["brick_range"][0, 0, 0] = [9, 3]
        del f["chunk_hashes"]
        del f.attrs["chunk_hash_check"]
        chunkhash.write_tables(f, a.density_sha256, hashed_datasets(False, 6),
                               chunkhash.attributes_of(f, hashed_attributes(6)), tables=["brick_range"])
    b = open_augmented(bad)                             # the table's type and shape checked, its rows not yet
    assert b.read("gradient_magnitude", 0, 8).shape == (8,) + SHAPE[1:]
    with pytest.raises(IsplatError, match=r"minmax\.aug\.h5: dataset 'brick_range' holds a brick whose smallest "
                                          r"density exceeds its largest"):
        b.read("density", 0, 8)


def test_an_edited_chunk_brick_is_refused_not_rendered(make_scene, files, tmp_path):
    """Format 5: a density changed through HDF5 (Fletcher-32 valid), or the range table edited, refused."""
    from isplat.augfile import finish_augmented
    from isplat.renderer import Renderer

    aug, _, idx = files["iso5"]
    bad = _copy(aug, tmp_path / "bad.aug.h5")
    with h5py.File(bad, "a") as f:                     # a density inside the shell changed: Fletcher-32 valid
        f["density"][15, 17, 31] = 0
    with pytest.raises(IsplatError, match=r"dataset 'density', chunk at \(8, 16, 24\)"):
        Renderer(_scene(make_scene, bad, idx, *CAMS[0], True)).render_view(0)
    ranged = _copy(aug, tmp_path / "ranged.aug.h5")    # the range table edited, hashes recomputed
    with h5py.File(ranged, "a") as f:
        f["brick_range"][1, 2, 3, 0] = 1
        del f["chunk_hashes"]
        del f.attrs["chunk_hash_check"]
        finish_augmented(f)
    with pytest.raises(IsplatError, match=r"brick at \(8, 16, 24\): densities .* /brick_range says 1\.\."):
        Renderer(_scene(make_scene, ranged, idx, *CAMS[0], True)).render_view(0)


def test_a_bricked_file_refuses_other_chunks_and_a_bad_range_table(tmp_path):
    rng = np.random.default_rng(1)
    dens = rng.integers(0, 256, (10, 9, 17)).astype(np.uint8)
    for version, e, grid in ((5, 8, (2, 2, 3)), (6, 4, (3, 3, 5)), (6, 8, (2, 2, 3))):
        aug = tmp_path / f"v{version}-{e}.aug.h5"
        write_augmented(aug, dens, dens, np.zeros(dens.shape, np.uint16), (1, 1, 1), (0, 255), 1.0, version=version,
                        edge=e)
        a = open_augmented(aug)
        assert a.bricks == (e, e, e) and a.brick_range.shape == grid + (2,)
        assert a.brick_range[0, 0, 0].tolist() == [int(dens[:e, :e, :e].min()), int(dens[:e, :e, :e].max())]
        assert a.brick_range[-1, -1, -1].tolist() == [int(dens[(grid[0] - 1) * e:, (grid[1] - 1) * e:,
                                                                (grid[2] - 1) * e:].min()),
                                                      int(dens[(grid[0] - 1) * e:, (grid[1] - 1) * e:,
                                                               (grid[2] - 1) * e:].max())]
        b = _copy(aug, tmp_path / "b.aug.h5")
        with h5py.File(b, "a") as f:
            del f["brick_range"]
            f.create_dataset("brick_range", data=np.zeros((2, 2, 2, 2), np.uint8), chunks=(1, 2, 2, 2),
                             fletcher32=True)
        with pytest.raises(IsplatError, match=rf"'brick_range' is uint8 \(2, 2, 2, 2\), expected uint8 "
                                              rf"\({grid[0]}, {grid[1]}, {grid[2]}, 2\)"):
            open_augmented(b)


def test_format_6_refuses_a_store_it_cannot_read_safely(tmp_path):
    """Every size and place of the store is checked at open, before compiled code reads through it: a channel or
    hash table of the wrong shape, a channel stored chunked, a file cut short."""
    dens = np.random.default_rng(2).integers(0, 256, (10, 9, 17)).astype(np.uint8)
    aug = tmp_path / "v.aug.h5"
    write_augmented(aug, dens, dens, np.zeros(dens.shape, np.uint16), (1, 1, 1), (0, 255), 1.0, edge=4)
    cases = {"table": lambda f: (f["brick_hashes"].__delitem__("normal"),
                                 f["brick_hashes"].create_dataset("normal", data=np.zeros(44, "<u8"))),
             "chunked": lambda f: (f.__delitem__("gradient_magnitude"),
                                   f.create_dataset("gradient_magnitude", (45, 4, 4, 4), "|u1", chunks=(1, 4, 4, 4)))}
    msgs = {"table": r"dataset 'brick_hashes/normal' is uint64 \(44,\), expected uint64 \(45,\)",
            "chunked": r"dataset 'gradient_magnitude' is not stored contiguous, whole, inside the file"}
    for name, edit in cases.items():
        b = _copy(aug, tmp_path / f"{name}.aug.h5")
        with h5py.File(b, "a") as f:
            edit(f)
        with pytest.raises(IsplatError, match=msgs[name]):
            open_augmented(b)
    a = open_augmented(aug)
    cut = tmp_path / "cut.aug.h5"
    cut.write_bytes(aug.read_bytes()[:a.store["normal"][0] + 100])
    with pytest.raises(IsplatError, match=r"cut\.aug\.h5"):
        open_augmented(cut).read("normal")


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 64 - 1), st.integers(0, 10 ** 6), st.sampled_from([64, 128, 512, 1024]),
       st.integers(0, 2 ** 31), st.data())
def test_brick_hash_is_the_reference_and_sees_any_word_changed(seed, row, size, data_seed, data):
    """The compiled brick hash is the plain one of formats/augmented.md §2.3; a brick with one 8-byte word changed,
    or read at another row, hashes differently (each step is a bijection of the state)."""
    from fuzzlab import brick_hash as hash_reference
    from isplat.brickstore import hash_bricks

    raw = np.random.default_rng(data_seed).integers(0, 256, size, dtype=np.uint8)
    got = int(hash_bricks(raw.view("<u8").reshape(1, -1), np.array([row]), np.uint64(seed))[0])
    assert got == hash_reference(raw.tobytes(), row, seed)
    w = data.draw(st.integers(0, size // 8 - 1))
    other = raw.copy()
    other[w * 8 + data.draw(st.integers(0, 7))] ^= np.uint8(data.draw(st.integers(1, 255)))
    assert hash_reference(other.tobytes(), row, seed) != got
    assert hash_reference(raw.tobytes(), row + 1, seed) != got


def test_old_files_are_read_whole(files):
    aug, old, _ = files["iso"]
    a, o, five = open_augmented(aug), open_augmented(old), open_augmented(files["iso5"][0])
    assert o.format_version == 4 and not o.bricked and a.format_version == 6 and a.bricked
    assert five.format_version == 5 and five.bricked and five.bricks == (8, 8, 8)
    for ch in ("density", "gradient_magnitude", "normal"):
        assert np.array_equal(a.read(ch), o.read(ch)) and np.array_equal(five.read(ch), o.read(ch))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.integers(0, 2 ** 31), st.tuples(st.integers(1, 20), st.integers(1, 20), st.integers(1, 27)),
       st.floats(0.05, 1.0), st.sampled_from([1, 700, 3000, None]))
def test_read_bricks_holds_exactly_the_bricks_asked(tmp_path_factory, seed, shape, share, window):
    """read_bricks: the bricks asked, zeros elsewhere, whatever part of the store is mapped at a time
    (``window``: augfile.STORE_WINDOW, from one brick a map to the default)."""
    import isplat.augfile as augfile

    rng = np.random.default_rng(seed)
    dens = rng.integers(0, 256, shape).astype(np.uint8)
    aug, _ = write_volume(tmp_path_factory.mktemp("rb"), dens, index=False)
    a = open_augmented(aug)
    old_window = augfile.STORE_WINDOW
    augfile.STORE_WINDOW = window or old_window
    try:
        _check_read_bricks(a, dens, shape, rng, share)
    finally:
        augfile.STORE_WINDOW = old_window


def _check_read_bricks(a, dens, shape, rng, share):
    grid = a.brick_range.shape[:3]
    want = rng.random(grid) < share
    got = a.read_bricks("density", np.argwhere(want))
    mask = np.kron(want, np.ones(a.bricks, bool))[:shape[0], :shape[1], :shape[2]]
    assert np.array_equal(got, np.where(mask, dens, 0)) and a.bytes_read == int(mask.sum())
    lo = tuple(int(rng.integers(0, n)) for n in shape)            # a box of it (a slab's block)
    hi = tuple(int(rng.integers(x + 1, n + 1)) for x, n in zip(lo, shape))
    box = a.read_bricks("density", np.argwhere(want), (lo, hi))
    assert np.array_equal(box, np.where(mask, dens, 0)[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]])


@pytest.mark.parametrize("kind", ["iso", "iso5"])
def test_blocks_of_every_channel_read_from_bricks_equal_whole_channels(files, kind):
    """Versions 6 and 5 read blocks (slabs, a slab's rows, the whole) brick by brick: the same values as version 4."""
    aug, old, _ = files[kind]
    a, o = open_augmented(aug), open_augmented(old)
    rng = np.random.default_rng(3)
    blocks = [(), (slice(8, 16),), (slice(3, 30), slice(5, 6)), (slice(36, 37), slice(0, 34), slice(33, 41))]
    for _ in range(6):
        lo = [int(rng.integers(0, n)) for n in SHAPE]
        blocks.append(tuple(slice(x, int(rng.integers(x + 1, n + 1))) for x, n in zip(lo, SHAPE)))
    for block in blocks:
        for ch in ("density", "gradient_magnitude", "normal"):
            got, want = a.read_block(ch, block), o.read_block(ch, block)
            assert got.dtype == want.dtype and np.array_equal(got, want), (ch, block)


def test_a_brick_stored_without_its_checksum_is_refused(files, tmp_path):
    """Bricks are read raw (formats/augmented.md §1): one whose Fletcher-32 was skipped (filter mask 1, 4 bytes
    short) cannot be read as the spec says and is refused with the dataset, the brick and the rebuild command."""
    aug, _, _ = files["iso5"]
    bad = _copy(aug, tmp_path / "mask.aug.h5")
    with h5py.File(bad, "a") as f:
        _, raw = f["normal"].id.read_direct_chunk((8, 16, 24))
        f["normal"].id.write_direct_chunk((8, 16, 24), raw[:-4], filter_mask=1)
    a = open_augmented(bad)
    a.read_bricks("normal", np.array([[0, 0, 0]]))                   # the other bricks still read
    with pytest.raises(IsplatError, match=r"mask\.aug\.h5: dataset 'normal', chunk at \(8, 16, 24\): stored as "
                                          r"1024 bytes with filter mask 1, .* rebuild it: isplat augment"):
        a.read_bricks("normal", np.array([[1, 2, 3]]))
    with pytest.raises(IsplatError, match=r"dataset 'normal', chunk at \(8, 16, 24\)"):
        a.verify_all()


@pytest.mark.parametrize("kind", ["thick", "thick5"])
def test_the_index_of_a_bricked_file_is_the_index_of_its_whole_channels(files, tmp_path, kind):
    """isplat index reads version 6's (and 5's) bricks (hashed, ranges checked) in k-slabs: the same index as
    from v4."""
    from isplat.index import build_index_file

    aug, old, _ = files[kind]
    built = {}
    for name, src in (("new", aug), ("old", old)):
        build_index_file(src, tmp_path / f"{name}.idx.h5", force=True, slab_voxels=5 * SHAPE[1] * SHAPE[2])
        with h5py.File(tmp_path / f"{name}.idx.h5") as f:
            names = []
            f.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) else None)
            built[name] = {n: f[n][()] for n in names}
    assert built["new"].keys() == built["old"].keys() and len(built["new"]) > 5
    for n, v in built["new"].items():
        assert np.array_equal(v, built["old"][n]), n



def test_augment_writes_bricks_unless_asked_for_rows(tmp_path):
    """`isplat augment` writes format 6 (isplat's brick store, 8^3) by default and format 4 (whole rows) with
    --rows; the channels are the same either way."""
    from click.testing import CliRunner

    from isplat.cli.main import cli

    np.save(tmp_path / "v.npy", _shell(SHAPE, (15, 17, 22), 9, 2.5, np.random.default_rng(3)))
    files = {}
    for flag, version in (([], 6), (["--rows"], 4), (["--bricks"], 6)):
        out = tmp_path / f"v{version}{''.join(flag)}.aug.h5"
        r = CliRunner().invoke(cli, ["augment", str(tmp_path / "v.npy"), "-o", str(out), "-q"] + flag)
        assert r.exit_code == 0, r.output
        files[version] = a = open_augmented(out)
        assert a.format_version == version and a.bricked == (version == 6)
        assert version == 4 or a.bricks == (8, 8, 8)
    for ch in ("density", "gradient_magnitude", "normal"):
        assert np.array_equal(files[4].read(ch, 0, SHAPE[0]), files[6].read(ch, 0, SHAPE[0])), ch


@pytest.mark.parametrize("window", [600, 1600, 5000])
def test_the_store_is_read_through_windows_of_any_size(tmp_path, window, monkeypatch):
    """augfile.STORE_WINDOW (the part of the file mapped at a time, so that a 1024^3 channel is read within a 2 GiB
    address space): windows of 1, 3 and 9 density bricks, subsets of 36 bricks: each read equals the volume's
    bricks, on every channel (normal bricks: 1024 B)."""
    import isplat.augfile as augfile

    rng = np.random.default_rng(window)
    shape = (20, 20, 27)                                      # 3 x 3 x 4 bricks of 8^3
    dens = rng.integers(0, 256, shape).astype(np.uint8)
    nrm = rng.integers(0, 65536, shape).astype(np.uint16)
    aug, _ = write_volume(tmp_path, dens, normal=nrm, index=False)
    monkeypatch.setattr(augfile, "STORE_WINDOW", window)
    a = open_augmented(aug)
    for share in (0.2, 0.5, 1.0):
        want = rng.random(a.brick_range.shape[:3]) < share
        mask = np.kron(want, np.ones(a.bricks, bool))[:shape[0], :shape[1], :shape[2]]
        for ch, vol in (("density", dens), ("normal", nrm)):
            got = a.read_bricks(ch, np.argwhere(want)[::-1])           # in any order
            assert np.array_equal(got, np.where(mask, vol, 0)), (ch, share)


@pytest.mark.parametrize("axis", ["k", "j", "i"])
def test_a_slab_pools_its_own_bricks(make_scene, files, axis, monkeypatch):
    """A slab of a composite scene from a format 6 file holds its bricks as a pool too (issue 26 item 5): its
    rows are bricks that meet its slices, fewer than the one-pass pool's, and the sampler's offsets of a voxel of
    the slab read the density the one-pass pool reads there."""
    import dataclasses

    from isplat import grid
    from isplat import selection as S
    from isplat.renderer import Renderer
    from isplat.selection import select

    monkeypatch.setattr(S, "BRICK_SHARE", 1.0)             # (bricks however many: a small volume)
    from isplat.augfile import open_augmented

    aug, old, idx = files["iso"]
    r = Renderer(_scene(make_scene, aug, idx, "orthographic", CAMS[0][1], True, lo=215))   # (few bricks show)
    one = select(dataclasses.replace(r.request, axes=axis))
    n_c = grid.slice_shape(one.shape, axis)[0]
    c0, c1 = 3, n_c // 3 + 1                        # (the near edge of the shell: fewer bricks than the whole)
    slab = select(dataclasses.replace(r.request, axes=axis, slab=((c0, c1),)))
    assert slab.slab == (axis, c0, c1) and slab.whole.pooled and one.whole.pooled
    rows = slab.whole.density.size // 512 - 1
    assert 0 < rows < one.whole.density.size // 512 - 1
    g = np.argwhere(slab.whole.table.reshape([-(-n // 8) for n in one.shape]) > 0)
    d = 2 - grid.AXES.index(axis)
    assert (g[:, d] * 8 < c1).all() and (g[:, d] * 8 + 8 > c0).all()      # bricks that meet the slab's slices
    ws, wo = slab.whole_volume(axis, pool=True), one.whole_volume(axis, pool=True)
    (oa, ob, oc, _), (pa, pb, pc, _) = ws.offs, wo.offs
    true = open_augmented(old).read("density").reshape(-1)           # (format 4: whole channels)
    held = np.repeat(slab.whole.table > 0, 512)                      # per brick-major place: its brick held
    flat_s = slab.whole.flat()[0]
    assert np.array_equal(flat_s[_brick_major_mask(held, one.shape)], true[_brick_major_mask(held, one.shape)])
    assert not flat_s[~_brick_major_mask(held, one.shape)].any()
    rng = np.random.default_rng(1)
    tried = 0
    for c, a_, b_ in zip(rng.integers(c0, c1, 400), rng.integers(0, ws.n_a, 400), rng.integers(0, ws.n_b, 400)):
        i = int(oc[c] + oa[a_] + ob[b_])
        assert i == int(pc[c] + pa[a_] + pb[b_])                     # the volume's brick-major offsets, slab or not
        if slab.whole.table[i >> 9] and one.whole.table[i >> 9]:
            si = (i + int(slab.whole.deltas()[i >> 9])) % 2 ** 64
            oi = (i + int(one.whole.deltas()[i >> 9])) % 2 ** 64
            assert slab.whole.density[si] == one.whole.density[oi]
            tried += 1
    assert tried > 10


def _brick_major_mask(held, shape):
    """bool [k, j, i] flat: ``held`` (per brick-major place of the padded grid of 8^3 bricks) in C order."""
    g = [-(-n // 8) for n in shape]
    m = held.reshape(g + [8, 8, 8]).transpose(0, 3, 1, 4, 2, 5).reshape([n * 8 for n in g])
    return np.ascontiguousarray(m[:shape[0], :shape[1], :shape[2]]).reshape(-1)
