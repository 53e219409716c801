"""Transfer functions in data units and presets: conversion through the recorded window, presets selecting
their material on synthetic scans with the right value ranges, `isplat presets`."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from isplat import units
from isplat.augment import augment_array
from isplat.augfile import write_augmented
from isplat.errors import IsplatError
from isplat.presets import PRESETS
from isplat.samples import HU, T1, make_sample
from isplat.scene import parse_scene
from isplat.transfer import build_luts

from test_cli_augment import run

finite = st.floats(-1e5, 1e5, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(lo=finite, width=st.floats(1e-3, 1e5), t=st.floats(0, 1))
def test_code_data_round_trip(lo, width, t):
    window = (lo, lo + width)
    x = lo + t * width
    code = units.to_code(x, window)
    assert -1e-6 <= code <= 255 + 1e-6
    assert units.to_data(code, window) == pytest.approx(x, rel=1e-9, abs=1e-9 * width)


@settings(max_examples=100, deadline=None)
@given(xs=st.lists(st.floats(-400, 400), min_size=2, max_size=6, unique=True), c=st.floats(0, 1))
def test_clip_points_keeps_the_map_inside_the_window(xs, c):
    pts = [(x, (x * 7919) % 1.0) for x in sorted(xs)]
    clipped = units.clip_points(pts, zero_outside=True)
    inside = np.linspace(0, 255, 52)
    ref = np.interp(inside, [p[0] for p in pts], [p[1] for p in pts])
    ref[(inside < pts[0][0]) | (inside > pts[-1][0])] = 0
    if not clipped:
        assert pts[-1][0] < 0 or pts[0][0] > 255
        return
    got = np.interp(inside, [p[0] for p in clipped], [p[1] for p in clipped])
    got[(inside < clipped[0][0]) | (inside > clipped[-1][0])] = 0
    assert np.allclose(got, ref, atol=1e-9) and all(0 <= p[0] <= 255 for p in clipped)


def _scene(tmp_path, transfer: str, window=None, aug="v.aug.h5"):
    text = f'[data]\naugmented = "{aug}"\n[render]\nmethod = "full"\n[transfer]\n{transfer}\n'
    return parse_scene(text, tmp_path, "s.toml", density_window=window)


def test_data_units_converted_through_the_recorded_window(tmp_path):
    d = np.zeros((2, 2, 2), np.uint8)
    write_augmented(tmp_path / "v.aug.h5", d, d, np.full(d.shape, 0x8080, np.uint16), (1, 1, 1), (-1024, 3071),
                    0.5)
    t = _scene(tmp_path, 'units = "data"\nopacity = [[300, 0], [1000, 1]]\ngradient_opacity = [[0, 0], [819, 1]]'
               ).transfer
    assert t.opacity == ((pytest.approx((300 + 1024) * 255 / 4095), 0), (pytest.approx(2024 * 255 / 4095), 1))
    assert t.gradient_opacity[1][0] == pytest.approx(819 * 255 / 4095)
    assert t.density_window == (-1024, 3071) and t.units == "data"
    with pytest.raises(IsplatError, match=r"density 3500 \(data units\) is outside the density window -1024\.\.3071 "
                                          r"of v\.aug\.h5; .*--window=-1024,3500"):
        _scene(tmp_path, 'units = "data"\nopacity = [[300, 0], [3500, 1]]')
    # codes stay codes, and need no file
    t = _scene(tmp_path, "opacity = [[10, 0], [20, 1]]", aug="missing.aug.h5").transfer
    assert t.opacity == ((10, 0), (20, 1)) and t.density_window is None


def test_window_provider_is_asked_once_and_only_for_data_units(tmp_path, monkeypatch):
    """The parser opens no file: the window comes from the caller, a provider asked lazily (once per scene)."""
    import isplat.augfile
    from isplat.scene import DensityWindow, WindowUnavailable

    def no_io(*args):
        raise AssertionError("the parser opened a file")

    monkeypatch.setattr(isplat.augfile, "open_augmented", no_io)
    calls = []

    def provider(data):
        calls.append(data.written)
        return DensityWindow((-1024.0, 3071.0), "ct.aug.h5", "ct.nii", "HU")

    data = ('units = "data"\nopacity = [[300, 0], [1000, 1]]\ncolor = [[300, 1, 1, 1]]\n'
            'gradient_opacity = [[0, 0], [9, 1]]')
    for transfer, n in (("opacity = [[10, 0], [20, 1]]", 0), ('preset = "micro-ct"', 0), (data, 1),
                        ('preset = "ct-bone"', 1)):
        calls.clear()
        t = _scene(tmp_path, transfer, window=provider).transfer
        assert calls == ["v.aug.h5"] * n and t.density_window == ((-1024.0, 3071.0) if n else None)
    with pytest.raises(IsplatError, match=r"s\.toml:6: transfer\.preset = \"mri-t1-head\": preset mri-t1-head is "
                                          r"placed from the data's density histogram, which ct\.aug\.h5 does not "
                                          r"give"):
        _scene(tmp_path, 'preset = "mri-t1-head"', window=provider)   # a window alone has no histogram
    with pytest.raises(IsplatError, match=r"of ct\.aug\.h5; re-augment .*isplat augment ct\.nii "):
        _scene(tmp_path, 'units = "data"\nopacity = [[300, 0], [5000, 1]]', window=provider)

    def unavailable(data):
        raise WindowUnavailable("no window here")

    with pytest.raises(IsplatError) as info:
        _scene(tmp_path, 'units = "data"\nopacity = [[300, 0], [1000, 1]]', window=unavailable)
    assert str(info.value) == 's.toml:6: transfer.units = "data": no window here'


def test_scene_reader_imports_no_hdf5():
    """Only isplat.scene.augmented_window opens the augmented file, and imports its reader when called."""
    import subprocess
    import sys

    code = "import sys, isplat.scene; print(sorted(m for m in ('h5py', 'isplat.augfile') if m in sys.modules))"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout == "[]\n"


def test_preset_overridable_key_by_key(tmp_path):
    base = _scene(tmp_path, 'preset = "ct-bone"', window=(-1024, 3071)).transfer
    over = _scene(tmp_path, 'preset = "ct-bone"\nopacity = [[500, 0], [600, 1]]', window=(-1024, 3071)).transfer
    assert over.color == base.color and over.opacity != base.opacity
    assert over.opacity[0][0] == pytest.approx(1524 * 255 / 4095)
    assert over.preset == "ct-bone" and over.units == "data"


# --- each preset selects its material -------------------------------------------------------------------------

SHAPE = (64, 64, 56)


def _material(x, value, tol):
    return np.abs(x.astype(np.float64) - value) <= tol


CASES = {  # preset: (sample, window, materials it must show, materials it must hide)
    "ct-bone": ("ct-head", None, ["bone"], ["soft", "brain", "air"]),
    "slicer-ct-bone": ("ct-head", None, ["bone", "brain"], ["air"]),   # Slicer's ramp starts at -16 HU
    "ct-skin": ("ct-head", None, ["soft"], ["bone", "air"]),
    "ct-soft-tissue": ("ct-chest", None, ["soft", "fat"], ["bone", "lung", "air"]),
    "ct-angio": ("ct-chest", None, ["contrast"], ["soft", "fat", "lung", "air"]),
    "ct-lung": ("ct-chest", None, ["lung"], ["soft", "bone", "contrast", "air"]),
    "slicer-ct-lung": ("ct-chest", None, [], ["lung", "soft", "bone", "air"]),
    "mri-t1-head": ("mr-head", None, ["scalp", "white", "grey"], ["background"]),
    "micro-ct": ("engine", "p0.5,p99.9", ["steel", "bolt"], ["air"]),
}
VALUES = {"ct-head": HU, "ct-chest": HU, "mr-head": T1, "engine": {"air": 0.0, "steel": 160.0, "bolt": 235.0}}
TOL = {"ct-head": 15, "ct-chest": 24, "mr-head": 15, "engine": 6}


def _with_histogram(aug):
    from isplat.scene import DensityWindow

    return DensityWindow(tuple(aug["density_window"]), "v.aug.h5",
                         histogram=lambda: np.bincount(aug["density"].ravel(), minlength=256))


def test_every_preset_has_a_case():
    assert set(CASES) == set(PRESETS)


@pytest.mark.parametrize("name", sorted(CASES))
def test_preset_selects_its_material(tmp_path, name):
    sample, window, show, hide = CASES[name]
    x, spacing = make_sample(sample, SHAPE)
    aug = augment_array(x, spacing, window=window)
    scene = _scene(tmp_path, f'preset = "{name}"', window=_with_histogram(aug))
    alpha = build_luts(scene.transfer, aug["gradient_magnitude_scale"]).opacity[aug["density"]]
    for m in show:
        sel = _material(x, VALUES[sample][m], TOL[sample])
        assert sel.sum() > 50, m
        assert np.median(alpha[sel]) > 0.02, (name, m, np.median(alpha[sel]))
    for m in hide:
        sel = _material(x, VALUES[sample][m], TOL[sample])
        assert sel.sum() > 50, m
        assert np.percentile(alpha[sel], 99) == 0.0, (name, m, np.percentile(alpha[sel], 99))


@pytest.mark.parametrize("name", sorted(CASES))
def test_every_preset_renders_on_its_sample(tmp_path, name):
    """Rendered through the whole pipeline on its sample, each preset draws a picture (which material it shows
    is checked voxel by voxel above; partial-volume edges make a picture-level check of that fuzzy)."""
    from isplat.renderer import Renderer

    sample, window, _, _ = CASES[name]
    x, spacing = make_sample(sample, (40, 40, 36))
    aug = augment_array(x, spacing, window=window)
    write_augmented(tmp_path / "v.aug.h5", aug["density"], aug["gradient_magnitude"], aug["normal"], spacing,
                    aug["density_window"], aug["gradient_magnitude_scale"], {"density_units": "HU"})
    scene = _scene(tmp_path, f'preset = "{name}"\n[image]\nwidth = 32\nheight = 32\nbackground = [0, 0, 0, 0]\n')
    rgba, _ = Renderer(scene).render_view(0)
    assert np.count_nonzero(rgba[..., 3] > 0.3) > 20


def test_bone_and_skin_render_differently_on_the_head(tmp_path):
    """Rendered: the skin preset covers the head's whole silhouette, the bone preset the smaller skull inside."""
    from isplat.renderer import Renderer

    x, spacing = make_sample("ct-head", (48, 48, 42))
    aug = augment_array(x, spacing)
    write_augmented(tmp_path / "v.aug.h5", aug["density"], aug["gradient_magnitude"], aug["normal"], spacing,
                    aug["density_window"], aug["gradient_magnitude_scale"])
    cover = {}
    for name in ("ct-bone", "ct-skin"):
        scene = _scene(tmp_path, f'preset = "{name}"\n[image]\nwidth = 48\nheight = 48\nbackground = [0, 0, 0, 0]\n')
        rgba, _ = Renderer(scene).render_view(0)
        cover[name] = np.count_nonzero(rgba[..., 3] > 0.5)
    assert cover["ct-bone"] > 100 and cover["ct-skin"] > 1.1 * cover["ct-bone"]


def test_presets_command(capsys):
    code, out, _ = run(capsys, "presets")
    lines = out.splitlines()
    assert code == 0 and [ln.split("\t")[0] for ln in lines] == list(PRESETS)
    assert all("source: " in ln for ln in lines)
    code, out, _ = run(capsys, "presets", "ct-angio")
    assert code == 0 and 'units = "data"' in out and "opacity = [[143.556, 0]" in out
    code, _, err = run(capsys, "presets", "nope")
    assert code == 2 and "preset 'nope' unknown" in err


def test_hounsfield_preset_on_non_hounsfield_file_warns(tmp_path, capsys):
    d = np.zeros((2, 2, 2), np.uint8)
    write_augmented(tmp_path / "v.aug.h5", d, d, np.full(d.shape, 0x8080, np.uint16), (1, 1, 1), (0, 4095), 0.5,
                    {"density_units": "HU"})
    _scene(tmp_path, 'preset = "ct-bone"')
    assert capsys.readouterr().err == ""
    write_augmented(tmp_path / "w.aug.h5", d, d, np.full(d.shape, 0x8080, np.uint16), (1, 1, 1), (0, 4095), 0.5)
    _scene(tmp_path, 'preset = "ct-bone"', aug="w.aug.h5")
    err = capsys.readouterr().err
    assert err == ("isplat: warning: s.toml:6: preset ct-bone is in Hounsfield units, but w.aug.h5 does not record "
                   "Hounsfield data (its window 0..4095 is taken as HU)\n")


@pytest.mark.parametrize("background", [0.0, 450.0])
def test_mri_preset_is_placed_above_the_background(tmp_path, background):
    """mri-t1-head on the T1 sample with its background raised (every voxel + B, the air's noise B/8, as the
    MNI152 template's 350-550): the opacity is zero on the background's voxels (not an opaque cube) and on the dark
    bone, and starts above them, below grey matter; through the whole pipeline from a file on disk. Before, the
    preset's fixed points (2% of the window) made the raised background opaque."""
    from isplat.presets import tissue_range
    from isplat.renderer import Renderer

    x, spacing = make_sample("mr-head", SHAPE, background=background)
    aug = augment_array(x, spacing)
    write_augmented(tmp_path / "v.aug.h5", aug["density"], aug["gradient_magnitude"], aug["normal"], spacing,
                    aug["density_window"], aug["gradient_magnitude_scale"])
    scene = _scene(tmp_path, 'preset = "mri-t1-head"')
    alpha = build_luts(scene.transfer, aug["gradient_magnitude_scale"]).opacity[aug["density"]]
    air = _material(x, T1["background"] + background, 15) if not background else \
        make_sample("mr-head", SHAPE)[0] == 0      # the air of the same head
    assert np.percentile(alpha[air], 99) == 0.0
    start = scene.transfer.opacity[0][0]
    assert np.percentile(aug["density"][air], 99) < start
    grey = _material(x, T1["grey"] + background, 15)
    assert start < np.median(aug["density"][grey]) and np.median(alpha[grey]) > 0.02
    counts = np.bincount(aug["density"].ravel(), minlength=256)
    assert start == tissue_range(counts)[0]
    # rendered: the background is not an opaque cube (the corners of the picture, outside the head, stay clear)
    scene = _scene(tmp_path, 'preset = "mri-t1-head"\n[image]\nwidth = 32\nheight = 32\n'
                   'background = [0, 0, 0, 0]\n')
    rgba, _ = Renderer(scene).render_view(0)
    assert rgba[0, 0, 3] == 0.0 and rgba[-1, -1, 3] == 0.0 and np.count_nonzero(rgba[..., 3] > 0.3) > 20


def test_ct_preset_keeps_its_hounsfield_points(tmp_path):
    """A pure CT file keeps its Hounsfield preset: ct-bone's codes are its HU points through the window, whatever
    the histogram (the data-placed branch is for the MRI preset only)."""
    x, spacing = make_sample("ct-head", SHAPE)
    aug = augment_array(x, spacing)
    write_augmented(tmp_path / "v.aug.h5", aug["density"], aug["gradient_magnitude"], aug["normal"], spacing,
                    aug["density_window"], aug["gradient_magnitude_scale"], {"density_units": "HU"})
    t = _scene(tmp_path, 'preset = "ct-bone"').transfer
    lo, hi = aug["density_window"]
    assert t.opacity[0][0] == pytest.approx(units.to_code(200.0, (lo, hi)))
    assert [p[1] for p in t.opacity] == [p[1] for p in PRESETS["ct-bone"].opacity]


def test_otsu_threshold_splits_two_modes():
    """Otsu's threshold on two separated modes lies between them; on one code it is 0."""
    from isplat.presets import otsu_threshold, tissue_range

    h = np.zeros(256, np.int64)
    h[30:40] = 1000
    h[150:200] = 100
    assert 39 <= otsu_threshold(h) < 150
    start, top = tissue_range(h)
    assert 39 < start < 150 and top == 199          # 99th percentile of 150..199, inverted cdf
    one = np.zeros(256, np.int64)
    one[7] = 5
    assert otsu_threshold(one) == 0 and tissue_range(np.zeros(256, np.int64)) == (0.5, 1.5)


def test_presets_command_places_an_mri_preset_on_a_file(tmp_path, capsys):
    x, spacing = make_sample("mr-head", (32, 32, 28), background=450.0)
    aug = augment_array(x, spacing)
    write_augmented(tmp_path / "m.aug.h5", aug["density"], aug["gradient_magnitude"], aug["normal"], spacing,
                    aug["density_window"], aug["gradient_magnitude_scale"])
    code, out, _ = run(capsys, "presets", "mri-t1-head")
    assert code == 0 and 'preset = "mri-t1-head"' in out and "tissue range" in out
    code, out, _ = run(capsys, "presets", "mri-t1-head", str(tmp_path / "m.aug.h5"))
    assert code == 0 and 'units = "code"' in out and "opacity = [[" in out
