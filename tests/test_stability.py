"""Fast checks of numerical stability on stiff and extreme cases (docs/stability.md has the full table, made
by ``python -m benchmarks stability``; these tests keep their own small copies of its helpers)."""

import math

import numpy as np
import pytest

from conftest import scene_text, write_volume
from isplat.augment import augment_array
from isplat.renderer import Renderer
from isplat.scene import parse_scene

# reference kernel knobs, so that the kernel's own error (about 2e-4) stays below what is looked for
FINE = 'footprint_radius = 4\nfootprint_table = 1048576\nearly_termination = 1.0\n'


class Lab:
    """Small volumes (spacing 1, window 0..255) in a temporary folder, and view 0 of scenes of them."""

    def __init__(self, tmp):
        self.tmp, self.n = tmp, 0

    def volume(self, density):
        self.n += 1
        return write_volume(self.tmp, density, name=f"v{self.n}")

    def augmented(self, array):
        """Through the real augment step (gradients; normals NO_NORMAL where the gradient is 0)."""
        self.n += 1
        o = augment_array(np.asarray(array, np.float32), (1.0, 1.0, 1.0), (0.0, 255.0))
        return write_volume(self.tmp, o["density"], name=f"v{self.n}", gm=o["gradient_magnitude"],
                            normal=o["normal"], gscale=o["gradient_magnitude_scale"])

    def render(self, vol, *, size=16, camera, transfer, shading="enabled = false", render=FINE,
               precision="float32"):
        """View 0 as float RGBA, and whether every pixel is finite."""
        text = scene_text(*vol, image=f"width = {size}\nheight = {size}\nbackground = [0, 0, 0, 0]",
                          camera=camera, transfer=transfer, shading=shading,
                          render=f'{render}precision = "{precision}"\n')
        img, _ = Renderer(parse_scene(text, self.tmp, "stability.toml", ())).render_view(0)
        return img, bool(np.all(np.isfinite(img)))


def centre(img, ch=3, half=2):
    """Mean of channel ``ch`` over the central 2*half x 2*half pixels (odd sizes: the central pixel)."""
    h, w = img.shape[:2]
    if h % 2:
        return float(img[h // 2, w // 2, ch])
    return float(img[h // 2 - half:h // 2 + half, w // 2 - half:w // 2 + half, ch].mean())


def ortho_down_k(n_ab, n_k, size=16):
    """Orthographic camera looking down the k axis of a unit-spacing volume, one pixel per voxel."""
    radius = 0.5 * math.sqrt(2 * n_ab ** 2 + n_k ** 2)
    return f'projection = "orthographic"\nazimuth = 0\nelevation = 90\nzoom = {2 * radius / size!r}'


def column(a, path_units):
    """Opacity of a path of ``path_units`` unit distances through opacity ``a`` per unit: 1 - (1 - a)^path."""
    return -math.expm1(path_units * math.log1p(-min(a, 1 - 2.0 ** -40)))


def opacity_tf(a, unit, density=200, color=(1.0, 1.0, 1.0)):
    """Opacity ``a`` per ``unit`` distance at ``density`` alone, in one colour."""
    c = ", ".join(repr(float(x)) for x in color)
    return (f"opacity = [[{density - 1}, 0.0], [{density}, {a!r}], [{density + 1}, 0.0]]\n"
            f"color = [[0, {c}]]\nunit_distance = {unit!r}")


@pytest.fixture
def lab(tmp_path):
    return Lab(tmp_path)


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("a, unit, n", [(1e-7, 1.0, 1024), (1e-9, 1e-6, 32), (0.5, 1e6, 32), (1 - 1e-12, 1.0, 4),
                                        (1.0, 1.0, 4)])
def test_slab_opacity_matches_the_stable_formula(lab, precision, a, unit, n):
    vol = lab.volume(np.full((n, 16, 16), 200, np.uint8))
    cam = ortho_down_k(16, n)
    img, ok = lab.render(vol, camera=cam, transfer=opacity_tf(a, unit), precision=precision)
    assert ok
    expect = column(a, n / unit)
    assert abs(centre(img) - expect) <= 1e-4 * expect + 1e-12


@pytest.mark.parametrize("pos", [(0.0, 0.0, 0.0), (0.5, 0.5, 0.0), (0.0, 0.0, -0.5), (0.0, 0.0, -1e-9)])
def test_eye_on_a_voxel_or_slice_plane_is_finite(lab, pos):
    vol = lab.volume(np.full((9, 9, 9), 200, np.uint8))
    near = "\nnear = 1e-12" if pos[2] == -1e-9 else ""
    cam = (f'projection = "perspective"\nposition = [{pos[0]}, {pos[1]}, {pos[2]!r}]\n'
           f'look_at = [{pos[0]}, {pos[1]}, 10.0]\nup = [0, 1, 0]\nfov = 170{near}')
    img, ok = lab.render(vol, size=17, camera=cam, transfer=opacity_tf(0.3, 1.0))
    assert ok and 0.0 < img[8, 8, 3] <= 1.0


def test_early_termination_just_below_one_matches_off(lab):
    vol = lab.volume(np.full((32, 16, 16), 200, np.uint8))
    cam = ortho_down_k(16, 32)
    imgs = [lab.render(vol, camera=cam, transfer=opacity_tf(0.5, 1.0),
                       render=FINE.replace("early_termination = 1.0", f"early_termination = {et}"))[0]
            for et in (1.0, 0.999999)]
    assert np.abs(imgs[0] - imgs[1]).max() <= 2e-6


def test_constant_volume_with_shading_is_lit_by_ambient_only(lab):
    vol = lab.augmented(np.full((8, 8, 8), 200.0, np.float32))
    cam = ortho_down_k(8, 8, size=8)
    img, ok = lab.render(vol, size=8, camera=cam, transfer=opacity_tf(0.05, 1.0, color=(0.8, 0.8, 0.8)),
                            shading="enabled = true\nambient = 0.25")
    assert ok and abs(img[4, 4, 0] - 0.2) < 1e-5


def test_threads_do_not_change_the_image_with_early_termination(lab):
    rng = np.random.default_rng(3)
    dens = rng.choice(np.array([0, 200], np.uint8), size=(24, 48, 48), p=[0.3, 0.7])
    vol = lab.volume(dens)
    cam = 'projection = "orthographic"\nazimuth = 20\nelevation = 10'
    imgs = [lab.render(vol, size=64, camera=cam, transfer=opacity_tf(0.6, 1.0),
                       render=f"early_termination = 0.9\nthreads = {t}\n")[0] for t in (1, 2)]
    assert np.array_equal(imgs[0], imgs[1])


@pytest.mark.parametrize("pos, fov, near", [((0.0, 0.0, -0.5), 60, 0.0), ((0.0, 0.0, 0.0), 60, 0.0),
                                            ((0.5, 0.5, 0.0), 60, 0.0), ((0.0, 0.0, -1e-9), 60, 1e-12),
                                            ((0.0, 0.0, -0.5), 170, 0.0)])
def test_eye_inside_matches_the_analytic_integral_from_the_eye(lab, pos, fov, near):
    """Rows 29-33 of docs/stability.md: an eye inside a uniform 33^3 slab (between slices, on a voxel, on a slice
    plane, 1e-9 from a voxel with a 1e-12 near plane, fov 170) looking along +z: the centre pixel is the
    emission-absorption integral from the eye to the far face of the voxel boxes, 1 - (1 - a)^(16.5 - z_eye),
    within the issue's 5% (the model gives about 1e-4: the first slab kept reaches back to the eye and
    footprints next to the eye take each pixel's own ray)."""
    n, a = 33, 0.02
    vol = lab.volume(np.full((n, n, n), 200, np.uint8))
    extra = f"\nnear = {near!r}" if near else ""
    cam = (f'projection = "perspective"\nposition = [{pos[0]!r}, {pos[1]!r}, {pos[2]!r}]\n'
           f'look_at = [{pos[0]!r}, {pos[1]!r}, 10.0]\nup = [0, 1, 0]\nfov = {fov}{extra}')
    img, ok = lab.render(vol, size=33, camera=cam, transfer=opacity_tf(a, 1.0))
    expect = column(a, n / 2 - pos[2])
    rel = abs(centre(img) - expect) / expect
    assert ok and rel <= 0.05, f"centre pixel {rel:.1%} off the analytic integral (the issue's target: 5%)"
    assert rel <= 2e-3
    if fov == 60 and pos[:2] == (0.0, 0.0):
        # every pixel's ray leaves through the far face (z = 16.5): its path from the eye is (8.5 - z) / cos
        ys, xs = np.mgrid[0:33, 0:33] - 16.0
        half = math.tan(math.radians(fov / 2)) / 16.5               # tan of the angle per pixel
        cos = 1 / np.sqrt(1 + (xs * half) ** 2 + (ys * half) ** 2)
        every = -np.expm1((n / 2 - pos[2]) / cos * math.log1p(-a))
        assert np.abs(img[..., 3] / every - 1).max() <= 2e-3


@pytest.mark.parametrize("near", [2.0, 3.7])
def test_a_set_near_plane_clips_the_integral_there(lab, near):
    """camera.near set: voxels nearer are culled and the integral starts at the near plane (the slab it cuts
    counts from there on), so the centre pixel is the integral from depth ``near`` to the far face."""
    n, a = 33, 0.02
    vol = lab.volume(np.full((n, n, n), 200, np.uint8))
    cam = ('projection = "perspective"\nposition = [0.0, 0.0, -0.5]\nlook_at = [0.0, 0.0, 10.0]\nup = [0, 1, 0]\n'
           f'fov = 60\nnear = {near!r}')
    img, ok = lab.render(vol, size=33, camera=cam, transfer=opacity_tf(a, 1.0))
    expect = column(a, n / 2 + 0.5 - near)
    assert ok and abs(centre(img) - expect) <= 2e-3 * expect


def test_eye_just_outside_the_face_counts_from_the_face(lab):
    """The eye 0.3 in front of the volume's face (the first slice, 0.8 away, is culled by the default near
    plane): the first slab kept reaches back to the face, not to the eye, so the centre pixel is the whole
    depth of the volume, 33 units."""
    n, a = 33, 0.02
    vol = lab.volume(np.full((n, n, n), 200, np.uint8))
    cam = 'projection = "perspective"\nposition = [0.0, 0.0, -16.8]\nlook_at = [0.0, 0.0, 10.0]\nup = [0, 1, 0]\nfov = 60'
    img, ok = lab.render(vol, size=33, camera=cam, transfer=opacity_tf(a, 1.0))
    assert ok and abs(centre(img) / column(a, n) - 1) <= 2e-3
