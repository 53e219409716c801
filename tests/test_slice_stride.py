"""render.slice_stride (issue 27 item 3): the post-classified sampler samples every n-th slice of the principal
axis, each sample's opacity corrected for the path of n slices; against the slow reference
(tests/post_reference.py), a closed form, the one-pass frame in slabs, and refused in one line where it does not
apply. Its speed and error are measured in benchmarks/accuracy.py (docs/accuracy.md), not here."""

import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import scene_text, write_volume
from post_reference import post_reference

from isplat.errors import IsplatError
from isplat.renderer import Renderer

TF = "opacity = [[50, 0.0], [60, 0.3], [130, 0.1], [200, 0.9]]\ncolor = [[0, 1, 0, 0], [255, 0, 0.5, 1]]"
CAMERAS = ["azimuth = 0\nelevation = 0", "azimuth = 180\nelevation = 0", "azimuth = 33\nelevation = 21",
           "azimuth = 150\nelevation = -40", "azimuth = 0\nelevation = 90"]


def volume(tmp, seed, shape, spacing=(1.0, 1.2, 0.8)):
    from isplat.normals import encode

    r = np.random.default_rng(seed)
    dens = r.choice(np.array([0, 60, 120, 200], np.uint8), size=shape, p=[0.55, 0.15, 0.15, 0.15])
    return write_volume(tmp, dens, spacing=spacing, gm=r.integers(0, 256, shape),
                        normal=encode(r.normal(size=shape + (3,))))


def stride_scene(make_scene, vol, cam, stride, proj="orthographic", et=1.0, **kw):
    kw.setdefault("image", "width = 24\nheight = 20")
    kw.setdefault("transfer", TF)
    kw.setdefault("shading", "enabled = true")
    return make_scene(*vol, camera=f'projection = "{proj}"\n{cam}',
                      render=f'early_termination = {et}\nslice_stride = {stride}', **kw)


@pytest.mark.parametrize("stride", [2, 3])
@pytest.mark.parametrize("cam", CAMERAS)
@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
def test_stride_agrees_with_the_reference_for_both_methods(tmp_path, make_scene, cam, proj, stride):
    """Every n-th slice (by its index), each for the path of n slices: the kernel is the reference's image (both
    methods, orthographic and perspective), and not the every-slice image."""
    vol = volume(tmp_path, 1, (7, 6, 8))
    sc = stride_scene(make_scene, vol, cam, stride, proj)
    ind, st_i = Renderer(sc, method="indexed").render_view(0)
    full, st_f = Renderer(sc, method="full").render_view(0)
    ref = post_reference(sc)
    assert np.abs(ind - full).max() <= 1e-6 and st_i.drawn == st_f.drawn > 0
    assert np.abs(ind - ref).max() <= 2e-4
    assert ref[..., 3].max() > 0.2
    assert np.abs(ind - post_reference(sc, stride=1)).max() > 1e-3


@pytest.mark.parametrize("cam", CAMERAS[2:4])
def test_stride_with_the_cubic_between_thick_slices(tmp_path, make_scene, cam):
    """A grid thick enough for the cubic between slices (THICK_RATIO) with a stride of 2: both knobs, as the
    reference has them."""
    vol = volume(tmp_path, 3, (6, 7, 8), spacing=(1.0, 0.9, 4.5))
    sc = stride_scene(make_scene, vol, cam, 2)
    img, _ = Renderer(sc).render_view(0)
    assert np.abs(img - post_reference(sc)).max() <= 2e-4


def test_a_uniform_block_gives_the_closed_form_of_its_sampled_slices(tmp_path, make_scene):
    """A uniform block of 8 slices seen head-on: the slices 0, n, 2n, ... are sampled, each with opacity
    1 - (1 - alpha)^n, so a pixel sees 1 - (1 - alpha)^(n ceil(8 / n)): the whole block's opacity whenever n
    divides 8 (n = 1, 2, 4), nine slices' for n = 3; and ceil(8 / n) of the 8 slices' samples are composited."""
    vol = write_volume(tmp_path, np.full((8, 8, 8), 200, np.uint8))
    alpha = 0.1
    drawn = {}
    for stride in (1, 2, 3, 4):
        sc = stride_scene(make_scene, vol, "azimuth = 0\nelevation = 0\nzoom = 0.25", stride,
                          image="width = 64\nheight = 64\nbackground = [0, 0, 0, 0]",
                          transfer=f"opacity = [[199, 0], [200, {alpha}], [201, 0]]\nunit_distance = 1.0",
                          shading="enabled = false")
        img, st = Renderer(sc).render_view(0)
        sampled = -(-8 // stride)
        inside = img[..., 3][img[..., 3] > 0.5 * img[..., 3].max()]
        assert inside.size >= 64 and np.abs(inside - (1 - (1 - alpha) ** (stride * sampled))).max() < 1e-5
        drawn[stride] = st.drawn
        assert st.drawn * 8 == drawn[1] * sampled > 0


def test_stride_one_is_the_image_without_the_key_bit_for_bit(tmp_path, make_scene):
    """slice_stride = 1 (the default) draws what isplat drew before the key, bit for bit: the same tables
    (opacity corrected for one slice's path, alpha_table(luts, ds / unit)), the same image as no key at all,
    orthographic and perspective."""
    from isplat import frame as F
    from isplat.splat.post import lerp_tables
    from isplat.transfer import alpha_table

    vol = volume(tmp_path, 2, (6, 7, 5))
    for proj in ("orthographic", "perspective"):
        sc1 = stride_scene(make_scene, vol, CAMERAS[2], 1, proj)
        sc0 = make_scene(*vol, camera=f'projection = "{proj}"\n{CAMERAS[2]}', image="width = 24\nheight = 20",
                         transfer=TF, shading="enabled = true", render="early_termination = 1.0")
        assert sc0.render.slice_stride == 1
        r1 = Renderer(sc1)
        a, b = r1.render_view(0)[0], Renderer(sc0).render_view(0)[0]
        assert np.array_equal(a, b) and a[..., 3].max() > 0.2
        view = r1.views[0]
        setup = F.prepare(r1.selection, view)
        tables = F.frame_tables(r1.selection, view, np.float32, 1, setup.rows, 1)
        if proj == "orthographic":
            unit = float(view.geom.spacing.min())
            want = lerp_tables(alpha_table(r1.selection.luts, tables.proj.ds / unit), r1.selection.luts.color)[0]
            assert np.array_equal(setup.plan.cls.alpha, want)
        assert setup.plan.stride == 1


@pytest.mark.parametrize("cam", ["azimuth = 30\nelevation = 20", "azimuth = 200\nelevation = -30"])
def test_slabs_sample_the_same_slices_as_one_pass(tmp_path, make_scene, cam):
    """Slices chosen by their index, not by their place in a slab: a frame streamed slab by slab
    (isplat.slabs.render_streamed, as ``--slabs`` without a scheduler) is the one-pass image, bit for bit,
    with early termination on and off."""
    from isplat.slabs import render_streamed

    vol = volume(tmp_path, 4, (9, 8, 11))
    for et in (1.0, 0.9):
        sc = stride_scene(make_scene, vol, cam, 3, et=et)
        r = Renderer(sc)
        want, st = r.render_view(0)
        for k in (2, 3, 5):
            got, st_k, _ = render_streamed(r.request, r.views[0], k)
            assert np.array_equal(got, want), (et, k)
            assert st_k.drawn == st.drawn


@pytest.mark.parametrize("sets, needle", [
    (["render.slice_stride=0"], "render.slice_stride = 0: expected an integer 1..64"),
    (["render.slice_stride=65"], "render.slice_stride = 65: expected an integer 1..64"),
    (["render.slice_stride=1.5"], "render.slice_stride = 1.5: expected an integer 1..64"),
    (['render.slice_stride="2"'], 'render.slice_stride = "2": expected an integer 1..64'),
    (['render.classification="pre"', "render.slice_stride=2"],
     'render.slice_stride = 2: render.slice_stride > 1 samples the post-classified slices; it takes '
     'render.classification = "post"'),
    (['render.mode="mip"', "render.slice_stride=2"],
     'render.slice_stride = 2: render.slice_stride > 1 corrects the opacity of a composited ray; it takes '
     'render.mode = "composite" (the mode is "mip")'),
    (['version=5', "render.slice_stride=2"], "render.slice_stride"),
])
def test_bad_strides_are_refused_in_one_line(tmp_path, sets, needle):
    """The command line refuses a bad value, or a stride where it does not apply (pre-classified splatting,
    an intensity projection, a file of a version without the key), in one line naming where, the key, the value
    and what is expected, exit status 2, no traceback; the parser raises the same line."""
    from isplat.scene import parse_scene

    aug, idx = volume(tmp_path, 5, (4, 4, 4))
    (tmp_path / "s.toml").write_text(scene_text(aug.name, idx.name, transfer=TF))
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    res = subprocess.run([sys.executable, "-m", "isplat", "render", "s.toml", "-o", "x.png",
                          *[f"--set={s}" for s in sets]], cwd=tmp_path, capture_output=True, env=env, timeout=300)
    err = res.stderr.decode().strip().splitlines()
    assert res.returncode == 2 and len(err) == 1 and err[0].startswith("isplat: error: --set "), res.stderr
    assert needle in err[0]
    with pytest.raises(IsplatError, match="slice_stride"):
        parse_scene((tmp_path / "s.toml").read_text(), tmp_path, "s.toml", sets)
    assert not (tmp_path / "x.png").exists()


def test_a_stride_in_the_file_is_named_by_file_and_line(tmp_path):
    from isplat.scene import parse_scene

    text = scene_text("v.aug.h5", "v.idx.h5", transfer=TF, render="threads = 1\nslice_stride = -2")
    with pytest.raises(IsplatError) as info:
        parse_scene(text, tmp_path, "s.toml")
    line = 1 + text.splitlines().index("slice_stride = -2")
    assert str(info.value) == (f"s.toml:{line}: render.slice_stride = -2: expected an integer 1..64 (sample every "
                               "n-th slice of the principal axis, the opacity corrected for the longer step; 1 = "
                               "every slice)")


def test_a_shown_label_is_corrected_for_the_stride_too(tmp_path):
    """A segmentation label shown with opacity alpha over a uniform block of 8 slices seen head-on (labels are
    composited by the post-classified sampler, isplat.splat.labels): 1 - (1 - alpha)^(n ceil(8 / n)), as the
    density's opacity."""
    from isplat.augfile import write_augmented
    from isplat.scene import parse_scene

    lab = np.ones((8, 8, 8), np.uint8)
    d = np.zeros(lab.shape, np.uint8)
    write_augmented(tmp_path / "l.aug.h5", d, d, np.full(d.shape, 0x8080, np.uint16), (1.0, 1.0, 1.0),
                    (0.0, 255.0), 0.0, labels=lab)
    for stride in (1, 2, 3):
        text = ('version = 6\n[data]\naugmented = "l.aug.h5"\n[render]\nmethod = "full"\nearly_termination = 1.0\n'
                f'slice_stride = {stride}\n[image]\nwidth = 64\nheight = 64\nbackground = [0, 0, 0, 0]\n[camera]\n'
                'elevation = 90\nzoom = 0.25\n[transfer]\nopacity = [[0, 0], [255, 0]]\n[shading]\nenabled = false\n'
                '[labels.1]\ncolor = [1.0, 0.0, 0.0]\nopacity = 0.1\n')
        img, _ = Renderer(parse_scene(text, tmp_path, "l.toml")).render_view(0)
        inside = img[..., 3][img[..., 3] > 0.5 * img[..., 3].max()]
        assert inside.size >= 64
        assert np.abs(inside - (1 - 0.9 ** (stride * -(-8 // stride)))).max() < 1e-5, stride
