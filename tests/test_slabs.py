"""A selection restricted to a slab of slices (isplat.slabs): the slab draws what the whole selection draws."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from conftest import write_volume
from isplat import frame as F
from isplat import grid
from isplat.augfile import open_augmented
from isplat.errors import IsplatError
from isplat.selection import Selection, select_from_files
from isplat.slabs import restrict, slice_runs

SLOW = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def volume(tmp_path_factory):
    from isplat.normals import encode

    r = np.random.default_rng(3)
    shape = (12, 9, 10)
    dens = r.choice(np.array([0, 60, 120, 200], np.uint8), size=shape, p=[0.4, 0.2, 0.2, 0.2])
    gm = r.integers(0, 256, shape).astype(np.uint8)
    aug, idx = write_volume(tmp_path_factory.mktemp("slabs"), dens, spacing=(1.0, 1.2, 0.9), gm=gm,
                            normal=encode(r.normal(size=shape + (3,))), gscale=0.5)
    return aug, idx


def scene(make_scene, volume, proj, cam, et=0.99, method="indexed", classification="post"):
    return make_scene(*volume, image="width = 30\nheight = 28", camera=f'projection = "{proj}"\n{cam}',
                      transfer="opacity = [[50, 0.0], [60, 0.5], [130, 0.3], [200, 0.95]]\n"
                               "gradient_opacity = [[0, 0.3], [100, 1]]",
                      shading="enabled = true", render=f'method = "{method}"\nthreads = 1\nearly_termination = {et}\n'
                                                      f'classification = "{classification}"')


@given(st.lists(st.integers(0, 40), max_size=12), st.integers(1, 41))
def test_slice_runs_are_the_sorted_distinct_slices_as_runs(slices, n):
    slices = [s for s in slices if s < n]
    runs = slice_runs(slices, n)
    assert [s for a, b in runs for s in range(a, b)] == sorted(set(slices))
    assert all(b2 > b1 for (_, b1), (b2, _) in zip(runs, runs[1:]))     # runs do not touch: maximal


def test_slice_runs_refuse_slices_outside_the_axis():
    with pytest.raises(IsplatError, match="outside 0..9"):
        slice_runs([3, 10], 10)


@given(data=st.data())
@SLOW
def test_a_slab_of_the_restricted_selection_is_the_slab_of_the_whole(make_scene, volume, data):
    """render_slab on restrict(sel, axis, order[a:b]) equals render_slab on sel, bit for bit (perspective with
    the eye inside too, where a slab's slices are two runs), and the slabs' voxels add up to the whole."""
    proj = data.draw(st.sampled_from(["orthographic", "perspective"]))
    cam = data.draw(st.sampled_from(["azimuth = 30\nelevation = 20", "azimuth = 100\nelevation = -50",
                                     "mode = \"look_at\"\nposition = [0.5, 0.3, 0.2]\nlook_at = [3, -5, 2]"]))
    if proj == "orthographic" and "look_at" in cam:
        cam = "azimuth = 200\nelevation = 70"
    sc = scene(make_scene, volume, proj, cam, et=data.draw(st.sampled_from([1.0, 0.9])))
    from isplat.augfile import open_augmented
    view = F.views_for(sc, open_augmented(sc.data.augmented))[0]
    axis = view.axis_sign[0]
    sel = select_from_files(sc, axis)
    setup = F.prepare(sel, view)
    n = len(view.order)
    k = data.draw(st.integers(1, min(5, n)))
    total = 0
    for a, b in F.slab_bounds(n, k):
        part_sel = restrict(sel, axis, view.order[a:b])
        total += part_sel.axes[axis].n_voxels
        want = F.render_slab(setup, a, b)
        got = F.render_slab(F.prepare(part_sel, view), a, b)
        assert np.array_equal(got.img, want.img) and np.array_equal(got.band_stats, want.band_stats)
    assert total == sel.axes[axis].n_voxels


def test_restrict_keeps_every_array_in_order(make_scene, volume):
    sc = scene(make_scene, volume, "orthographic", "azimuth = 0", classification="pre")   # values gathered
    sel = select_from_files(sc, "k")
    whole = sel.axes["k"]
    parts = [restrict(sel, "k", range(a, b)).axes["k"] for a, b in [(0, 5), (5, 12)]]
    for name in ("region_id", "block_pos", "cell_pos", "cell_count", "offset", "density", "gradient_magnitude",
                 "normal"):
        assert np.array_equal(np.concatenate([getattr(p, name) for p in parts]), getattr(whole, name)), name
    assert all(p.normal.size == p.density.size > 0 for p in parts)
    empty = restrict(sel, "k", [])
    assert empty.axes["k"].n_voxels == 0 and empty.axes["k"].block_voxel.tolist() == [0]


@pytest.mark.parametrize("axis,slices", [("k", range(3, 8)), ("i", [0, 1, 7, 8, 9]), ("j", []), ("j", range(9)),
                                         ("j", [2, 3, 6])])
def test_a_slab_selected_from_files_is_the_restricted_whole(make_scene, volume, axis, slices):
    """select_from_files(..., slices=): the decoded blocks cut to the slab, its values gathered from the
    augmented k-slabs: the same arrays as restricting the whole selection (index with values or without), and
    fewer channel bytes read than the whole selection gathers the same way."""
    from isplat.index import build_index_file

    aug, idx = volume
    v2 = idx.with_name("novalues.idx.h5")
    if not v2.exists():
        build_index_file(aug, v2, values=False)
    for index in (idx, v2):
        sc = make_scene(aug, index,
                        transfer="opacity = [[50, 0.0], [200, 0.9]]\ngradient_opacity = [[0, 0.3], [100, 1]]",
                        shading="enabled = true", render='classification = "pre"')     # values gathered
        whole = select_from_files(sc, axis)
        slab = select_from_files(sc, axis, slices=slices)
        assert slab.report.values_from == "augmented bricks"
        want = restrict(whole, axis, slices).axes[axis]
        for got, exp in zip(slab.axes[axis].arrays(), want.arrays()):
            assert got.dtype == exp.dtype and np.array_equal(got, exp)
        if axis in "jk" and len(slices) < {"j": 9, "k": 12}[axis] and index == v2:     # only its planes or rows
            assert slab.report.augmented_bytes < whole.report.augmented_bytes


def test_restrict_of_the_full_method_shares_the_channels(make_scene, volume):
    sc = scene(make_scene, volume, "orthographic", "azimuth = 0", method="full")
    sel = select_from_files(sc, "k")
    assert restrict(sel, "k", [1, 2]) is sel


def test_restrict_refuses_an_axis_not_selected():
    vol = np.zeros((6, 6, 6), np.uint8)
    vol[2:4, 2:4, 2:4] = 200
    from isplat.scene import parse_scene
    sc = parse_scene("[transfer]\nopacity = [[100, 0], [200, 0.8]]", ".", "t", data_required=False)
    sel = Selection.from_arrays(vol, sc, axes="k")
    with pytest.raises(IsplatError, match="axis i was not selected"):
        restrict(sel, "i", [0])


INSIDE = "mode = \"look_at\"\nposition = [0.5, 0.3, 0.2]\nlook_at = [3, -5, 2]"      # the eye inside the volume


@pytest.mark.parametrize("proj,cam", [("orthographic", "azimuth = 30\nelevation = 20"),
                                      ("orthographic", "azimuth = 100\nelevation = -50"), ("perspective", INSIDE)])
@pytest.mark.parametrize("et,method", [(0.9, "indexed"), (1.0, "indexed"), (0.9, "full")])
def test_a_frame_streamed_slab_by_slab_is_the_one_pass_frame(make_scene, volume, proj, cam, et, method):
    """render_streamed: each slab's selection made from the files, rendered over the slabs in front, dropped:
    the same image and counters as one pass (early termination included), whatever the number of slabs."""
    from isplat.renderer import Renderer
    from isplat.slabs import render_streamed

    sc = scene(make_scene, volume, proj, cam, et=et, method=method)
    r = Renderer(sc)
    want, st = r.render_view(0)
    for k in (1, 2, 3, 7):
        got, st_k, report = render_streamed(r.request, r.views[0], k)
        assert np.array_equal(got, want), k
        assert np.array_equal(Renderer(sc, slabs=k).render_view(0)[0], want), k      # the Renderer drives it
        assert (st_k.voxels_examined, st_k.drawn, st_k.slices) == (st.voxels_examined, st.drawn,
                                                                             st.slices)
        assert report.index_bytes >= r.report.index_block_bytes and report.axes == r.report.axes  # blocks, each slab
        if method == "full":
            assert report.augmented_bytes == r.report.augmented_bytes          # whole channels read once
        else:                                                   # each slab's reads and needs, added up
            assert report.voxels_of_interest == r.report.voxels_of_interest, k
            assert report.needed_voxels >= r.report.needed_voxels, k
        aug = open_augmented(sc.data.augmented)
        report = render_streamed(r.request, r.views[0], k, aug)[2]
        assert report.augmented_file_bytes == aug.io.bytes, k      # every slab's reads, the opening once


def test_cli_slabs_without_a_scheduler_stream_the_same_image(volume, tmp_path):
    import os
    import subprocess
    import sys

    import imageio.v3 as iio
    from conftest import scene_text

    aug, idx = volume
    (tmp_path / "s.toml").write_text(scene_text(aug, idx, image="width = 24\nheight = 20",
                                                transfer="opacity = [[50, 0.0], [200, 0.9]]"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    env["ISPLAT_PROGRESS"] = "0"
    for name, extra in (("one.png", []), ("slabs.png", ["--slabs", "4"])):
        res = subprocess.run([sys.executable, "-m", "isplat", "render", "s.toml", "-o", name, *extra], cwd=tmp_path,
                             capture_output=True, env=env)
        assert res.returncode == 0, res.stderr
    assert np.array_equal(iio.imread(tmp_path / "one.png"), iio.imread(tmp_path / "slabs.png"))


def test_a_selection_that_does_not_fit_is_streamed_by_itself(volume, tmp_path, monkeypatch, capsys):
    """Without --slabs, a render whose selection would not fit the memory left (here: made small) is rendered in
    the slabs slabs_needed asks for, says so on stderr, and writes the one-pass image."""
    import imageio.v3 as iio

    from conftest import scene_text
    from isplat import slabs as S
    from isplat.augfile import open_augmented
    from isplat.cli.main import main
    from isplat.scene import load_scene

    aug, idx = volume
    (tmp_path / "s.toml").write_text(scene_text(aug, idx, image="width = 24\nheight = 20",
                                                transfer="opacity = [[50, 0.0], [200, 0.9]]",
                                                render='classification = "pre"'))
    sc = load_scene(tmp_path / "s.toml")
    a = open_augmented(aug)
    views = F.views_for(sc, a)
    k, voxels = S.slabs_needed(sc, views, a, room=10 ** 12)
    assert k == 1 and voxels > 0
    room = 2 * voxels * S.PEAK_PER_VOXEL // 3 + 6    # a slab may take half of it: a third of the selection
    assert S.slabs_needed(sc, views, a, room=room)[0] == 3
    assert S.fits_anyway(sc, a, 10 ** 12) and not S.fits_anyway(sc, a, room)  # (the Renderer's check before counting)
    assert S.slabs_needed(sc, views, a, room=1)[0] == len(views[0].order)   # at most a slice per slab
    # post-classified, a slab holds its slices' channels too (density, and normals when shaded)
    post = load_scene(tmp_path / "s.toml", ['render.classification="post"'])
    assert S.slabs_needed(post, views, a, room=10 ** 12)[0] == 1
    assert S.slabs_needed(post, views, a, room=1)[0] == len(views[0].order)
    whole = int(np.prod(a.shape)) * (4 if post.shading.enabled else 1)   # (shaded: gradient magnitudes too)
    room_post = 2 * (voxels * S.PEAK_PER_VOXEL + whole) // 3 + 6
    assert S.slabs_needed(post, views, a, room=room_post)[0] == 3

    def render(name):
        with pytest.raises(SystemExit) as exc:
            main(["render", str(tmp_path / "s.toml"), "-o", str(tmp_path / name)])
        assert exc.value.code in (0, None)
        return iio.imread(tmp_path / name), capsys.readouterr().err
    one, err = render("one.png")
    assert "slabs front to back" not in err
    monkeypatch.setattr(S, "memory_room", lambda: room)
    streamed, err = render("auto.png")
    assert "each frame in 3 slabs front to back (--slabs 3)" in err
    assert np.array_equal(one, streamed)


@pytest.mark.parametrize("axis", ["k", "j", "i"])
def test_a_post_classified_slab_reads_only_its_slices_channels(make_scene, volume, axis):
    """Post-classification samples within a slice, so a slab's selection holds the channels of its slices alone
    (a block of the file), and its frame is the one-pass frame's slab."""
    sc = scene(make_scene, volume, "orthographic", "azimuth = 20\nelevation = 10", et=1.0)
    whole = select_from_files(sc, axis)
    n = whole.whole_volume(axis)
    slab = select_from_files(sc, axis, slices=range(2, 5))
    assert slab.slab == (axis, 2, 5) and whole.slab is None
    assert slab.report.augmented_bytes * 2 < whole.report.augmented_bytes
    per_slice = whole.whole.density.size // grid.slice_shape(whole.shape, axis)[0]
    assert slab.whole.density.size == 3 * per_slice
    w = slab.whole_volume(axis)
    # the flat index of voxel (a, b) of slice c reads the same density in both
    for c, a_, b_ in [(2, 0, 0), (4, n.n_a - 1, n.n_b - 1), (3, 1, 2)]:
        fw = c * n.strides[2] + a_ * n.strides[0] + b_ * n.strides[1] + n.strides[3]
        fs = c * w.strides[2] + a_ * w.strides[0] + b_ * w.strides[1] + w.strides[3]
        assert whole.whole.density[fw] == slab.whole.density[fs]
    with pytest.raises(IsplatError, match="not of axis"):
        slab.whole_volume("k" if axis != "k" else "i")


@pytest.mark.parametrize("cam", ["azimuth = 30\nelevation = 20", "azimuth = 100\nelevation = -10"])
def test_streamed_slabs_of_thick_slices_give_the_cubic_one_pass_frame(make_scene, tmp_path, cam):
    """Slices 5 times thicker than the pixels' spacing along k: post-classified frames take the cubic between
    slices along k (isplat.splat.post.between_slices), which reads the voxels before and after along an
    in-slice axis; a slab holds whole slices of the view's axis, so slab by slab is the one-pass image."""
    from isplat.normals import encode
    from isplat.renderer import Renderer
    from isplat.slabs import render_streamed
    from isplat.splat import post

    r = np.random.default_rng(5)
    shape = (8, 9, 10)
    dens = r.choice(np.array([0, 60, 120, 200], np.uint8), size=shape, p=[0.4, 0.2, 0.2, 0.2])
    vol = write_volume(tmp_path, dens, spacing=(1.0, 1.0, 5.0), gm=r.integers(0, 256, shape),
                       normal=encode(r.normal(size=shape + (3,))))
    sc = scene(make_scene, vol, "orthographic", cam)
    rend = Renderer(sc)
    assert post.between_slices((1.0, 1.0, 5.0), rend.views[0].axis_sign[0])[0] != 0
    want, _ = rend.render_view(0)
    for k in (2, 3):
        got, _, _ = render_streamed(rend.request, rend.views[0], k)
        assert np.array_equal(got, want), k


@pytest.fixture(scope="module")
def larger(tmp_path_factory):
    """A volume with many densities of interest and several chunks per table: slabs cut each density's rows."""
    r = np.random.default_rng(5)
    shape = (40, 36, 34)
    k, j, i = np.meshgrid(*[np.linspace(-1, 1, n) for n in shape], indexing="ij")
    dens = np.clip(255 * (1.2 - np.sqrt(k * k + j * j + i * i)) + r.normal(0, 12, shape), 0, 255).astype(np.uint8)
    return write_volume(tmp_path_factory.mktemp("slabreads"), dens)


def _loads(idx_path, axis, ivs, slabs, verify, shared):
    from isplat.index import open_index

    idx = open_index(idx_path)
    out = []
    with idx.shared_tables() if shared else idx.session():
        for s in slabs:
            out.append(idx.load_axis(axis, ivs, verify_offsets=verify, slices=s))
    return out, idx


@pytest.mark.parametrize("axis", ["k", "i"])
@pytest.mark.parametrize("verify", [False, True])
@pytest.mark.parametrize("n_slabs,reverse", [(3, False), (7, True), (40, False)])
def test_slabs_sharing_the_tables_load_what_each_slab_loads_alone(larger, axis, verify, n_slabs, reverse):
    """IndexFile.shared_tables: slab after slab (front to back either way), each load decodes exactly the blocks
    an unshared load of its slices decodes; what they need adds up to one whole load's need plus the two end
    offsets of each extra run of rows; and the index file is read about once, not once per slab."""
    from isplat.index import open_index

    _, idx_path = larger
    ivs = [(90, 180), (200, 255)]
    n = open_index(idx_path).n_slices(axis)
    slabs = [list(range(a, b)) for a, b in F.slab_bounds(n, n_slabs)]
    slabs = slabs[::-1] if reverse else slabs
    alone, _ = _loads(idx_path, axis, ivs, slabs, verify, shared=False)
    together, idx = _loads(idx_path, axis, ivs, slabs, verify, shared=True)
    for a, b in zip(alone, together):
        for name in ("slice_block_ptr", "block_density", "block_voxel_ptr", "positions"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
    [one], one_idx = _loads(idx_path, axis, ivs, [None], verify, shared=False)
    need = sum(la.bytes_needed for la in together)
    runs = len(slabs) * sum(hi - lo + 1 for lo, hi in ivs)         # at most a run of rows per density and slab
    assert one.bytes_read <= need <= one.bytes_read + 16 * runs, need
    assert idx.bytes_read == sum(la.bytes_read for la in together)          # the counters are what was read
    assert idx.io.bytes <= 1.5 * one_idx.io.bytes, (idx.io.bytes, one_idx.io.bytes)


@pytest.mark.parametrize("classification", ["pre", "post"])
def test_streamed_slabs_read_the_index_about_once(make_scene, larger, monkeypatch, classification):
    """A frame streamed in K slabs (render_streamed) reads the index's tables once for all its slabs: the bytes
    read from the index file and the bytes needed stay near the one-pass frame's as K grows (they grew with K
    when each slab read its intervals' tables again), and the report's totals are the counters of the files."""
    from isplat import index as I
    from isplat.renderer import Renderer
    from isplat.slabs import render_streamed

    sc = make_scene(*larger, image="width = 40\nheight = 36", camera="azimuth = 20\nelevation = 10",
                    transfer="opacity = [[150, 0.0], [200, 0.05], [255, 0.4]]",
                    render=f'threads = 1\nclassification = "{classification}"')
    r = Renderer(sc)
    want = r.render_view(0)[0]
    one = r.report
    opened = []
    real = I.open_index
    monkeypatch.setattr(I, "open_index", lambda *a, **k: opened.append(real(*a, **k)) or opened[-1])
    for k in (4, 16):
        aug = open_augmented(sc.data.augmented)
        got, _, rep = render_streamed(r.request, r.views[0], k, aug)
        assert np.array_equal(got, want), k
        idx = opened[-1]
        assert rep.index_file_bytes == idx.io.bytes and rep.index_bytes == idx.bytes_read, k   # what was read
        assert rep.augmented_file_bytes == aug.io.bytes, k
        # (measured: 1.38x at K = 4 and 16 -- every offset row of the intervals, read once -- where each slab
        # reading its intervals' tables again read 9.0x and 26.5x; needed 1.08-1.51x, two end offsets per run of
        # rows, where it counted the tables again: 2.0-6.7x)
        assert rep.index_file_bytes <= 1.5 * one.index_file_bytes, (k, rep.index_file_bytes, one.index_file_bytes)
        assert rep.index_bytes_needed <= 1.6 * one.index_bytes_needed, (k, rep.index_bytes_needed,
                                                                        one.index_bytes_needed)
