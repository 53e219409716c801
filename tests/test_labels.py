"""Segmentation labels (docs/labels.md): the label channel of the augmented file, the scene's [labels] table, the
label sampling kernel against a slow obvious reference, renders in each label's colour, what a label scene
reads, and one stderr line per bad input."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from isplat import normals as N
from isplat.augfile import label_counts, open_augmented, write_augmented
from isplat.cli.main import main
from isplat.errors import IsplatError
from isplat.renderer import Renderer
from isplat.scene_schema import SCENE_VERSION

COLORS = {1: (1.0, 0.0, 0.0), 2: (0.0, 1.0, 0.0), 3: (0.0, 0.0, 1.0)}


def run(capsys, *argv):
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return e.value.code, out, err


def one_error(code, err, *needles):
    assert code != 0 and "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("isplat: error: "), err
    for n in needles:
        assert n in lines[0], (n, lines[0])


def three_boxes(shape=(12, 16, 36)):
    """Density 0 everywhere; labels 1, 2, 3 as three boxes side by side along i (and a fourth id, 4, unshown)."""
    lab = np.zeros(shape, np.uint8)
    lab[3:9, 4:12, 3:11] = 1
    lab[3:9, 4:12, 14:22] = 2
    lab[3:9, 4:12, 25:33] = 3
    lab[0, 0, 0] = 4
    return lab


def write_labelled(path, lab, density=None):
    d = np.zeros(lab.shape, np.uint8) if density is None else density
    write_augmented(path, d, np.zeros_like(d), np.full(d.shape, 0x8080, np.uint16), (1.0, 1.0, 1.0), (0.0, 255.0),
                    0.0, labels=lab)
    return path


def label_scene(tmp_path, aug, shown=(1, 2, 3), extra="", size=96):
    text = (f'version = {SCENE_VERSION}\n[data]\naugmented = "{aug}"\n[render]\nmethod = "full"\n[image]\nwidth = {size}\n'
            f'height = {size}\n[camera]\nelevation = 90\n[transfer]\nopacity = [[0, 0], [255, 0]]\n'
            f'[shading]\nenabled = false\n{extra}')
    for i in shown:
        text += f"[labels.{i}]\ncolor = {list(COLORS[i])}\nopacity = 1.0\n"
    p = tmp_path / "labels.toml"
    p.write_text(text)
    return p


# ---- the label channel -------------------------------------------------------------------------------------------

@settings(max_examples=25, deadline=None)
@given(largest=st.integers(1, 65535), seed=st.integers(0, 2 ** 32 - 1))
def test_label_channel_round_trips(tmp_path_factory, largest, seed):
    """Any ids 0..65535 are written (uint8 up to 255, else uint16) and read back exactly, with their counts."""
    rng = np.random.default_rng(seed)
    lab = rng.integers(0, largest + 1, size=(3, 4, 5)).astype(np.int64)
    lab.flat[0] = largest
    p = write_labelled(tmp_path_factory.mktemp("l") / "v.aug.h5", lab)
    aug = open_augmented(p)
    assert aug.read("labels").tolist() == lab.tolist()
    assert aug.label_voxels.tolist() == np.bincount(lab.ravel(), minlength=2).tolist()
    with h5py.File(p) as f:
        assert f["labels"].dtype == (np.uint8 if largest <= 255 else np.dtype("<u2"))
    assert label_counts(lab).sum() == lab.size


def test_label_ids_beyond_the_counts_are_refused(tmp_path):
    p = write_labelled(tmp_path / "v.aug.h5", three_boxes())
    with h5py.File(p, "a") as f:                # counts cut short, hashes recomputed as a writer would
        from isplat.augfile import finish_augmented

        c = f["label_voxels"][()]
        del f["label_voxels"], f["chunk_hashes"], f["brick_hashes"]     # (augmented format 6: + the brick hashes)
        del f.attrs["chunk_hash_check"]
        f.create_dataset("label_voxels", data=np.r_[c[:2], c[2:].sum()].astype("<i8"), chunks=(3,),
                         fletcher32=True)
        f["labels"][0, 0, 0] = 9
        finish_augmented(f)
    aug = open_augmented(p)
    with pytest.raises(IsplatError, match="'labels' holds id 9, expected ids below 3"):
        aug.read("labels")


# ---- the sampling kernel against a slow obvious reference ----------------------------------------------------------

def reference_label_at(lab3, axis, a, b, c, shown):
    """Slow and obvious: the weights of each shown label's indicator among the quad's four voxels (bilinear, the
    edge voxel repeated), the largest if above 1/2."""
    from isplat import grid

    n_c, n_a, n_b = grid.slice_shape(lab3.shape, axis)
    ia, ib, ic = grid.SLICE_AXES[axis]
    a0, b0 = int(np.floor(a)), int(np.floor(b))
    fu, fv = a - a0, b - b0
    weights = {}
    for da, wa in ((0, 1 - fu), (1, fu)):
        for db, wb in ((0, 1 - fv), (1, fv)):
            pos = [0, 0, 0]
            pos[ia], pos[ib], pos[ic] = min(a0 + da, n_a - 1), min(b0 + db, n_b - 1), c
            lid = int(lab3[pos[2], pos[1], pos[0]])
            if lid in shown:
                weights[lid] = weights.get(lid, 0.0) + wa * wb
    if not weights:
        return -1
    best = max(weights, key=lambda k: (weights[k], -k))
    return best if weights[best] > 0.5 else -1


@pytest.mark.parametrize("axis", ["i", "j", "k"])
def test_label_at_matches_the_reference(axis):
    from isplat import grid
    from isplat.label_select import LabelSelection
    from isplat.splat.labels import label_at

    rng = np.random.default_rng(3)
    lab3 = rng.integers(0, 5, size=(7, 8, 9)).astype(np.uint16)
    shown = {1, 3, 4}
    table = np.zeros((5, 4))
    for i in shown:
        table[i] = (1, 1, 1, 0.5)
    steps = LabelSelection(lab3.reshape(-1), table, lab3.shape, np.zeros(0, np.uint16)).frame_steps(axis)
    n_c, n_a, n_b = grid.slice_shape(lab3.shape, axis)
    for _ in range(3000):
        a, b, c = rng.uniform(0, n_a - 1 + 0.49), rng.uniform(0, n_b - 1 + 0.49), int(rng.integers(0, n_c))
        if rng.random() < 0.2:          # on the quads' edges
            a = float(int(a))
        a0, b0 = int(a), int(b)
        got, w = label_at(lab3.reshape(-1), table, steps, n_a, n_b, a0, b0, c, a - a0, b - b0)
        want = reference_label_at(lab3, axis, a, b, c, shown)
        if want != got:     # a tie of two labels at exactly the same weight may go either way; none above 1/2
            assert want == -1 or abs(w - 0.5) < 1e-12, (a, b, c, got, want)


def reference_label_normals(lab3, lid, spacing, sigma=1.0, radius=3):
    """Slow and obvious: the indicator convolved with a 7 x 7 x 7 Gaussian (edges extended), central differences
    in physical units (one-sided at the edges), at each voxel of the label."""
    ind = np.pad((lab3 == lid).astype(np.float64), radius, mode="edge")
    x = np.arange(-radius, radius + 1)
    g1 = np.exp(-0.5 * (x / sigma) ** 2)
    g1 /= g1.sum()
    kern = g1[:, None, None] * g1[None, :, None] * g1[None, None, :]
    sm = np.zeros(lab3.shape)
    for k in range(lab3.shape[0]):
        for j in range(lab3.shape[1]):
            for i in range(lab3.shape[2]):
                sm[k, j, i] = (ind[k:k + 2 * radius + 1, j:j + 2 * radius + 1, i:i + 2 * radius + 1] * kern).sum()
    gk, gj, gi = np.gradient(sm)
    return np.stack([gi / spacing[0], gj / spacing[1], gk / spacing[2]], axis=-1)


def test_label_normals_match_the_reference():
    from isplat.labels import label_normals

    lab3 = np.zeros((9, 10, 11), np.uint16)
    k, j, i = np.meshgrid(np.arange(9), np.arange(10), np.arange(11), indexing="ij")
    lab3[(i - 5.2) ** 2 + (j - 4.6) ** 2 + ((k - 4.1) * 1.5) ** 2 < 12] = 2
    lab3[:2] = 7
    spacing = (1.0, 1.0, 1.5)
    codes = label_normals(lab3, [2], spacing)
    assert np.all(codes[lab3 != 2] == N.NO_NORMAL)
    ref = reference_label_normals(lab3, 2, spacing)[lab3 == 2]
    got = N.decode(codes[lab3 == 2])
    ok = np.linalg.norm(ref, axis=1) > 1e-6
    cos = (got[ok] * (ref[ok] / np.linalg.norm(ref[ok], axis=1)[:, None])).sum(axis=1)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 1.0      # oct16's error is at most 0.64 degrees


def test_label_normals_follow_a_sphere():
    """On a voxelised sphere the smoothed indicator's normals are close to the true ones (smooth, not blocky)."""
    from isplat.labels import label_normals

    n = 40
    k, j, i = np.meshgrid(*[np.arange(n)] * 3, indexing="ij")
    r = np.sqrt((i - 19.3) ** 2 + (j - 20.1) ** 2 + (k - 19.7) ** 2)
    lab3 = (r < 12).astype(np.uint16)
    codes = label_normals(lab3, [1], (1.0, 1.0, 1.0))
    shell = (lab3 == 1) & (r > 11)
    true = -np.stack([i - 19.3, j - 20.1, k - 19.7], axis=-1)[shell] / r[shell][:, None]
    ang = np.degrees(np.arccos(np.clip((N.decode(codes[shell]) * true).sum(axis=1), -1, 1)))
    assert np.median(ang) < 4 and np.percentile(ang, 95) < 10, (np.median(ang), np.percentile(ang, 95))


def test_label_shade_is_the_renormalised_corner_interpolation():
    from isplat.splat.labels import _label_shade

    rng = np.random.default_rng(5)
    lab3 = rng.integers(0, 3, size=(4, 5, 6)).astype(np.uint16)
    nrm = rng.integers(0, 65536, size=lab3.shape).astype(np.uint16)
    shade = rng.random((65536, 6)).astype(np.float32)
    steps = np.array([1, 6, 30, 4], np.int64)                           # axis k: a = i, b = j
    for _ in range(500):
        a0, b0, c = int(rng.integers(0, 6)), int(rng.integers(0, 5)), int(rng.integers(0, 4))
        fu, fv, lid = rng.random(), rng.random(), int(rng.integers(1, 3))
        got = _label_shade(lab3.ravel(), nrm.ravel(), steps, shade, 6, 5, a0, b0, c, fu, fv, lid)
        acc, wsum = np.zeros(6), 0.0
        for da, wa in ((0, 1 - fu), (1, fu)):
            for db, wb in ((0, 1 - fv), (1, fv)):
                a, b = min(a0 + da, 5), min(b0 + db, 4)
                if lab3[c, b, a] == lid:
                    acc += wa * wb * shade[nrm[c, b, a]]
                    wsum += wa * wb
        want = acc / wsum if wsum > 0 else acc
        assert np.allclose(got, want, rtol=1e-5, atol=1e-6)


# ---- renders and reads -------------------------------------------------------------------------------------------

def test_three_labels_render_in_their_colours(capsys, tmp_path):
    aug = write_labelled(tmp_path / "v.aug.h5", three_boxes())
    scene = label_scene(tmp_path, aug)
    out = tmp_path / "l.png"
    code, _, err = run(capsys, "render", scene, "-o", out, "-q")
    assert code == 0, err
    from PIL import Image

    img = np.asarray(Image.open(out).convert("RGB")).astype(int)
    cols = {}
    for lid, c in COLORS.items():
        ch = int(np.argmax(c))
        mine = (img[..., ch] > 200) & (img.sum(axis=-1) - img[..., ch] < 30)
        assert mine.sum() > 150, (lid, mine.sum())      # each label a solid patch of its own colour
        cols[lid] = np.nonzero(mine)[1].mean()
    assert cols[1] < cols[2] < cols[3] or cols[1] > cols[2] > cols[3]   # side by side along i, in order
    # nothing else: no grey, no blend of two labels' colours
    lit = img.sum(axis=-1) > 60
    pure = np.zeros_like(lit)
    for c in COLORS.values():
        ch = int(np.argmax(c))
        pure |= (img[..., ch] > 60) & (img.sum(axis=-1) - img[..., ch] < 30)
    assert (lit & ~pure).sum() < 0.05 * lit.sum()



def test_a_label_that_stops_a_pixel_fills_it_with_its_colour(tmp_path):
    """A shown label's sample that takes a pixel to the early-termination opacity fills the rest of its
    transmittance with the label's colour (render.termination = "fill", scene version 7): seen through a label's
    box, a pixel is opaque in exactly that colour; with "stop" it keeps the opacity it reached."""
    from isplat.scene import load_scene

    aug = write_labelled(tmp_path / "v.aug.h5", three_boxes())
    out = {}
    for term in ("fill", "stop"):
        p = label_scene(tmp_path, aug, size=48)
        # both at one opacity (a stopped pixel's default is 0.99, a filled one's 0.986)
        text = p.read_text().replace('method = "full"', f'method = "full"\ntermination = "{term}"\n'
                                     'early_termination = 0.99')
        text = text.replace("height = 48\n", "height = 48\nbackground = [0.0, 0.0, 0.0, 0.0]\n", 1)
        text = text.replace("opacity = 1.0\n", "opacity = 0.6\n")     # 6 voxels deep: 1 - 0.4^6 > 0.99
        p.write_text(text)
        img, _ = Renderer(load_scene(p)).render_view(0)
        out[term] = img
    fill, stop = out["fill"], out["stop"]
    seen = stop[..., 3] >= 0.99           # through a box: its voxels stop the pixel
    assert seen.sum() > 100
    assert np.all(fill[seen, 3] == 1.0) and np.all(stop[seen, 3] < 1.0)
    red = fill[seen][np.argmax(fill[seen][:, 0])]
    assert np.allclose(red[:3], COLORS[1], atol=1e-5)            # straight colour: the label's own
    assert np.array_equal(fill[~seen], stop[~seen])

def test_a_scene_showing_one_label_selects_only_its_voxels(capsys, tmp_path):
    lab = three_boxes()
    aug = write_labelled(tmp_path / "v.aug.h5", lab)
    scene = label_scene(tmp_path, aug, shown=(2,))
    code, out, err = run(capsys, "stats", aug, "--scene", scene, "--json")
    assert code == 0, err
    sc = json.loads(out)["scene"]
    assert sc["voxels_of_interest"] == int((lab == 2).sum())       # the density selects nothing here
    assert sc["labels"] == [{"id": 2, "name": None, "voxels": int((lab == 2).sum())}]
    assert "labels" in sc["loaded"]["channels"]


def test_pre_technique_refuses_labels(capsys, tmp_path):
    aug = write_labelled(tmp_path / "v.aug.h5", three_boxes())
    scene = label_scene(tmp_path, aug)
    code, _, err = run(capsys, "render", scene, "-o", tmp_path / "x.png", "--set", 'render.classification="pre"')
    one_error(code, err, "post-classified technique only")


def test_an_intensity_projection_refuses_labels(capsys, tmp_path):
    aug = write_labelled(tmp_path / "v.aug.h5", three_boxes())
    scene = label_scene(tmp_path, aug)
    for mode in ("mip", "minip"):
        code, _, err = run(capsys, "render", scene, "-o", tmp_path / "x.png", "--set", f'render.mode="{mode}"')
        one_error(code, err, f'render.mode = "{mode}" shows one density per pixel')
    assert not (tmp_path / "x.png").exists()


# ---- bad inputs: one line each -------------------------------------------------------------------------------------

def test_augment_refuses_a_label_map_on_another_grid(capsys, tmp_path):
    np.save(tmp_path / "ct.npy", np.arange(4 * 5 * 6, dtype=np.int16).reshape(4, 5, 6))
    np.save(tmp_path / "mask.npy", np.zeros((4, 5, 7), np.uint8))
    code, _, err = run(capsys, "augment", tmp_path / "ct.npy", "-o", tmp_path / "o.aug.h5", "--labels",
                       tmp_path / "mask.npy")
    one_error(code, err, "mask.npy", "NI,NJ,NK=7,5,4", "6,5,4")
    assert not (tmp_path / "o.aug.h5").exists()
    np.save(tmp_path / "mask.npy", np.full((4, 5, 6), -1, np.int16))
    code, _, err = run(capsys, "augment", tmp_path / "ct.npy", "-o", tmp_path / "o.aug.h5", "--labels",
                       tmp_path / "mask.npy")
    one_error(code, err, "mask.npy", "expected ids 0..65535")


def test_augment_stores_labels(capsys, tmp_path):
    np.save(tmp_path / "ct.npy", np.arange(4 * 5 * 6, dtype=np.int16).reshape(4, 5, 6))
    lab = np.zeros((4, 5, 6), np.float32)
    lab[1:3, 1:4, 2:5] = 300
    np.save(tmp_path / "mask.npy", lab)
    code, _, err = run(capsys, "augment", tmp_path / "ct.npy", "-o", tmp_path / "o.aug.h5", "--labels",
                       tmp_path / "mask.npy", "-q")
    assert code == 0, err
    a = open_augmented(tmp_path / "o.aug.h5")
    assert a.read("labels").tolist() == lab.astype(int).tolist() and a.label_voxels.shape == (301,)
    a.verify_all()


def test_a_label_the_file_lacks_is_one_line(capsys, tmp_path):
    aug = write_labelled(tmp_path / "v.aug.h5", three_boxes())
    scene = label_scene(tmp_path, aug, extra="[labels.9]\ncolor = [1, 1, 0]\n")
    code, _, err = run(capsys, "render", scene, "-o", tmp_path / "x.png")
    one_error(code, err, "labels.toml:", "labels.9", "label 9 is not in", "ids present: 1, 2, 3, 4")


def test_a_bad_colour_is_one_line(capsys, tmp_path):
    aug = write_labelled(tmp_path / "v.aug.h5", three_boxes())
    scene = label_scene(tmp_path, aug, shown=(), extra="[labels.2]\ncolor = [1, 2]\n")
    code, _, err = run(capsys, "render", scene, "-o", tmp_path / "x.png")
    one_error(code, err, "labels.toml:16: labels.2.color = [1, 2]", "expected 3 numbers in [0, 1]")


def test_names_map(capsys, tmp_path):
    aug = write_labelled(tmp_path / "v.aug.h5", three_boxes())
    (tmp_path / "names.json").write_text(json.dumps({"1": "liver", "2": "spleen", "3": "aorta"}))
    (tmp_path / "names.csv").write_text("id,name\n1,liver\n2,spleen\n3,aorta\n")
    for names in ("names.json", "names.csv"):
        scene = label_scene(tmp_path, aug, shown=(),
                            extra=f'[labels]\nnames = "{names}"\n[labels.spleen]\ncolor = [0, 1, 0]\n')
        code, _, err = run(capsys, "render", scene, "-o", tmp_path / "x.png", "--force", "-q")
        assert code == 0, err
        scene.write_text(scene.read_text().replace("labels.spleen", "labels.kidney"))
        code, _, err = run(capsys, "render", scene, "-o", tmp_path / "x.png", "--force")
        one_error(code, err, "labels.toml:", "labels.kidney", f"no label of that name in {names}")
    scene = label_scene(tmp_path, aug, shown=(), extra='[labels]\nnames = "missing.json"\n')
    code, _, err = run(capsys, "render", scene, "-o", tmp_path / "x.png", "--force")
    one_error(code, err, "labels.names", "missing.json", "cannot read")
    scene = label_scene(tmp_path, aug, shown=(), extra="[labels.liver]\ncolor = [1, 0, 0]\n")
    code, _, err = run(capsys, "render", scene, "-o", tmp_path / "x.png", "--force")
    one_error(code, err, "labels.liver", "needs labels.names")


def test_labels_need_scene_version_6(capsys, tmp_path):
    aug = write_labelled(tmp_path / "v.aug.h5", three_boxes())
    scene = label_scene(tmp_path, aug)
    scene.write_text(scene.read_text().replace(f"version = {SCENE_VERSION}", "version = 5"))
    code, _, err = run(capsys, "render", scene, "-o", tmp_path / "x.png")
    one_error(code, err, "[labels] is new in scene version 6")


def test_sample_ct_chest_labels(capsys, tmp_path):
    code, out, err = run(capsys, "sample", "ct-chest", "-o", tmp_path / "c.npy", "--shape", "32,24,20", "--labels",
                         tmp_path / "l.npy", "-q")
    assert code == 0, err
    assert "--labels" in out
    lab = np.load(tmp_path / "l.npy")
    names = json.loads((tmp_path / "l.json").read_text())
    assert lab.shape == (20, 24, 32) and lab.dtype == np.uint8
    assert set(np.unique(lab).tolist()) <= set(range(9)) and names["5"] == "heart"
    assert (lab == 5).sum() > 0 and (lab == 3).sum() > 0
    code, _, err = run(capsys, "sample", "head", "-o", tmp_path / "h.npy", "--labels", tmp_path / "hl.npy")
    one_error(code, err, "only ct-chest")


# ---- the index of the labels (formats/index.md §10) ----------------------------------------------------------------

@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), largest=st.integers(1, 255), axis=st.sampled_from("ijk"))
def test_label_index_gives_back_the_shown_labels(tmp_path_factory, seed, largest, axis):
    from isplat.index.labels import build_label_index_file, open_label_index, shown_ids_volume

    rng = np.random.default_rng(seed)
    shape = tuple(int(x) for x in rng.integers(1, 7, size=3))
    lab = (rng.random(shape) < 0.6) * rng.integers(1, largest + 1, size=shape)
    lab.flat[0] = largest
    d = tmp_path_factory.mktemp("li")
    aug = open_augmented(write_labelled(d / "v.aug.h5", lab))
    build_label_index_file(aug, d / "v.labels.idx.h5", "ijk")
    idx = open_label_index(d / "v.labels.idx.h5", aug)
    shown = sorted(set(rng.integers(1, largest + 1, size=3).tolist()))
    ids, _ = shown_ids_volume(idx, axis, shown, aug.shape)
    assert ids.tolist() == np.where(np.isin(lab, shown), lab, 0).reshape(-1).tolist()


def test_a_scene_showing_one_label_reads_only_its_blocks(capsys, tmp_path):
    """With the index of the labels beside the density's, a scene showing label 2 of 3 reads that label's blocks
    and not the label channel; its image is bit for bit the one made from the label channel."""
    from isplat.index import build_index_file

    lab = three_boxes((24, 32, 72))
    aug = write_labelled(tmp_path / "v.aug.h5", lab)
    build_index_file(aug, tmp_path / "v.idx.h5")
    assert (tmp_path / "v.labels.idx.h5").exists()
    scene = label_scene(tmp_path, aug, shown=(2,))
    scene.write_text(scene.read_text().replace('method = "full"', 'method = "indexed"')
                     .replace(f'augmented = "{aug}"', f'augmented = "{aug}"\nindex = "{tmp_path / "v.idx.h5"}"'))
    code, out, err = run(capsys, "stats", aug, tmp_path / "v.idx.h5", "--scene", scene, "--json")
    assert code == 0, err
    loaded = json.loads(out)["scene"]["loaded"]
    assert "labels" not in loaded["channels"]
    assert 0 < loaded["index_bytes"] < lab.size // 10       # label 2's blocks and table rows, not the channel
    assert loaded["augmented_bytes"] == lab.size        # the density (shading is off here), not the labels
    code, _, err = run(capsys, "render", scene, "-o", tmp_path / "a.png", "-q")
    assert code == 0, err
    scene.write_text(scene.read_text().replace('method = "indexed"', 'method = "full"'))
    code, _, err = run(capsys, "render", scene, "-o", tmp_path / "b.png", "-q")
    assert code == 0, err
    from PIL import Image

    a, b = (np.asarray(Image.open(tmp_path / n)) for n in ("a.png", "b.png"))
    assert np.array_equal(a, b) and a[..., 1].max() > 200


def test_a_label_index_of_other_labels_is_refused(capsys, tmp_path):
    from isplat.index import build_index_file

    lab = three_boxes()
    aug = write_labelled(tmp_path / "v.aug.h5", lab)
    build_index_file(aug, tmp_path / "v.idx.h5")
    other = lab.copy()
    other[other == 3] = 1
    write_labelled(tmp_path / "w.aug.h5", other)
    build_index_file(tmp_path / "w.aug.h5", tmp_path / "w.idx.h5")
    (tmp_path / "w.labels.idx.h5").replace(tmp_path / "v.labels.idx.h5")
    scene = label_scene(tmp_path, aug, shown=(2,))
    scene.write_text(scene.read_text().replace('method = "full"', 'method = "indexed"')
                     .replace(f'augmented = "{aug}"', f'augmented = "{aug}"\nindex = "{tmp_path / "v.idx.h5"}"'))
    code, _, err = run(capsys, "render", scene, "-o", tmp_path / "x.png")
    one_error(code, err, "v.labels.idx.h5", "labels_sha256 differs", "isplat index")


def test_uint16_labels_in_perspective(capsys, tmp_path):
    """Ids above 255 (stored as uint16, not indexed: the channel is read) render in their colours, in perspective."""
    from isplat.index import build_index_file

    lab = three_boxes().astype(np.uint16)
    lab[lab == 1], lab[lab == 3] = 300, 5464
    aug = write_labelled(tmp_path / "v.aug.h5", lab)
    build_index_file(aug, tmp_path / "v.idx.h5")
    assert not (tmp_path / "v.labels.idx.h5").exists()
    scene = label_scene(tmp_path, aug, shown=(2,), extra='[labels.300]\ncolor = [1, 0, 0]\n[labels.5464]\n'
                                                          'color = [0, 0, 1]\n')
    scene.write_text(scene.read_text().replace("[camera]\n", '[camera]\nprojection = "perspective"\n'))
    code, _, err = run(capsys, "render", scene, "-o", tmp_path / "p.png", "-q")
    assert code == 0, err
    from PIL import Image

    img = np.asarray(Image.open(tmp_path / "p.png").convert("RGB")).astype(int)
    for ch in range(3):
        assert ((img[..., ch] > 200) & (img.sum(axis=-1) - img[..., ch] < 30)).sum() > 150, ch
