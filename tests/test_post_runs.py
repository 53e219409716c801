"""Post-classified frames from the range runs file (isplat.selection._read_post_runs, formats/runs.md): the image
equals, bit for bit, the images from whole channels and from bricks; a mismatched or damaged runs file is one
clear error; without it post reads bricks as before."""

import contextlib
import shutil

import h5py
import numpy as np
import pytest
from conftest import write_volume
from hypothesis import given, settings
from hypothesis import strategies as st
from test_post import random_normals

from isplat import selection as S
from isplat.splat import post as P
from isplat.errors import IsplatError
from isplat.renderer import Renderer
from isplat.runsfile import build_runs_file, runs_path

SHAPE = (26, 28, 24)
CAMERAS = ["azimuth = 0\nelevation = 0", "azimuth = 90\nelevation = 0", "azimuth = 0\nelevation = 90",
           "azimuth = 33\nelevation = 21"]
COLOR = "color = [[0, 1, 0.8, 0.6], [120, 0.9, 0.3, 0.2], [255, 1, 1, 0.9]]"
TFS = {
    "threshold": "opacity = [[170, 0.0], [180, 0.8], [255, 0.9]]\n" + COLOR,
    # a faint veil and bone: the zeros left by the runs not read interpolate into the veil (zero-filling alone
    # draws a wrong picture, the sampler's test of the quads held does not)
    "veil+bone": "opacity = [[60, 0.0], [70, 0.05], [95, 0.05], [105, 0.0], [170, 0.0], [180, 0.8], [255, 0.9]]\n"
                 + COLOR,
}


def smooth(r, shape, scale):
    g = r.normal(size=tuple(-(-n // scale) + 1 for n in shape))
    k = np.kron(g, np.ones((scale,) * 3))[:shape[0], :shape[1], :shape[2]]
    return k


def blur(v):
    """A separable 3-tap box blur (edges repeated): partial volumes at the boundaries, as a scanner's."""
    for d in range(3):
        p = np.pad(v, [(1, 1) if e == d else (0, 0) for e in range(3)], mode="edge")
        v = (np.take(p, range(0, v.shape[d]), d) + np.take(p, range(1, v.shape[d] + 1), d)
             + np.take(p, range(2, v.shape[d] + 2), d)) / 3
    return v


def head_like(seed, shape=SHAPE):
    """Air (about 5), soft tissue (about 140) whose blurred boundary with the air passes through the veil's
    codes (the skin), a bone shell (about 205) and soft tissue inside: the deep tissue's voxels are in no run a
    veil + bone scene reads, and zero-filled they would ramp through the veil."""
    r = np.random.default_rng(seed)
    k, j, i = np.meshgrid(*(np.linspace(-1, 1, n) for n in shape), indexing="ij")
    rad = np.sqrt((k / 0.9) ** 2 + (j / 0.85) ** 2 + (i / 0.8) ** 2) + 0.05 * smooth(r, shape, 4)
    v = np.where(rad < 0.95, 140.0, 5.0)
    v = np.where((rad > 0.3) & (rad < 0.45), 205.0, v)
    v = blur(v) + 3 * r.normal(size=shape) * (rad < 0.95)
    return np.clip(v, 0, 255).astype(np.uint8)


def chest_like(seed, shape=SHAPE):
    """A body (about 140) with two lungs (about 20) and a few bones (about 210), blurred: the lungs' walls and
    the skin pass through the veil's codes."""
    r = np.random.default_rng(seed)
    k, j, i = np.meshgrid(*(np.linspace(-1, 1, n) for n in shape), indexing="ij")
    body = (j / 0.8) ** 2 + (i / 0.95) ** 2 < 1
    lungs = ((j / 0.5) ** 2 + ((np.abs(i) - 0.45) / 0.3) ** 2 < 1) & (np.abs(k) < 0.8)
    v = np.where(body, 140.0, 3.0)
    v = np.where(lungs, 20.0, v)
    ribs = body & (np.abs(j) > 0.55) & (np.cos(k * 9) > 0.5)
    spine = (j > 0.45) & (j < 0.75) & (np.abs(i) < 0.15)
    v = np.where(ribs | spine, 220.0, v)
    v = blur(v) + 3 * smooth(r, shape, 3)
    return np.clip(v, 1, 255).astype(np.uint8)


VOLUMES = {"head": head_like, "chest": chest_like}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    out = {}
    for name, make in VOLUMES.items():
        tmp = tmp_path_factory.mktemp(name)
        dens = make(3)
        gm = np.clip(np.abs(np.gradient(dens.astype(float))[0]) * 4, 0, 255).astype(np.uint8)
        aug, idx = write_volume(tmp, dens, normal=random_normals(3, SHAPE), gm=gm, gscale=1.0)
        build_runs_file(aug, idx)
        out[name] = (aug, idx)
    return out


@contextlib.contextmanager
def without_runs(idx):
    p = runs_path(idx)
    keep = p.with_suffix(".away")
    shutil.move(p, keep)
    try:
        yield
    finally:
        shutil.move(keep, p)


@contextlib.contextmanager
def selection_setting(name: str, value):
    """isplat.selection's module setting ``name`` set to ``value`` for the block."""
    old = getattr(S, name)
    setattr(S, name, value)
    try:
        yield
    finally:
        setattr(S, name, old)


def brick_share(value):
    return selection_setting("BRICK_SHARE", value)


def three_images(sc, idx):
    """(runs, bricks, whole channels): each image and its renderer."""
    runs = Renderer(sc)
    with without_runs(idx):
        with brick_share(1.0):
            bricks = Renderer(sc)
        with brick_share(-1.0):
            whole = Renderer(sc)
    return [(r.render_view(0)[0], r) for r in (runs, bricks, whole)]


@pytest.mark.parametrize("cam", CAMERAS)
@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
@pytest.mark.parametrize("shade", [True, False])
@pytest.mark.parametrize("tf", sorted(TFS))
@pytest.mark.parametrize("vol", sorted(VOLUMES))
def test_runs_give_the_image_of_bricks_and_whole_channels(files, make_scene, vol, tf, shade, proj, cam):
    aug, idx = files[vol]
    sc = make_scene(aug, idx, camera=f'projection = "{proj}"\n{cam}', transfer=TFS[tf],
                    shading=f"enabled = {str(shade).lower()}", image="width = 44\nheight = 40",
                    render='classification = "post"\nearly_termination = 1.0')
    (img, r), (ib, rb), (iw, rw) = three_images(sc, idx)
    assert r.report.values_from.startswith("runs file"), r.report.values_from
    assert rb.report.values_from.startswith("bricks") and rw.report.values_from == "whole channels"
    assert r.selection.held is not None and rb.selection.held is None and rw.selection.held is None
    assert ("normal" in r.report.channels) == shade
    assert np.array_equal(img, ib) and np.array_equal(img, iw)
    assert img[..., 3].max() > 0.1
    loaded = np.count_nonzero(r.selection.whole.density)
    assert loaded < np.count_nonzero(rw.selection.whole.density)       # some voxels left out


def whole_shape(on: bool):
    """Channels held whole-shape (on) or as pools (off), whatever their bytes per voxel of interest."""
    return selection_setting("FLAT_BYTES_PER_VOXEL", 10 ** 9 if on else 0)


@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
@pytest.mark.parametrize("shade", [True, False])
@pytest.mark.parametrize("tf", sorted(TFS))
@pytest.mark.parametrize("vol", sorted(VOLUMES))
def test_whole_shape_channels_give_the_pools_image(files, make_scene, vol, tf, shade, proj):
    """The runs' packed pool and the bricks' pool placed whole-shape (selection._unpooled), with the runs' bits
    of the quads held in that layout, give their pools' images bit for bit."""
    aug, idx = files[vol]
    sc = make_scene(aug, idx, camera=f'projection = "{proj}"\nazimuth = 33\nelevation = 21', transfer=TFS[tf],
                    shading=f"enabled = {str(shade).lower()}", image="width = 44\nheight = 40",
                    render='classification = "post"')
    got = {}
    for flat in (False, True):
        with whole_shape(flat):
            runs = Renderer(sc)
            with without_runs(idx), brick_share(1.0):
                bricks = Renderer(sc)
        for name, r in (("runs", runs), ("bricks", bricks)):
            assert r.report.values_from.endswith(", held whole-shape") == flat, r.report.values_from
            assert r.selection.whole.pooled != flat
            got[name, flat] = r.render_view(0)[0]
        assert runs.selection.held is not None and bricks.selection.held is None
    assert got["runs", False][..., 3].max() > 0.1
    assert all(np.array_equal(img, got["runs", False]) for img in got.values())


@pytest.mark.parametrize("shade", [True, False])
def test_whole_shape_only_within_the_bytes_per_voxel_of_interest(files, make_scene, shade):
    """By default the channels are whole-shape exactly when that holds at most FLAT_BYTES_PER_VOXEL a voxel of
    interest (with the bits of the quads held), and the selection then holds no more: not for the bone alone
    (few voxels of interest), but for a veil over every tissue."""
    from isplat.stats import bytes_per_voxel

    aug, idx = files["head"]
    seen = set()
    for tf in (TFS["threshold"], "opacity = [[1, 0.0], [2, 0.02], [255, 0.02]]\n" + COLOR):
        sc = make_scene(aug, idx, camera="azimuth = 0\nelevation = 0", transfer=tf,
                        shading=f"enabled = {str(shade).lower()}", render='classification = "post"')
        for reads_runs in (True, False):
            with contextlib.ExitStack() as stack:
                if not reads_runs:
                    stack.enter_context(without_runs(idx))
                    stack.enter_context(brick_share(1.0))
                sel = Renderer(sc).selection
            rep = sel.report
            assert rep.values_from.startswith("runs file" if reads_runs else "bricks")
            need = S.flat_bytes(sel.shape, bytes_per_voxel({"density", *rep.channels}), len(sel.held or {}))
            fits = need <= S.FLAT_BYTES_PER_VOXEL * rep.voxels_of_interest
            assert rep.values_from.endswith(", held whole-shape") == fits, (rep.values_from, need)
            if fits:
                assert sel.held_bytes() <= S.FLAT_BYTES_PER_VOXEL * rep.voxels_of_interest
            seen.add(fits)
    assert seen == {True, False}


@pytest.mark.parametrize("vol", sorted(VOLUMES))
def test_runs_with_gradient_modulated_opacity(files, make_scene, vol):
    aug, idx = files[vol]
    sc = make_scene(aug, idx, camera='projection = "perspective"\nazimuth = 33\nelevation = 21',
                    transfer=TFS["veil+bone"] + "\ngradient_opacity = [[0, 0.2], [255, 1.0]]",
                    shading="enabled = true", image="width = 44\nheight = 40",
                    render='classification = "post"\nearly_termination = 1.0')
    (img, r), (ib, _), (iw, _) = three_images(sc, idx)
    assert r.report.values_from.startswith("runs file")
    assert "gradient_magnitude" in r.report.channels and r.selection.whole.gradient_magnitude.size
    assert np.array_equal(img, ib) and np.array_equal(img, iw)


@pytest.mark.parametrize("vol", sorted(VOLUMES))
def test_zero_filling_alone_draws_a_wrong_veil(files, make_scene, vol):
    """The test of the quads held is what makes the veil right: marked all held, the zeros show."""
    aug, idx = files[vol]
    sc = make_scene(aug, idx, camera='projection = "orthographic"\nazimuth = 33\nelevation = 21',
                    transfer=TFS["veil+bone"], shading="enabled = false", image="width = 44\nheight = 40",
                    render='classification = "post"\nearly_termination = 1.0')
    (img, r), _, (iw, _) = three_images(sc, idx)
    assert np.array_equal(img, iw)
    from dataclasses import replace
    r.selection = replace(r.selection, held={ax: np.full_like(b, 255) for ax, b in r.selection.held.items()})
    assert not np.array_equal(r.render_view(0)[0], iw)


def test_report_counts_the_runs_file(files, make_scene):
    aug, idx = files["chest"]
    sc = make_scene(aug, idx, camera="azimuth = 0\nelevation = 0", transfer=TFS["threshold"],
                    shading="enabled = true", render='classification = "post"')
    rep = Renderer(sc).report
    assert rep.runs_file_bytes > 0 and rep.values_path == str(runs_path(idx))
    assert rep.file_bytes == rep.augmented_file_bytes + rep.index_file_bytes + rep.runs_file_bytes
    assert rep.runs_file_pages >= rep.runs_file_bytes - 4096 * 64 and rep.bytes_needed > 0
    with without_runs(idx):
        rb = Renderer(sc).report
    assert rb.runs_file_bytes == 0 and rb.values_from.startswith("bricks")
    assert rep.channels == rb.channels and rep.bytes_needed == rb.bytes_needed


def test_slabs_and_thick_slices_keep_bricks(files, make_scene, tmp_path):
    aug, idx = files["head"]
    sc = make_scene(aug, idx, camera="azimuth = 0\nelevation = 0", transfer=TFS["threshold"],
                    render='classification = "post"')
    from isplat.request import RenderRequest
    from isplat.selection import select
    from isplat.augfile import open_augmented
    a = open_augmented(aug)
    sel = select(RenderRequest.from_files(sc, a, "k", None, range(3, 9)), a)
    assert sel.held is None and not sel.report.values_from.startswith("runs")
    thick = make_scene(aug, idx, camera="azimuth = 0\nelevation = 0", transfer=TFS["threshold"],
                       render='classification = "post"', volume="spacing = [1.0, 1.0, 5.0]")
    r = Renderer(thick)
    assert r.selection.held is None and not r.report.values_from.startswith("runs")


def _copy(files, tmp_path, name="head"):
    aug, idx = files[name]
    out = tmp_path / "c"
    out.mkdir()
    for p in (aug, idx, runs_path(idx)):
        shutil.copy(p, out / p.name)
    from isplat.index.store import values_path
    if values_path(idx).exists():
        shutil.copy(values_path(idx), out / values_path(idx).name)
    return out / aug.name, out / idx.name


def _scene(make_scene, aug, idx):
    return make_scene(aug, idx, camera="azimuth = 0\nelevation = 0", transfer=TFS["threshold"],
                      render='classification = "post"')


def test_runs_of_another_volume_refused(files, make_scene, tmp_path):
    aug, idx = _copy(files, tmp_path)
    shutil.copy(runs_path(files["chest"][1]), runs_path(idx))          # same shape, another density
    with pytest.raises(IsplatError, match="runs of another volume"):
        Renderer(_scene(make_scene, aug, idx))


@pytest.mark.parametrize("what", ["density", "positions", "garbage"])
def test_damaged_runs_file_refused(files, make_scene, tmp_path, what):
    aug, idx = _copy(files, tmp_path)
    p = runs_path(idx)
    if what == "garbage":
        p.write_bytes(b"not an HDF5 file at all" * 10)
    else:
        with h5py.File(p, "r+") as f:
            ds = f[f"runs/{what}"]
            v = ds[...]
            v ^= 0x5A
            ds[...] = v
    with pytest.raises(IsplatError) as exc:
        Renderer(_scene(make_scene, aug, idx))
    assert "\n" not in str(exc.value) and str(p.name) in str(exc.value)


def test_cli_render_reports_runs_and_falls_back(files, tmp_path, capsys):
    """isplat render -v says where the channel values came from; without the runs file, the bricks (or whole
    channels, more than BRICK_SHARE of them needed)."""
    import logging

    from conftest import scene_text

    from isplat.cli.main import main
    aug, idx = _copy(files, tmp_path, "chest")
    scene = tmp_path / "s.toml"
    scene.write_text(scene_text(aug, idx, transfer=TFS["veil+bone"], render='classification = "post"',
                                image="width = 32\nheight = 32"))
    outs = []
    for _ in range(2):
        logging.getLogger("isplat").handlers.clear()
        with pytest.raises(SystemExit) as ex:
            main(["-v", "render", str(scene), "-o", str(tmp_path / f"o{len(outs)}.png")])
        assert ex.value.code in (0, None)
        outs.append(capsys.readouterr().err)
        runs_path(idx).unlink(missing_ok=True)
    assert "channel values from runs file (" in outs[0] and "read/needed" in outs[0]
    assert "channel values from bricks (" in outs[1] or "channel values from whole channels" in outs[1]
    assert "runs file" not in outs[1]
    a = np.asarray(__import__("PIL.Image", fromlist=["Image"]).open(tmp_path / "o0.png"))
    b = np.asarray(__import__("PIL.Image", fromlist=["Image"]).open(tmp_path / "o1.png"))
    assert np.array_equal(a, b)


def test_stats_scene_says_runs(files, tmp_path, capsys):
    """isplat stats --scene: the runs file in the table and the JSON, its bytes in the bytes read."""
    import json

    from conftest import scene_text

    from isplat.cli.main import main
    aug, idx = files["head"]
    scene = tmp_path / "s.toml"
    scene.write_text(scene_text(aug, idx, transfer=TFS["veil+bone"], render='classification = "post"',
                                image="width = 32\nheight = 32"))
    outs = []
    for extra in (["--json"], []):
        with pytest.raises(SystemExit) as ex:
            main(["stats", str(aug), str(idx), "--scene", str(scene), "-q", *extra])
        assert ex.value.code in (0, None)
        outs.append(capsys.readouterr().out)
    ld = json.loads(outs[0])["scene"]["loaded"]
    assert ld["values_from"].startswith("runs file (") and ld["runs_path"] == str(runs_path(idx))
    assert ld["runs_file_bytes_read"] > 0 and ld["file_bytes_read"] >= ld["runs_file_bytes_read"]
    assert "the index's runs file" in outs[1] and "loaded: runs file" in outs[1]


def test_render_json_holds_what_stats_holds(files, tmp_path, capsys):
    """isplat render --json: the bytes held for the frames (and per voxel of interest) as isplat stats --scene
    counts them, for the runs file's pool and for whole channels (the runs file moved away)."""
    import json

    from conftest import scene_text

    from isplat.cli.main import main
    aug, idx = files["head"]
    scene = tmp_path / "s.toml"
    scene.write_text(scene_text(aug, idx, transfer=TFS["veil+bone"], render='classification = "post"',
                                image="width = 32\nheight = 32"))
    got = []
    for moved in (False, True):
        if moved:
            runs_path(idx).rename(tmp_path / "away.h5")
        try:
            for cmd in (["render", str(scene), "-o", str(tmp_path / "o.png"), "--force", "--json", "-q"],
                        ["stats", str(aug), str(idx), "--scene", str(scene), "--json", "-q"]):
                with pytest.raises(SystemExit) as ex:
                    main(cmd)
                assert ex.value.code in (0, None)
                got.append(json.loads(capsys.readouterr().out))
        finally:
            if moved:
                (tmp_path / "away.h5").rename(runs_path(idx))
    for r, st in (got[:2], got[2:]):
        ld = st["scene"]["loaded"]
        assert r["held_bytes"] == ld["held_bytes"] > 0 and r["voxels_of_interest"] == st["scene"]["voxels_of_interest"]
        assert r["held_bytes_per_voxel_of_interest"] == pytest.approx(ld["held_bytes_per_voxel_of_interest"])
    assert got[0]["values_from"].startswith("runs file (") and not got[2]["values_from"].startswith("runs file")
    assert got[0]["held_bytes"] != got[2]["held_bytes"]


def test_runs_read_only_the_channels_asked_for(files):
    """RunsFile.read(channels=): the normals and gradient magnitudes not asked for are not read (fewer bytes),
    the density and positions the same."""
    from isplat.runsfile import open_runs

    _, idx = files["chest"]
    got = {}
    for chans in ((), ("gradient_magnitude",), ("normal", "gradient_magnitude")):
        with open_runs(runs_path(idx)) as rf:
            got[chans] = rf.read([(60, 105), (170, 255)], chans)
    none, gm, both = got.values()
    assert none.normal.size == 0 and none.gradient_magnitude.size == 0 and gm.normal.size == 0
    assert np.array_equal(none.positions, both.positions) and np.array_equal(none.density, both.density)
    assert np.array_equal(gm.gradient_magnitude, both.gradient_magnitude) and both.normal.size == both.density.size
    assert none.bytes_read < gm.bytes_read < both.bytes_read
    with open_runs(runs_path(idx)) as rf, pytest.raises(ValueError):
        rf.read(None, ("density",))


@pytest.mark.parametrize("ivs", [[(60, 105), (170, 255)], [(1, 255)], [(200, 255)]])
def test_runs_placed_into_a_pool_equal_their_positions_and_values(files, ivs):
    """RunsFile.read(place=True): a row for each brick a run read (in brick order, 0 for the others), packed
    (rows sharing places), each voxel where its position (read without placing) says, zeros elsewhere; the loaded
    bits those voxels'."""
    from isplat.runsfile import open_runs

    _, idx = files["chest"]
    with open_runs(runs_path(idx)) as rf:
        runs = rf.read(ivs, ("normal", "gradient_magnitude"))
    with open_runs(runs_path(idx)) as rf:
        pool = rf.read(ivs, ("normal", "gradient_magnitude"), place=True)
    shape = rf.shape
    n = int(np.prod(shape))
    want = [np.zeros(n, a.dtype) for a in (runs.density, runs.gradient_magnitude, runs.normal)]
    for w, a in zip(want, (runs.density, runs.gradient_magnitude, runs.normal)):
        w[runs.positions] = a
    w = S.WholeChannels(pool.placed[0], pool.placed[2], pool.placed[1], table=pool.table, shape=tuple(shape),
                        bases=pool.bases, loaded=pool.loaded)
    for got, ref in zip(w.flat(), want):
        assert np.array_equal(got, ref)
    loaded = np.zeros(n, np.uint8)
    loaded[runs.positions] = 1
    rows = S.WholeChannels(np.unpackbits(pool.loaded.view(np.uint8), bitorder="little"), S._EMPTY_U8,
                           S._EMPTY_U16, table=pool.table, shape=tuple(shape))
    assert np.array_equal(rows.flat()[0], loaded)
    g = [-(-n // 8) for n in shape]
    brick_loaded = np.pad(loaded.reshape(shape), [(0, 8 * b - n) for b, n in zip(g, shape)]).reshape(
        g[0], 8, g[1], 8, g[2], 8).any(axis=(1, 3, 5)).reshape(-1)
    assert np.array_equal(pool.table > 0, brick_loaded) and brick_loaded.any()
    assert brick_loaded.all() == (ivs != [(200, 255)])          # (bone alone leaves bricks out)
    assert np.array_equal(pool.table[brick_loaded], np.arange(1, brick_loaded.sum() + 1))
    rows = brick_loaded.sum() + 1
    assert pool.bases.shape == (rows,) and 512 <= pool.placed[0].size <= rows * 512
    assert pool.placed[0].size < (rows - 1) * 512 or brick_loaded.all()    # (partial rows share places)
    place = pool.bases[pool.table.astype(np.int64)][:, None] + np.arange(512)   # every row's places, brick order
    bits = np.unpackbits(pool.loaded.view(np.uint8), bitorder="little").reshape(-1, 512) > 0
    bits = bits[pool.table.astype(np.int64)]
    assert np.unique(place[bits]).size == bits.sum() == runs.positions.size   # no place holds two voxels
    unread = np.ones(pool.placed[0].size, bool)
    unread[place[bits]] = False
    assert not pool.placed[0][unread].any()                     # zeros where no voxel lies


def test_runs_placed_on_a_daemon_thread():
    """The placing's thread (selection._in_daemon_thread) is a daemon, so an interrupted load exits without
    waiting for it; its result and its exception reach the caller through the future."""
    import threading

    from isplat.selection import _in_daemon_thread

    seen = {}

    def twice(x):
        seen["daemon"], seen["name"] = threading.current_thread().daemon, threading.current_thread().name
        return 2 * x

    assert _in_daemon_thread(twice, 21).result(timeout=60) == 42
    assert seen == {"daemon": True, "name": "isplat-runs"}
    with pytest.raises(ZeroDivisionError):
        _in_daemon_thread(lambda: 1 / 0).result(timeout=60)


@pytest.fixture(scope="module")
def larger_head(tmp_path_factory):
    """A head-like volume large enough that its runs' pool is well below whole channels."""
    shape = (64, 72, 80)
    dens = head_like(5, shape)
    gm = np.clip(np.abs(np.gradient(dens.astype(float))[0]) * 4, 0, 255).astype(np.uint8)
    aug, idx = write_volume(tmp_path_factory.mktemp("larger"), dens, normal=random_normals(3, shape), gm=gm,
                            gscale=1.0)
    build_runs_file(aug, idx)
    return aug, idx


@pytest.mark.parametrize("tf", list(TFS))
@pytest.mark.parametrize("shaded", [True, False])
def test_one_pass_from_the_runs_file_counted_before_the_load(larger_head, make_scene, tf, shaded):
    """selection.post_runs_bytes bounds what the one-pass frame from the runs file holds (its packed pool, table,
    deltas and quad bits; at most a few times it: the runs read and the pool's rows before they are packed are
    counted too, freed once placed and packed), and slabs_needed takes
    one pass when that fits where whole channels would not; pre-classified there is no such count."""
    import dataclasses

    from isplat import frame as F
    from isplat import slabs as S
    from isplat.augfile import open_augmented
    from isplat.request import RenderRequest
    from isplat.selection import _voxels_of_interest, post_runs_bytes, select

    aug, idx = larger_head
    sc = make_scene(aug, idx, camera="azimuth = 0\nelevation = 0", transfer=TFS[tf],
                    shading=f"enabled = {'true' if shaded else 'false'}", render='classification = "post"')
    a = open_augmented(aug)
    views = F.views_for(sc, a)
    req = RenderRequest.from_files(sc, a, F.axes_of(views))
    est = post_runs_bytes(req, a)
    sel = select(req, a)
    assert sel.report.values_from.startswith("runs file (")
    # the count before the load knows whether the channels will be held whole-shape
    assert sel.report.voxels_of_interest == _voxels_of_interest(req, sel.luts.intervals)
    assert post_runs_bytes(req, a, sel.report.voxels_of_interest) == est      # the caller's count, the same
    assert post_runs_bytes(req, a, 0) <= est <= post_runs_bytes(req, a, 10 ** 12)   # the pool; and beside it
    sel.whole.value_deltas()                                    # (made at the first frame)
    held = sel.whole.held_bytes() + sum(b.nbytes for b in sel.held.values())
    assert held <= est <= 4 * held
    n = sel.report.voxels_of_interest
    whole = int(np.prod(a.shape)) * (4 if shaded else 1)
    assert est < whole or not shaded          # shaded, the pool is well below whole channels (4 B a voxel) here;
    room = 2 * (n * S.PEAK_PER_VOXEL + est)   # unshaded, a density channel (1 B a voxel) may be below the pool
    assert S.slabs_needed(sc, views, a, room=room, request=req)[0] == 1     # (a slab may take half of the room)
    handed = []                       # slabs_needed hands post_runs_bytes the voxels of interest it counted
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("isplat.selection.post_runs_bytes", lambda r, au, voi=None: handed.append(voi) or est)
        S.slabs_needed(sc, views, a, room=1, request=req)         # (whole channels do not fit: asked)
    assert handed == [n]
    assert (S.slabs_needed(sc, views, a, room=room)[0] == 1) == (whole <= est)   # whole channels counted
    if whole > est:
        assert S.slabs_needed(sc, views, a, room=room - 2, request=req)[0] > 1     # (just too little: slabs)
    assert post_runs_bytes(dataclasses.replace(req, classification="pre"), a) is None
