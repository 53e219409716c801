"""Post-classified splatting (render.classification = "post", isplat.splat.post) against its slow reference."""


import numpy as np
import pytest
from conftest import post_setting, write_volume
from hypothesis import given, settings
from hypothesis import strategies as st
from post_reference import post_reference

from isplat.renderer import Renderer

CAMERAS = ["azimuth = 0\nelevation = 0", "azimuth = 90\nelevation = 0", "azimuth = 180\nelevation = 0",
           "azimuth = 0\nelevation = 90", "azimuth = 33\nelevation = 21", "azimuth = 150\nelevation = -40"]
TF = "opacity = [[50, 0.0], [60, 0.3], [130, 0.1], [200, 0.9]]\ncolor = [[0, 1, 0, 0], [255, 0, 0.5, 1]]"


def rng_volume(seed, shape, levels=(0, 60, 120, 200)):
    r = np.random.default_rng(seed)
    return r.choice(np.array(levels, np.uint8), size=shape, p=[0.55, 0.15, 0.15, 0.15])


def random_normals(seed, shape):
    from isplat.normals import encode
    return encode(np.random.default_rng(seed + 1).normal(size=shape + (3,)))


def render(scene, method=None, et=None):
    return Renderer(scene, method=method).render_view(0, et=et)


def post_scene(make_scene, aug, idx, cam, proj="orthographic", render="", et=1.0, **kw):
    kw.setdefault("image", "width = 24\nheight = 20")
    kw.setdefault("transfer", TF)
    kw.setdefault("shading", "enabled = true")
    return make_scene(aug, idx, camera=f'projection = "{proj}"\n{cam}',
                      render=f'classification = "post"\nearly_termination = {et}\n{render}', **kw)



@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
def test_a_pixel_that_reaches_early_termination_is_filled_with_its_last_sample(tmp_path, make_scene, proj):
    """render.termination = "fill" (the default of scene version 7): a pixel that reaches the early-termination
    opacity takes the colour of the sample that took it there for the rest of its transmittance and becomes
    opaque; "stop" leaves it as it was. Both against the slow reference, and against each other: the difference
    is (1 - alpha) times that colour at the stopped pixels, nothing elsewhere."""
    shape = (6, 5, 6)
    aug, idx = write_volume(tmp_path, rng_volume(2, shape), normal=random_normals(2, shape))
    clear = 'width = 20\nheight = 20\nbackground = [0.0, 0.0, 0.0, 0.0]'    # straight alpha out
    imgs = {}
    for term in ("fill", "stop"):
        sc = post_scene(make_scene, aug, idx, "azimuth = 20\nelevation = 30", proj, f'termination = "{term}"',
                        et=0.9, image=clear)
        assert sc.render.termination == term
        ind, _ = render(sc, "indexed")
        full, _ = render(sc, "full")
        assert np.abs(ind - full).max() <= 1e-6
        assert np.abs(ind - post_reference(sc, et=0.9)).max() <= 2e-4
        imgs[term] = ind
    fill, stop = imgs["fill"], imgs["stop"]
    stopped = stop[..., 3] >= 0.9
    assert stopped.sum() >= 8 and (~stopped & (stop[..., 3] > 0)).sum() >= 20
    assert np.all(fill[stopped, 3] == 1.0)                       # filled: opaque
    assert np.all(stop[stopped, 3] < 1.0)
    assert np.array_equal(fill[~stopped], stop[~stopped])       # pixels that never stopped: bit for bit
    # premultiplied, the fill added (1 - alpha) x a sample's colour, at most 1 - 0.9 of it
    add = fill[stopped, :3] * fill[stopped, 3:] - stop[stopped, :3] * stop[stopped, 3:]
    assert add.min() >= -1e-6 and add.max() <= 0.1 + 1e-6 and add.max() > 1e-3

@pytest.mark.parametrize("cam", CAMERAS)
@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
def test_post_agrees_with_the_reference_for_both_methods(tmp_path, make_scene, cam, proj):
    shape = (5, 6, 7)
    aug, idx = write_volume(tmp_path, rng_volume(1, shape), spacing=(1.0, 1.2, 0.8), normal=random_normals(1, shape))
    sc = post_scene(make_scene, aug, idx, cam, proj)
    ref = post_reference(sc)
    ind, st_i = render(sc, "indexed")
    full, st_f = render(sc, "full")
    assert np.abs(ind - full).max() <= 1e-6
    assert st_i.drawn == st_f.drawn > 0       # the samples composited
    assert np.abs(ind - ref).max() <= 2e-4
    assert ref[..., 3].max() > 0.2


def test_post_with_cut_coloured_lights_and_early_termination(tmp_path, make_scene):
    shape = (6, 5, 6)
    aug, idx = write_volume(tmp_path, rng_volume(2, shape), normal=random_normals(2, shape))
    sc = post_scene(make_scene, aug, idx, "azimuth = 20\nelevation = 30", image="width = 20\nheight = 20",
                    transfer="opacity = [[55, 0.0], [60, 0.95], [255, 0.95]]",
                    cut="point = [0.3, 0.0, 0.0]\nnormal = [1.0, 0.2, 0.0]",
                    shading="enabled = true\ntwo_sided = false\nspecular = 0.5",
                    shading__light="direction = [0.3, 0.5, 1.0]\ncolor = [1.0, 0.6, 0.2]\n"
                                   "[[shading.light]]\ndirection = [-1.0, 0.2, 0.4]\nintensity = 0.5",
                    et=0.9)
    ind, _ = render(sc, "indexed", et=0.9)
    full, _ = render(sc, "full", et=0.9)
    assert np.abs(ind - full).max() <= 1e-6
    assert np.abs(ind - post_reference(sc, et=0.9)).max() <= 2e-4


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10 ** 6), az=st.floats(0, 360), el=st.floats(-80, 80), zoom=st.floats(0.5, 3.0),
       proj=st.sampled_from(["orthographic", "perspective"]))
def test_post_property_random_volumes_and_views(tmp_path_factory, seed, az, el, zoom, proj):
    from conftest import scene_text
    from isplat.scene import parse_scene
    tmp = tmp_path_factory.mktemp("post")
    shape = tuple(int(x) for x in np.random.default_rng(seed).integers(2, 7, 3))
    aug, idx = write_volume(tmp, rng_volume(seed, shape), normal=random_normals(seed, shape))
    text = scene_text(aug, idx, image="width = 16\nheight = 14", transfer=TF, shading="enabled = true",
                      camera=f'projection = "{proj}"\nazimuth = {az}\nelevation = {el}\nzoom = {zoom}',
                      render='classification = "post"\nearly_termination = 1.0')
    sc = parse_scene(text, tmp, "t.toml")
    img, _ = render(sc)
    assert np.abs(img - post_reference(sc)).max() <= 2e-4


def test_post_images_do_not_depend_on_threads_or_bands(tmp_path, make_scene, monkeypatch):
    from isplat import frame as F
    shape = (24, 10, 70)
    dens = rng_volume(5, shape)
    dens[:, :2, :] = 250
    aug, idx = write_volume(tmp_path, dens)
    images = []
    for threads, per, least in [(1, 1, 1000), (2, 2, 1), (3, 2, 4), (3, 5, 1), (2, 0, 0)]:      # (per 0: bands cut unevenly, as learned ones are)
        monkeypatch.setattr(F, "BANDS_PER_THREAD", per or 2)
        monkeypatch.setattr(F, "MIN_BAND_TILES", least or 1)
        if not per:
            monkeypatch.setattr(F, "band_rows", lambda *_: np.array([[0, 8], [8, 16], [16, 48], [48, 72]], np.int64))
        sc = post_scene(make_scene, aug, idx, "azimuth = 4\nelevation = 3", image="width = 100\nheight = 72",
                        transfer="opacity = [[55, 0.0], [60, 0.6], [249, 0.6], [250, 1.0]]",
                        shading="enabled = false", render=f"threads = {threads}", et=0.9)
        img, st_ = render(sc, et=0.9)
        images.append(img)
        if least == 1000:            # one band: the wall hides most voxels behind it, cells and all
            assert st_.voxels_tested - dens[:, :2].size < 0.3 * (dens[:, 2:] >= 55).sum()
    assert all(np.array_equal(images[0], im) for im in images[1:])
    assert np.abs(images[0] - post_reference(sc, et=0.9)).max() <= 2e-4


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10 ** 6), nca=st.integers(1, 13), ncb=st.integers(1, 13), unit=st.sampled_from([4, 8, 16]),
       density=st.floats(0.0, 1.0))
def test_marks_and_plan_against_the_obvious(seed, nca, ncb, unit, density):
    """_mark_cells and _plan_squares (called from Python through their compiled callers) against the obvious,
    for visible cells in any order: each visible cell flags itself (1) and its neighbours at -a (2), -b (4) and
    -a-b (8); the squares of ``unit`` voxels holding flagged cells come in the order of their first flagged cell,
    each scanned whole when enough of its cells are flagged (all 4 of 2 x 2 cells, half of 4 x 4), else its
    flagged cells one by one, row by row; every flagged cell is in exactly one thing scanned."""
    from isplat.splat import post

    rng = np.random.default_rng(seed)
    visible = rng.permutation(np.flatnonzero(rng.random(nca * ncb) < density))
    cells = np.zeros((max(visible.size, 1), 4), np.int64)
    cells[:visible.size, 2], cells[:visible.size, 3] = visible % nca * 4, visible // nca * 4
    per, nsa = unit // 4, -(-nca * 4 // unit)
    n = nca * ncb
    mark, marked, smark = np.zeros(n, np.uint8), np.empty(n, np.int64), np.zeros(n, np.uint8)
    squares, todo = np.empty((n, 3), np.int64), np.empty((n, 4), np.int64)
    nm, ns = post._mark_cells(cells, visible.size, nca, unit, nsa, mark, marked, smark, squares)
    nt = post._plan_squares(squares, ns, smark, mark, nca, ncb, unit, todo)
    flags, order = np.zeros(n, np.uint8), []
    for v in visible:
        for da in (0, 1):
            for db in (0, 1):
                if v % nca - da >= 0 and v // nca - db >= 0:
                    q = v - db * nca - da
                    if flags[q] == 0:
                        order.append(q)
                    flags[q] |= 1 << (da + 2 * db)
    assert np.array_equal(mark, flags) and marked[:nm].tolist() == order
    sq_order, want = [], []
    for q in order:
        sq = (q // nca // per) * nsa + (q % nca) // per
        if sq not in sq_order:
            sq_order.append(sq)
    for sq in sq_order:
        sa, sb = sq % nsa, sq // nsa
        inside = [cb * nca + ca for cb in range(sb * per, min(sb * per + per, ncb))
                  for ca in range(sa * per, min(sa * per + per, nca))]
        k = int((flags[inside] != 0).sum())
        assert smark[sq] == k
        if k >= (per * per if per <= 2 else per * per // 2):
            want.append((sq, unit, sa * unit, sb * unit))
        else:
            want += [(q, 4, q % nca * 4, q // nca * 4) for q in inside if flags[q]]
    assert [tuple(r) for r in squares[:ns].tolist()] == [(sq, sq % nsa, sq // nsa) for sq in sq_order]
    assert [tuple(r) for r in todo[:nt].tolist()] == want


@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
def test_squares_of_any_side_give_the_reference_image(tmp_path, make_scene, monkeypatch, proj):
    """Voxels far smaller than pixels (squares of 16 voxels scanned, of which an opaque wall in front leaves a
    few cells visible, scanned one by one): the image is the slow reference's, and bit for bit the one
    scanned with squares of 8 voxels and with single cells."""
    from isplat.splat import post

    shape = (24, 10, 96)
    dens = rng_volume(7, shape)
    dens[:, :2, 10:90] = 250                               # a wall with open sides, seen from -y
    aug, idx = write_volume(tmp_path, dens)
    sc = post_scene(make_scene, aug, idx, "azimuth = 3\nelevation = 2", proj, image="width = 40\nheight = 30",
                    transfer="opacity = [[55, 0.0], [60, 0.6], [249, 0.6], [250, 1.0]]", shading="enabled = false",
                    et=0.9)
    images = []
    for side in (None, 8, 4):
        if side:
            monkeypatch.setattr(post, "scan_unit", lambda jac, side=side: side)
        images.append(render(sc, et=0.9)[0])
    monkeypatch.undo()
    from isplat.camera import projection

    view = Renderer(sc).views[0]
    assert post.scan_unit(projection(view.frame, view.geom, view.axis_sign[0]).jac) == 16
    assert all(np.array_equal(images[0], im) for im in images[1:])
    assert np.abs(images[0] - post_reference(sc, et=0.9)).max() <= 2e-4


def test_uniform_block_gives_the_closed_form_opacity_without_lattice_ripple(tmp_path, make_scene):
    """A uniform block seen head-on at 4 pixels per voxel: every pixel inside sees n slices of opacity alpha,
    1 - (1 - alpha)^n, exactly (the bilinear density is constant), where a Gaussian splat ripples."""
    shape = (8, 8, 8)
    aug, idx = write_volume(tmp_path, np.full(shape, 200, np.uint8))
    alpha = 0.1
    sc = post_scene(make_scene, aug, idx, "azimuth = 0\nelevation = 0\nzoom = 0.25",
                    image="width = 64\nheight = 64\nbackground = [0, 0, 0, 0]",
                    transfer=f"opacity = [[199, 0], [200, {alpha}], [201, 0]]\nunit_distance = 1.0",
                    shading="enabled = false")
    img, _ = render(sc)
    a = img[..., 3]
    inside = a[a > 0.5 * a.max()]
    assert np.abs(inside - (1 - (1 - alpha) ** 8)).max() < 1e-5


def test_a_thin_opaque_edge_is_not_widened(tmp_path, make_scene):
    """An opaque slab with a sharp transfer-function edge: post-classification puts the silhouette where the
    bilinear density crosses the edge (half-way between the voxels), pre-classification widens it by the
    footprint's reach."""
    shape = (8, 8, 16)
    dens = np.zeros(shape, np.uint8)
    dens[:, :, 4:12] = 200                         # i in [4, 12): its edges at i = 3.5 and 11.5
    aug, idx = write_volume(tmp_path, dens)
    kw = dict(image="width = 64\nheight = 32\nbackground = [0, 0, 0, 0]", shading="enabled = false",
              transfer="opacity = [[99, 0], [100, 1.0], [255, 1.0]]")
    post = post_scene(make_scene, aug, idx, "azimuth = 0\nelevation = 0\nzoom = 2.5", **kw)
    r = Renderer(post)
    img, _ = r.render_view(0)
    covered = np.flatnonzero(img[16, :, 3] > 0.5)
    # the density crosses 100 half-way between voxels 3 and 4 and between 11 and 12: 8 voxels wide
    expect = 8.0 / r.frames[0].pixel_size
    assert expect > 20 and abs(covered.size - expect) <= 1.01
    pre = make_scene(aug, idx, camera="azimuth = 0\nelevation = 0\nzoom = 2.5",
                     render='early_termination = 1.0\nclassification = "pre"', **kw)
    pre_img, _ = render(pre)
    assert (pre_img[16, :, 3] > 0.5).sum() >= covered.size + 2


def test_post_with_image_sheets_is_refused(tmp_path, make_scene):
    from isplat.errors import IsplatError
    aug, idx = write_volume(tmp_path, rng_volume(1, (4, 4, 4)))
    with pytest.raises(IsplatError, match="classification"):
        make_scene(aug, idx, transfer=TF, render='classification = "post"\nsheets = "image"')


def test_a_post_selection_is_refused_by_the_pre_kernel_when_it_lacks_values(tmp_path, make_scene):
    """A selection made for post-classification gathers no channel values (its frames read the whole channels);
    a pre-classified frame that needs normals must not index the missing ones."""
    from isplat.errors import IsplatError
    from isplat.frame import render_frame, views_for
    shape = (5, 6, 7)
    aug, idx = write_volume(tmp_path, rng_volume(1, shape), normal=random_normals(1, shape))
    post = post_scene(make_scene, aug, idx, "azimuth = 10")
    pre = make_scene(aug, idx, transfer=TF, shading="enabled = true", render='classification = "pre"')
    r = Renderer(post)
    assert r.selection.post and r.selection.axes["j"].normal.size == 0
    with pytest.raises(IsplatError, match="needs the channel values"):
        render_frame(r.selection, views_for(pre, r.selection)[0])


def test_a_post_selection_holds_the_cells_alone_and_pre_and_mip_frames_refuse_it(tmp_path, make_scene):
    """A post-classified composite selection holds no voxel's square and density (its frames sample the channels
    at the cells' quads): a pre-classified frame (unshaded too) and an intensity projection, whose kernels read
    them, are refused instead of indexing the empty arrays; the voxels are still counted."""
    from isplat.errors import IsplatError
    from isplat.frame import render_frame, views_for
    shape = (5, 6, 7)
    dens = rng_volume(1, shape)
    aug, idx = write_volume(tmp_path, dens)
    post = post_scene(make_scene, aug, idx, "azimuth = 10", shading="enabled = false")
    pre = make_scene(aug, idx, transfer=TF, render='classification = "pre"')
    r = Renderer(post)
    ax = r.selection.axes["j"]
    assert ax.cells_only and ax.offset.size == 0 and ax.density.size == 0
    assert ax.n_voxels == Renderer(pre).selection.axes["j"].n_voxels == r.report.voxels_of_interest > 0
    assert not Renderer(pre).selection.axes["j"].cells_only
    with pytest.raises(IsplatError, match="needs the voxels of interest"):
        render_frame(r.selection, views_for(pre, r.selection)[0])
    mip = post_scene(make_scene, aug, idx, "azimuth = 10", shading="enabled = false", render='mode = "mip"')
    assert not Renderer(mip).selection.axes["j"].cells_only
    with pytest.raises(IsplatError, match="needs a selection made for it"):
        render_frame(r.selection, views_for(mip, r.selection)[0])
    with pytest.raises(IsplatError, match="cells alone"):
        ax.coordinates()


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10 ** 6), levels=st.sampled_from([1, 2, 7, 256]), k=st.integers(0, 254),
       f=st.floats(0.0, 1.0))
def test_lerp_tables_give_the_lerp_between_codes_bit_for_bit(seed, levels, k, f):
    """post.lerp_tables: the opacities and colours, then their steps to the next code; t[k] + f step[k] is the
    lerp t[k] + f (t[k + 1] - t[k]) exactly (the kernel's samples are those of the two-load lerp), and code
    255's steps are 0."""
    from isplat.splat.post import lerp_tables

    rng = np.random.default_rng(seed)
    alpha = rng.uniform(0, 1, (256, levels)).astype(np.float32) * (rng.uniform(size=(256, 1)) > 0.3)
    color = rng.uniform(0, 1, (256, 3)).astype(np.float32)
    a, c = lerp_tables(alpha, color)
    assert a.shape == (256, 2 * levels) and c.shape == (256, 6) and a.dtype == c.dtype == np.float64
    assert a.flags.c_contiguous and c.flags.c_contiguous
    for t, lerped in ((alpha.astype(np.float64), a), (color.astype(np.float64), c)):
        n = t.shape[1]
        assert np.array_equal(lerped[:, :n], t) and not lerped[255, n:].any()
        assert np.array_equal(lerped[k, :n] + f * lerped[k, n:], t[k] + f * (t[k + 1] - t[k]))


def test_prefetch_compiles_to_a_hint_that_changes_nothing():
    """isplat.jit.prefetch in compiled code is one PREFETCHT0 (on x86-64) and changes no value, also for an
    index far outside the array (a prefetch never faults)."""
    import numba
    import platform

    from isplat.jit import prefetch

    @numba.njit
    def total(a, ahead):
        s = 0
        for i in range(a.size):
            prefetch(a, np.uint64(i + ahead))
            s += a[i]
        return s

    a = np.arange(1000, dtype=np.uint8)
    assert total(a, 3) == total(a, 1 << 40) == int(a.sum())
    if platform.machine() == "x86_64":
        asm = total.inspect_asm(total.signatures[0])
        assert "prefetcht0" in asm


@settings(max_examples=200, deadline=None)
@given(unit=st.sampled_from([4, 8, 16]), n_a=st.integers(1, 40), n_b=st.integers(1, 40), sa=st.integers(1, 70),
       extra=st.integers(0, 70), c=st.integers(0, 3), between=st.sampled_from([0, 1, 2]), data=st.data())
def test_prefetch_square_covers_every_line_the_square_reads(unit, n_a, n_b, sa, extra, c, between, data):
    """_prefetch_square (run as Python, its prefetches recorded) asks for every 64-byte line of every channel
    that the square's quads read: voxels a0 .. a0 + unit and b0 .. b0 + unit (the quads reach the next voxel),
    within the slice, and with the cubic along a or b (``between`` 1 or 2) the voxel or row before and the one
    after too; so no sample of the square waits for memory that could have been fetched."""
    from isplat.splat import post

    a0 = data.draw(st.integers(0, n_a - 1)) // 4 * 4
    b0 = data.draw(st.integers(0, n_b - 1)) // 4 * 4
    sb = sa * n_a + extra                          # a slice's rows: any step along b past a row along a
    sc = sb * n_b
    size = sc * 4
    offset = data.draw(st.integers(-c * sc, 0))    # a slab's channels: a negative offset for its first slice
    size = size + offset
    density, gm, nrm = np.zeros(size, np.uint8), np.zeros(size, np.uint8), np.zeros(size, np.uint16)
    asked = {id(density): set(), id(gm): set(), id(nrm): set()}
    from post_reference import kernel_offsets

    voxel = (density, gm, nrm, kernel_offsets([sa, sb, sc, offset], n_a, n_b, c), n_a, n_b, c, (between, 0, 1))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(post, "prefetch", lambda arr, i: asked[id(arr)].add(int(i) * arr.itemsize // 64))
        post._prefetch_square.py_func(unit, a0, b0, voxel, True, True)
    for arr in (density, gm, nrm):
        read = {(c * sc + offset + a * sa + b * sb) * arr.itemsize // 64
                for a in range(max(a0 - (between == 1), 0), min(a0 + unit + (between == 1), n_a - 1) + 1)
                for b in range(max(b0 - (between == 2), 0), min(b0 + unit + (between == 2), n_b - 1) + 1)}
        assert read <= asked[id(arr)]


def test_reference_weighting_is_what_the_kernel_does(tmp_path, make_scene):
    """The corners' Phong factors weighted by their gradient magnitudes (isplat.splat.post._sample): the kernel
    agrees with the weighted reference and not with the bilinear one on random gradient magnitudes, and with
    the bilinear one when the sampler's weighting is switched off."""
    shape = (5, 6, 7)
    gm = np.random.default_rng(3).integers(0, 256, shape)
    gm.flat[::5] = 0                    # corners that count for nothing (and quads whose four are all 0)
    aug, idx = write_volume(tmp_path, rng_volume(3, shape), spacing=(1.0, 1.2, 0.8), normal=random_normals(3, shape),
                            gm=gm)
    sc = post_scene(make_scene, aug, idx, CAMERAS[0], "orthographic")
    img, _ = render(sc, "full")
    weighted, plain = post_reference(sc), post_reference(sc, weighted=False)
    assert np.abs(img - weighted).max() <= 2e-4 < np.abs(img - plain).max()
    with post_setting("WEIGHTED_SHADING", False):
        img, _ = render(sc, "full")
    assert np.abs(img - plain).max() <= 2e-4


THICK = (1.0, 0.9, 4.5)         # spacing i, j, k: k five times the finest (isplat.splat.post.THICK_RATIO: 4)


def _between(kind):
    """Context: isplat.splat.post.BETWEEN_SLICES set to ``kind``."""
    return post_setting("BETWEEN_SLICES", kind)


@pytest.mark.parametrize("kind", ["monotone", "catmull-rom", "b-spline"])
@pytest.mark.parametrize("cam", CAMERAS)
@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
def test_cubic_between_thick_slices_agrees_with_the_reference(tmp_path, make_scene, cam, proj, kind):
    """Slices 4.5 times thicker than the finest spacing (0.9): the kernel's cubic along the thick in-slice axis (a or b
    by the view; none when the view is along it) agrees with the reference's, for both methods, and (views
    not along k) not with the linear reference."""
    shape = (6, 7, 8)
    aug, idx = write_volume(tmp_path, rng_volume(7, shape), spacing=THICK, normal=random_normals(7, shape))
    sc = post_scene(make_scene, aug, idx, cam, proj)
    with _between(kind):
        ind, _ = render(sc, "indexed")
        full, _ = render(sc, "full")
    ref = post_reference(sc, between=kind)
    assert np.abs(ind - full).max() <= 1e-6
    assert np.abs(ind - ref).max() <= 2e-4
    assert ref[..., 3].max() > 0.2
    if "elevation = 90" not in cam:          # the view along k: samples on the slices, nothing between them
        assert np.abs(ind - post_reference(sc, between="linear")).max() > 1e-3


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10 ** 6), az=st.floats(0, 360), el=st.floats(-80, 80), zoom=st.floats(0.5, 3.0),
       proj=st.sampled_from(["orthographic", "perspective"]), thick=st.integers(0, 2),
       ratio=st.floats(4.0, 10.0), kind=st.sampled_from(["monotone", "catmull-rom", "b-spline"]))
def test_cubic_property_random_anisotropic_volumes_and_views(tmp_path_factory, seed, az, el, zoom, proj, thick, ratio,
                                                              kind):
    from conftest import scene_text
    from isplat.scene import parse_scene
    tmp = tmp_path_factory.mktemp("post")
    shape = tuple(int(x) for x in np.random.default_rng(seed).integers(2, 8, 3))
    spacing = [1.0, 1.0, 1.0]
    spacing[thick] = ratio
    aug, idx = write_volume(tmp, rng_volume(seed, shape), spacing=tuple(spacing), normal=random_normals(seed, shape))
    text = scene_text(aug, idx, image="width = 16\nheight = 14", transfer=TF, shading="enabled = true",
                      camera=f'projection = "{proj}"\nazimuth = {az}\nelevation = {el}\nzoom = {zoom}',
                      render='classification = "post"\nearly_termination = 1.0')
    sc = parse_scene(text, tmp, "t.toml")
    with _between(kind):
        img, _ = render(sc)
    assert np.abs(img - post_reference(sc, between=kind)).max() <= 2e-4


@pytest.mark.parametrize("spacing", [(1.0, 1.0, 1.0), (1.0, 1.2, 0.8), (1.0, 1.0, 1.99), (0.7, 0.7, 2.5)])
def test_below_the_ratio_images_are_the_linear_ones_bit_for_bit(tmp_path, make_scene, spacing):
    """Isotropic data, and grids less anisotropic than THICK_RATIO: the same bilinear sampler as before (the
    same float operations), bit for bit, whatever BETWEEN_SLICES says."""
    shape = (5, 6, 7)
    aug, idx = write_volume(tmp_path, rng_volume(4, shape), spacing=spacing, normal=random_normals(4, shape))
    sc = post_scene(make_scene, aug, idx, CAMERAS[4])
    images = []
    for kind in ("linear", "monotone", "catmull-rom", "b-spline"):
        with _between(kind):
            images.append(render(sc)[0])
    assert images[0][..., 3].max() > 0.2
    assert all(np.array_equal(images[0], im) for im in images[1:])


@settings(max_examples=300, deadline=None)
@given(p=st.lists(st.integers(0, 255), min_size=4, max_size=4), t=st.floats(0.0, 1.0),
       kind=st.sampled_from([0, 1]))
def test_cubic_interpolates_the_voxels_and_stays_in_the_codes(p, t, kind):
    """isplat.splat.post.cubic: the voxels themselves at t = 0 and 1 (exactly); the monotone kind never
    outside the two voxels around t (no overshoot), Catmull-Rom never outside the codes 0..255; monotone data
    give a monotone curve."""
    from isplat.splat.post import cubic

    pm, p0, p1, p2 = (np.uint8(x) for x in p)
    assert cubic(pm, p0, p1, p2, 0.0, kind) == p[1]
    assert cubic(pm, p0, p1, p2, 1.0, kind) == p[2]
    v = cubic(pm, p0, p1, p2, t, kind)
    assert 0.0 <= v <= 255.0
    if kind == 0:
        assert min(p[1], p[2]) - 1e-9 <= v <= max(p[1], p[2]) + 1e-9
        if p == sorted(p) and t < 1.0:
            assert v <= cubic(pm, p0, p1, p2, min(1.0, t + 1e-3), kind) + 1e-9


def test_the_kernel_density_is_the_voxels_at_voxel_positions():
    """isplat.splat.post._density_at on a row of voxels along a thick axis: at fu = 0 the quad's first voxel,
    between voxels the cubic through the four around it (the neighbours clamped at the row's ends by _taps)."""
    from isplat.splat import post

    from post_reference import NO_TABLE, kernel_offsets

    vals = np.array([10, 200, 30, 90, 250, 0, 120], np.uint8)
    density = np.concatenate([vals, vals[::-1]])             # two rows along a (b = 0, 1)
    for kind in (0, 1):
        voxel = (density, density, density, kernel_offsets([1, 7, 14, 0], 7, 2, 0), 7, 2, 0, (1, kind, 1))
        for qa in range(7):
            taps = post._taps(qa, 0, voxel)
            sa = 1 if qa + 1 < 7 else 0
            assert post._density_at(density, qa, sa, 7, 0.0, 0.0, taps, NO_TABLE) == vals[qa]
            f = 0.37
            d = post._density_at(density, qa, sa, 7, f, 0.0, taps, NO_TABLE)
            q = [vals[min(max(qa + k, 0), 6)] for k in (-1, 0, 1, 2)]
            assert d == pytest.approx(post.cubic(*q, f, kind), abs=1e-12)


def test_the_spline_interpolates_the_voxels_and_matches_the_reference_kernel():
    """isplat.splat.post._density_at with the interpolating spline on a row of voxels along a thick axis: the
    voxel itself at f = 0 (exactly up to rounding), between voxels the reference's spline (tests/post_reference.py:
    the kernel summed from the B-spline and the prefilter), within the codes; constant data stay constant."""
    from post_reference import NO_TABLE, _cardinal, _spline_taps, kernel_offsets

    from isplat.splat import post

    vals = np.array([10, 200, 30, 90, 250, 0, 120, 7, 60, 255, 255], np.uint8)
    n = vals.size
    density = np.concatenate([vals, vals[::-1]])             # two rows along a (b = 0, 1)
    offs = kernel_offsets([1, n, 2 * n, 0], n, 2, 0)
    voxel = (density, density, density, offs, n, 2, 0, (1, 2, 1))
    for qa in range(n):
        taps = post._taps(qa, 0, voxel)
        sa = 1 if qa + 1 < n else 0
        assert post._density_at(density, qa, sa, n, 0.0, 0.0, taps, NO_TABLE) == pytest.approx(vals[qa], abs=1e-9)
        for f in (0.13, 0.5, 0.91):
            d = post._density_at(density, qa, sa, n, f, 0.0, taps, NO_TABLE)
            p = [vals[min(max(qa + k, 0), n - 1)] for k in _spline_taps()]
            assert d == pytest.approx(_cardinal(p, f), abs=1e-9)
            assert 0.0 <= d <= 255.0
    flat = np.full(2 * n, 77, np.uint8)
    taps = post._taps(4, 0, (flat, flat, flat, offs, n, 2, 0, (1, 2, 1)))
    assert post._density_at(flat, 4, 1, n, 0.37, 0.6, taps, NO_TABLE) == pytest.approx(77.0, abs=1e-9)


def test_the_spline_kernel_truncation_is_small():
    """isplat.splat.post.spline_kernel: the weights sum to 1 within the truncation's share (1.5% at reach 3, 0.4%
    at 4), and the renormalised negative weights add up to less than SPLINE_OVERSHOOT at every f (which MIP's
    bounds take), at the reach used and the one next to it."""
    from isplat.splat import post

    f = np.linspace(0.0, 1.0, 4001)
    for reach, tol in ((3, 0.015), (4, 0.004)):
        w = post.spline_kernel(reach) @ np.vstack([f ** 0, f, f ** 2, f ** 3])
        assert np.abs(w.sum(0) - 1).max() < tol
        assert (-np.minimum(w / w.sum(0), 0)).sum(0).max() < post.SPLINE_OVERSHOOT - 0.02
    w = post.SPLINE_KERNEL @ np.vstack([f ** 0, f, f ** 2, f ** 3])
    assert np.abs(w.sum(0) - 1).max() < 0.015
    assert (-np.minimum(w / w.sum(0), 0)).sum(0).max() < post.SPLINE_OVERSHOOT - 0.02


def test_the_bricks_read_reach_the_spline_taps():
    """isplat.selection.QUAD_REACH: a cell at a0 owns quads a0 - 1 .. a0 + 3, whose spline taps reach
    SPLINE_REACH - 1 before and SPLINE_REACH after the quad."""
    from isplat.selection import QUAD_REACH
    from isplat.splat.post import SPLINE_REACH

    assert QUAD_REACH[0] >= 1 + SPLINE_REACH - 1 and QUAD_REACH[1] >= 3 + SPLINE_REACH


def test_between_slices_picks_the_thick_in_slice_axis():
    from isplat.splat.post import between_slices

    assert between_slices((1.0, 1.0, 7.0), "i", "monotone") == (2, 0, 1)      # i's slices: a = j, b = k
    assert between_slices((1.0, 1.0, 7.0), "j", "catmull-rom") == (2, 1, 1)  # j's: a = i, b = k
    assert between_slices((7.0, 1.0, 1.0), "k", "monotone") == (1, 0, 1)      # k's: a = i
    assert between_slices((1.0, 1.0, 7.0), "k", "monotone") == (0, 0, 0)      # along the view: on the slices
    assert between_slices((1.0, 1.0, 1.9), "i", "monotone") == (0, 0, 0)
    assert between_slices((1.0, 1.0, 7.0), "i", "linear") == (0, 0, 0)
    assert between_slices((1.0, 1.0, 7.0), "i", "b-spline") == (2, 2, 1)


def test_thick_shading_weighted_by_gradient_magnitudes_agrees_with_the_reference(tmp_path, make_scene):
    """Between thick slices the eight voxels' Phong factors (B-spline weights along the thick axis) weighted by
    their gradient magnitude codes too, some 0 and some quads' all 0: the kernel agrees with the reference."""
    shape = (6, 7, 8)
    gm = np.random.default_rng(8).integers(0, 256, shape)
    gm.flat[::3] = 0
    aug, idx = write_volume(tmp_path, rng_volume(8, shape), spacing=THICK, normal=random_normals(8, shape), gm=gm)
    for cam in (CAMERAS[0], CAMERAS[4]):
        sc = post_scene(make_scene, aug, idx, cam, "orthographic")
        img, _ = render(sc, "full")
        assert np.abs(img - post_reference(sc)).max() <= 2e-4


def test_cubic_with_the_corners_shading_agrees_with_the_reference(tmp_path, make_scene, monkeypatch):
    """SHADE_BETWEEN off: the cubic density between thick slices, the quad's four corners' Phong factors."""
    from isplat.splat import post

    monkeypatch.setattr(post, "SHADE_BETWEEN", False)
    shape = (6, 7, 8)
    aug, idx = write_volume(tmp_path, rng_volume(9, shape), spacing=THICK, normal=random_normals(9, shape))
    for cam in (CAMERAS[1], CAMERAS[5]):
        sc = post_scene(make_scene, aug, idx, cam, "perspective")
        img, _ = render(sc)
        assert np.abs(img - post_reference(sc)).max() <= 2e-4
        monkeypatch.setattr(post, "SHADE_BETWEEN", True)
        assert np.abs(img - post_reference(sc)).max() > 1e-3        # the shading's weights do differ
        monkeypatch.setattr(post, "SHADE_BETWEEN", False)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10 ** 6), fu=st.floats(0.0, 1.0, exclude_max=True), fv=st.floats(0.0, 1.0, exclude_max=True),
       edge_a=st.booleans(), edge_b=st.booleans())
def test_density_at_is_the_bilinear_density(seed, fu, fv, edge_a, edge_b):
    """post._density_at (the one place a sample reads densities) against the obvious bilinear interpolation of
    the quad's four voxels on a 2-D slice, the edge voxel repeated where the step is 0."""
    from isplat.splat import post

    assert post.SAMPLE_STAGES == 4                # the whole sample unless measuring the stages' shares
    rng = np.random.default_rng(seed)
    plane = rng.integers(0, 256, (7, 9)).astype(np.uint8)      # [b, a]
    b, a = int(rng.integers(0, 6)), int(rng.integers(0, 8))
    sa, sb = (0 if edge_a else 1), (0 if edge_b else plane.shape[1])
    a1, b1 = a + (sa != 0), b + (sb != 0)
    want = ((1 - fu) * (1 - fv) * float(plane[b, a]) + fu * (1 - fv) * float(plane[b, a1])
            + (1 - fu) * fv * float(plane[b1, a]) + fu * fv * float(plane[b1, a1]))
    from post_reference import NO_TABLE

    got = post._density_at(plane.ravel(), b * plane.shape[1] + a, sa, sb, fu, fv, (0, 0, 0, 0, 0, 0, 1, np.zeros(1, np.int64)),
                           NO_TABLE)
    assert got == want
    # taps None: the variant a frame without a thick axis compiles (the cubic pruned out), the same value
    assert post._density_at(plane.ravel(), b * plane.shape[1] + a, sa, sb, fu, fv, None, NO_TABLE) == want


@settings(max_examples=60, deadline=None)
@given(shape=st.tuples(st.integers(1, 20), st.integers(1, 20), st.integers(1, 20)), axis=st.sampled_from("kji"),
       seed=st.integers(0, 2 ** 16))
def test_a_pool_holds_each_voxel_of_its_bricks_where_the_sampler_looks(shape, axis, seed):
    """A pool (isplat.selection.WholeChannels: some bricks of format 6's order, behind a uint32 table) read the
    sampler's way, ``_phys(deltas, oa[a] + ob[b] + oc[c])`` with its delta table (WholeChannels.deltas, each
    brick's row minus its place, modulo 2^64) and isplat.grid.flat_offsets' brick-major tables,
    gives every voxel of every brick it holds; and the table-free way, with the row-major tables, every voxel of
    the flat channel; and the pool made whole again (WholeChannels.flat, a strided kernel's) is the volume where bricks
    were held, zero elsewhere."""
    from isplat import grid
    from isplat.selection import WholeChannels
    from isplat.splat import post

    rng = np.random.default_rng(seed)
    vol = rng.integers(1, 256, shape).astype(np.uint8)            # [k, j, i]
    e = grid.POOL_EDGE
    g = [-(-n // e) for n in shape]
    held = rng.random(g) < 0.5
    pad = np.zeros([n * e for n in g], np.uint8)
    pad[:shape[0], :shape[1], :shape[2]] = vol
    bricks = pad.reshape(g[0], e, g[1], e, g[2], e).transpose(0, 2, 4, 1, 3, 5).reshape(-1, e ** 3)
    table = np.zeros(held.size, np.uint32)
    table[held.reshape(-1)] = np.arange(1, int(held.sum()) + 1, dtype=np.uint32)
    pool = np.concatenate([np.zeros((1, e ** 3), np.uint8), bricks[held.reshape(-1)]]).reshape(-1)
    phys = post._phys
    chans = WholeChannels(pool, pool[:0], pool[:0].view(np.uint16), table=table, shape=shape)
    deltas = chans.deltas()
    dims = grid.SLICE_AXES[axis]                                   # (i, j, k) dims of a, b, c
    oa, ob, oc = grid.flat_offsets(shape, axis, e)
    fa, fb, fc = grid.flat_offsets(shape, axis)
    for k, j, i in np.ndindex(*shape):
        a, b, c = ((i, j, k)[d] for d in dims)
        assert vol.reshape(-1)[phys(None, np.uint64(fa[a] + fb[b] + fc[c]))] == vol[k, j, i]
        if held[k // e, j // e, i // e]:
            assert pool[phys(deltas, np.uint64(oa[a] + ob[b] + oc[c]))] == vol[k, j, i]
    flat = chans.flat()[0]
    keep = np.repeat(np.repeat(np.repeat(held, e, 0), e, 1), e, 2)[:shape[0], :shape[1], :shape[2]]
    assert np.array_equal(flat.reshape(shape), np.where(keep, vol, 0))


@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
def test_the_linear_and_the_cubic_sampler_are_two_compiled_kernels(tmp_path, make_scene, proj):
    """Below THICK_RATIO a frame's plan carries ``between`` None and the sampler is compiled without the cubic's
    taps (_taps gives None; the bilinear sampler of before the cubic, whose images the sampler benchmark
    compares bit for bit with 2e683d4's); above it the thick axis: another numba type of the plan, so another
    compiled kernel of traverse.render. Each renders its reference, and the cubic's is not the linear one's."""
    import numba

    from isplat import frame as F
    from isplat.splat import post
    from isplat.splat import traverse as T

    plans = {}
    for name, spacing in (("linear", (1.0, 1.2, 0.8)), ("cubic", THICK)):
        shape = (6, 7, 8)
        aug, idx = write_volume(tmp_path, rng_volume(11, shape), spacing=spacing, normal=random_normals(11, shape),
                                name=name)
        sc = post_scene(make_scene, aug, idx, CAMERAS[4], proj)
        r = Renderer(sc)
        plans[name] = F.prepare(r.selection, r.views[0]).plan
        img, _ = r.render_view(0)
        assert np.abs(img - post_reference(sc)).max() <= 2e-4
        if name == "cubic":
            assert np.abs(img - post_reference(sc, between="linear")).max() > 1e-3
    assert plans["linear"].cls.between is None and plans["cubic"].cls.between[0] in (1, 2)
    types = {k: numba.typeof(p) for k, p in plans.items()}
    assert types["linear"] != types["cubic"]
    assert {types["linear"], types["cubic"]} <= {sig[2] for sig in T.render.signatures}
    voxel = (None,) * 7
    assert post._taps(3, 4, voxel + (None,)) is None
    from post_reference import kernel_offsets

    offs = kernel_offsets([1, 8, 64, 0], 8, 8, 0)
    taps = post._taps(3, 4, (None, None, None, offs, 8, 8, 0, (1, 1, 1)))
    assert taps == (1, 1, 1, 2, 1, 3, 8, 1)                  # (its last: the stride along a, or a pool's table)
