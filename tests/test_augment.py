"""Density mapping, gradients against analytic fields, flat regions, slab independence, the examples."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from isplat import augment as A
from isplat import normals as N
from isplat.augfile import density_sha256, open_augmented
from isplat.errors import IsplatError

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "formats" / "examples" / "augmented"


def _angle_deg(a, b):
    c = (a * b).sum(-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(c, -1, 1)))


def test_density_window_given():
    x = np.linspace(-1000, 3000, 2 * 3 * 50, dtype=np.float32).reshape(2, 3, 50)
    out = A.augment_array(x, window=(-1000, 1000))
    want = np.clip(np.rint((x.astype(np.float64) + 1000) * (255 / 2000)), 0, 255).astype(np.uint8)
    assert np.array_equal(out["density"], want)
    assert out["density_window"] == (-1000.0, 1000.0)
    # back to input units within half a step
    back = -1000 + out["density"].astype(np.float64) * 2000 / 255
    inside = x <= 1000
    assert np.all(np.abs(back[inside] - x[inside]) <= 2000 / 255 / 2 + 1e-3)


def test_robust_window_is_percentiles_of_the_strided_subsample():
    rng = np.random.default_rng(0)
    x = rng.normal(100, 10, (70, 65, 130)).astype(np.float32)
    x[0, 0, 0] = 1e6  # an outlier outside the subsample does not move the window
    lo, hi = A.robust_window(x)
    sub = x[::2, ::2, ::3].astype(np.float64)
    assert (lo, hi) == tuple(np.percentile(sub, [0.1, 99.9]))
    assert A.augment_array(x)["density_window"] == (lo, hi)


def test_robust_window_falls_back_to_min_max():
    x = np.zeros((20, 20, 20), np.uint8)
    x[3, 3, 3] = 9  # both percentiles are 0: the subsample's (here every voxel's) min and max
    assert A.robust_window(x) == (0.0, 9.0)
    y = np.zeros((130, 130, 130), np.uint8)
    y[1, 1, 1] = 7  # outside the ::3 subsample: whole-volume min/max
    assert A.robust_window(y) == (0.0, 7.0)


def test_constant_volume_refused_unless_window_given():
    x = np.full((4, 5, 6), 42, np.int16)
    with pytest.raises(IsplatError, match="constant volume.*--window"):
        A.augment_array(x)
    out = A.augment_array(x, window=(0, 84))
    assert np.all(out["density"] == 128)
    assert np.all(out["normal"] == N.NO_NORMAL) and np.all(out["gradient_magnitude"] == 0)
    assert out["gradient_magnitude_scale"] == 0.0


def test_linear_ramp_anisotropic_spacing_exact_gradient():
    nk, nj, ni = 6, 7, 8
    s = (0.5, 2.0, 1.25)
    k, j, i = np.meshgrid(np.arange(nk), np.arange(nj), np.arange(ni), indexing="ij")
    x = (3.0 * i + 5.0 * j + 7.0 * k).astype(np.float32)
    lo, hi = 0.0, float(3 * 7 + 5 * 6 + 7 * 5)
    out = A.augment_array(x, s, window=(lo, hi))
    c = 255 / (hi - lo)
    g = np.array([3.0 * c / s[0], 5.0 * c / s[1], 7.0 * c / s[2]])  # exact, borders included (one-sided)
    assert out["gradient_magnitude_scale"] == pytest.approx(np.linalg.norm(g) / 255, rel=1e-5)
    assert np.all(out["gradient_magnitude"] >= 254)
    err = _angle_deg(N.decode(out["normal"]).astype(np.float64), g)
    assert err.max() < 0.65


def test_radial_field_normals_point_outwards():
    n = 24
    s = np.array([1.0, 0.8, 1.5])  # i, j, k
    k, j, i = np.meshgrid(np.arange(n), np.arange(n), np.arange(n), indexing="ij")
    pos = np.stack([(i - 11.3) * s[0], (j - 12.1) * s[1], (k - 11.7) * s[2]], -1)
    # |r|^2: central differences are exact for a quadratic, so only the encoding error remains
    x = (pos ** 2).sum(-1)
    out = A.augment_array(x, tuple(s), window=(0, float(x.max())))
    r = np.linalg.norm(pos, axis=-1)
    interior = (r > 2) & (i > 0) & (j > 0) & (k > 0) & (i < n - 1) & (j < n - 1) & (k < n - 1)
    err = _angle_deg(N.decode(out["normal"][interior]).astype(np.float64), pos[interior])
    assert err.max() < 0.7


def test_sphere_normals_point_outwards():
    from isplat.samples import make_sample

    x, s = make_sample("sphere", (32, 32, 32))
    out = A.augment_array(x, s, window=(0, 1))
    k, j, i = np.indices(x.shape)
    pos = np.stack([i - 15.5, j - 15.5, k - 15.5], -1)
    shell = out["gradient_magnitude"] > 128
    # the gradient points inwards (towards increasing density) and is within a few degrees of radial
    err = _angle_deg(N.decode(out["normal"][shell]).astype(np.float64), -pos[shell])
    # (the sample's one-voxel anti-aliased edge is only approximately radial)
    assert shell.sum() > 500 and err.mean() < 4 and err.max() < 20


def test_flat_regions_no_normal_no_nan():
    x = np.zeros((8, 9, 10), np.float32)
    x[4:, :, :] = 1.0
    out = A.augment_array(x, window=(0, 1))
    nrm = out["normal"]
    assert np.all(nrm[:2] == N.NO_NORMAL) and np.all(nrm[6:] == N.NO_NORMAL)
    assert np.all(nrm[3:5] != N.NO_NORMAL)
    assert np.all(out["gradient_magnitude"][:2] == 0)
    assert not np.isnan(N.decode(nrm)).any()
    assert np.allclose(N.decode(nrm[3:5]), [0, 0, 1])


def test_gradient_kernel_matches_numpy_gradient():
    rng = np.random.default_rng(5)
    t = rng.uniform(0, 255, (9, 6, 7)).astype(np.float32)
    s = (0.7, 1.3, 2.1)
    want = np.gradient(t, s[2], s[1], s[0], edge_order=1)  # [d/dk, d/dj, d/di]
    for k0, k1 in [(0, 9), (0, 4), (4, 9), (3, 5), (8, 9)]:
        e0, e1 = max(0, k0 - 1), min(9, k1 + 1)
        g = np.empty((3, k1 - k0, 6, 7), np.float32)
        A._gradient_kernel(np.ascontiguousarray(t[e0:e1]), k0 - e0, k1 - k0, k0, 9, *s, g)
        for c, w in zip(range(3), [want[2], want[1], want[0]]):
            assert np.allclose(g[c], w[k0:k1], rtol=1e-6, atol=1e-5)


def test_window_and_encode_kernels_match_reference():
    from test_normals import ref_encode  # tests/ is on sys.path (rootdir-relative imports)

    rng = np.random.default_rng(6)
    x = rng.uniform(-50, 300, (3, 4, 5))
    t = np.empty(x.shape, np.float32)
    d = np.empty(x.shape, np.uint8)
    assert A._window_kernel(x, -10.0, 255 / 250, t, d) == -1
    ref = np.clip((x + 10) * (255 / 250), 0, 255)
    assert np.array_equal(d, np.rint(ref).astype(np.uint8)) and np.allclose(t, ref.astype(np.float32))
    g = rng.normal(0, 1, (3, 3, 4, 5)).astype(np.float32)
    g[:, 0, 0, 0] = 0
    gmax = float(np.sqrt((g.astype(np.float64) ** 2).sum(0)).max())
    assert A._magnitude_max(g) == gmax
    mag = np.empty(g.shape[1:], np.uint8)
    nrm = np.empty(g.shape[1:], np.uint16)
    A._encode_kernel(g, g, gmax, mag, nrm)
    for idx in np.ndindex(*g.shape[1:]):
        v = g[(slice(None),) + idx].astype(np.float64)
        assert nrm[idx] == ref_encode(v)
        assert mag[idx] == int(np.rint(min(np.linalg.norm(v) / gmax, 1) * 255))


def test_nonfinite_refused_with_position():
    x = np.ones((5, 6, 7), np.float32)
    x[3, 2, 1] = np.nan
    with pytest.raises(IsplatError, match=r"value nan at voxel \(i=1, j=2, k=3\)"):
        A.augment_array(x, window=(0, 2))
    x[3, 2, 1] = np.inf
    with pytest.raises(IsplatError, match="value inf"):
        A.augment_array(x, window=(0, 2))


def test_slab_size_does_not_change_the_result(monkeypatch, tmp_path):
    from isplat.samples import make_sample

    x, s = make_sample("head", (40, 36, 30))
    whole = A.augment_array(x, s)
    monkeypatch.setattr(A, "SLAB_VOXELS", 40 * 36 * 4)  # 4-slice slabs
    np.save(tmp_path / "h.npy", x)
    A.augment_file(tmp_path / "h.npy", tmp_path / "h.aug.h5", spacing=s)
    aug = open_augmented(tmp_path / "h.aug.h5")
    for ch in ("density", "gradient_magnitude", "normal"):
        assert np.array_equal(aug.read(ch), whole[ch]), ch
    assert aug.density_sha256 == density_sha256(whole["density"]) == whole["density_sha256"]
    assert aug.density_window == whole["density_window"]
    assert aug.gradient_magnitude_scale == pytest.approx(whole["gradient_magnitude_scale"], rel=1e-12)
    assert aug.attrs["source_format"] == "npy"


def test_head_sample_density_index_estimate():
    """The head's density index (paper §2.3) stays near 1 byte per voxel along k (see docs/augment.md)."""
    from isplat.samples import make_sample

    x, s = make_sample("head", (128, 128, 113))
    d = A.augment_array(x, s)["density"]
    assert d[0, 0, 0] == 0  # air maps to density 0
    assert index_bytes_per_voxel(d) <= 1.3


def index_bytes_per_voxel(d):
    """1 byte per voxel plus 2 per gap > 255 between same-density voxels of a k-slice (from position -1).

    A slow, plain copy of the estimate in benchmarks/augment.py (tests do not import the benchmarks)."""
    gaps = 0
    for plane in d.reshape(d.shape[0], -1):
        for v in np.unique(plane):
            gaps += int((np.diff(np.flatnonzero(plane == v), prepend=-1) > 255).sum())
    return (d.size + 2 * gaps) / d.size


def test_index_estimate_counts_long_gaps():
    d = np.zeros((2, 1, 600), np.uint8)
    d[0, 0, [0, 300, 599]] = 7            # 7: steps 1, 300, 299 from -1: two > 255; 0: steps of 1 or 2
    d[1, 0, 256] = 9                      # 9: a step of 257 from -1; 0: steps of 1 or 2
    assert index_bytes_per_voxel(d) == (1200 + 2 * 3) / 1200
    d[1, 0, 256] = 0
    assert index_bytes_per_voxel(d) == (1200 + 2 * 2) / 1200


# --- the format examples ---------------------------------------------------------------------------------------

def test_valid_example_decodes_to_expected_values():
    exp = json.loads((EXAMPLES / "valid.expected.json").read_text())
    aug = open_augmented(EXAMPLES / exp["file"])
    assert list(aug.shape) == exp["shape"]
    assert list(aug.spacing_ijk) == exp["spacing_ijk"]
    assert list(aug.density_window) == exp["density_window"]
    assert aug.gradient_magnitude_scale == exp["gradient_magnitude_scale"]
    assert aug.density_sha256 == exp["density_sha256"]
    for ch in ("density", "gradient_magnitude", "normal"):
        assert aug.read(ch).tolist() == exp[ch]
    assert np.allclose(N.decode(aug.read("normal")), exp["normal_decoded"], atol=1e-6)
    assert density_sha256(aug.read("density")) == exp["density_sha256"]
    assert aug.axes_lps.tolist() == exp["axes_lps"]
    assert exp["normal"][0][0][0] == N.NO_NORMAL
    assert aug.format_version == 6 and aug.read("labels").tolist() == exp["labels"]
    assert aug.bricked and aug.brick_range.tolist() == exp["brick_range"] and aug.edge == exp["brick_edge"]
    assert aug.label_voxels.tolist() == exp["label_voxels"]
    from isplat.index.labels import open_label_index, shown_ids_volume

    li = open_label_index(EXAMPLES / "valid.labels.idx.h5", aug)       # the index of its labels (index format 5)
    assert li.version == 5 and li.channel == "labels" and li.density_ranges == [(1, 2)]
    lab = np.asarray(exp["labels"])
    for axis in "ijk":
        for shown in ([1], [2], [1, 2]):
            ids, _ = shown_ids_volume(li, axis, shown, aug.shape)
            assert ids.tolist() == np.where(np.isin(lab, shown), lab, 0).reshape(-1).tolist()
    v5 = open_augmented(EXAMPLES / "valid-v5.aug.h5")              # version 5: 8^3 bricks as HDF5 chunks
    assert v5.format_version == 5 and v5.bricked and v5.read("labels").tolist() == exp["labels"]
    for ch in ("density", "gradient_magnitude", "normal"):
        assert v5.read(ch).tolist() == exp[ch]
    v4 = open_augmented(EXAMPLES / "valid-v4.aug.h5")              # version 4: read whole, with labels
    assert v4.format_version == 4 and not v4.bricked and v4.read("labels").tolist() == exp["labels"]
    for ch in ("density", "gradient_magnitude", "normal"):
        assert v4.read(ch).tolist() == exp[ch]
    old = open_augmented(EXAMPLES / "valid-v3.aug.h5")             # version 3: read, without labels
    assert old.format_version == 3 and not old.has_labels and old.read("density").tolist() == exp["density"]


@pytest.mark.parametrize("name,what", [("invalid-wrong-version.aug.h5", "format_version"),
                                       ("invalid-wrong-format.aug.h5", "'format'"),
                                       ("invalid-missing-normal.aug.h5", "'normal' is missing"),
                                       ("invalid-version-1.aug.h5", "lack this version's checksums, rebuild it: "
                                                                    "isplat augment"),
                                       ("invalid-version-2.aug.h5", "version 2 lack this version's checksums, "
                                                                    "rebuild it: isplat augment"),
                                       ("invalid-edited-value.aug.h5", "dataset 'density', brick 0 at \\(0, 0, 0\\): "
                                                                       ".* rebuild it: isplat augment"),
                                       ("invalid-flipped-bit.aug.h5", "dataset 'normal', brick 0 at \\(0, 0, 0\\)"),
                                       ("invalid-brick-hashes.aug.h5", "'brick_hashes/density' is uint64 \\(0,\\), "
                                                                       "expected uint64 \\(1,\\)"),
                                       ("invalid-axes-lps.aug.h5", "'axes_lps'.*orthonormal"),
                                       ("invalid-label-id.aug.h5", "'labels' holds id 7, expected ids below 3"),
                                       ("invalid-brick-range.aug.h5", "brick at \\(0, 0, 0\\): densities .*"
                                                                      "/brick_range says")])
def test_invalid_examples_refused(name, what):
    with pytest.raises(IsplatError, match=what):
        aug = open_augmented(EXAMPLES / name)
        for ch in ("density", "gradient_magnitude", "normal") + (("labels",) if aug.has_labels else ()):
            aug.read(ch)


def test_example_script_output_equals_committed_files(tmp_path):
    sys.path.insert(0, str(ROOT / "formats" / "examples"))
    try:
        import make_augmented_examples as mk
    finally:
        sys.path.pop(0)
    mk.build(tmp_path)
    assert json.loads((tmp_path / "valid.expected.json").read_text()) == \
        json.loads((EXAMPLES / "valid.expected.json").read_text())
    import h5py

    for f in EXAMPLES.glob("*.h5"):
        with h5py.File(f) as a, h5py.File(tmp_path / f.name) as b:
            assert sorted(a) == sorted(b)
            assert {k: str(v) for k, v in a.attrs.items()} == {k: str(v) for k, v in b.attrs.items()}
            names = []
            a.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) else None)
            assert "chunk_hashes" in a or f.name.startswith("invalid-version-")
            for ds in names:
                if f.name != "invalid-flipped-bit.aug.h5":     # its data does not read (checksum)
                    assert np.array_equal(a[ds][()], b[ds][()]), (f.name, ds)


# ---- normals of thick slices (isplat.augment.normal_sigmas; docs/thick-slices.md) -----------------------------------

def _smooth_sphere(shape, sp, width, noise=0.0, seed=0):
    """A ball of radius 0.35 of the smallest extent with a logistic edge ``width`` mm wide, on grid ``sp``."""
    ni, nj, nk = shape
    k, j, i = np.meshgrid(np.arange(nk), np.arange(nj), np.arange(ni), indexing="ij")
    pos = np.stack([(i - (ni - 1) / 2) * sp[0], (j - (nj - 1) / 2) * sp[1], (k - (nk - 1) / 2) * sp[2]], -1)
    r = np.linalg.norm(pos, axis=-1)
    R = 0.35 * min(n * s for n, s in zip(shape, sp))
    x = 1000.0 / (1.0 + np.exp((r - R) / width))
    if noise:
        x = x + np.random.default_rng(seed).normal(0, noise, x.shape)
    return x.astype(np.float32), pos, r, R, k


def test_normal_sigmas_only_on_thick_slices():
    assert A.normal_sigmas((1, 1, 1)) is None
    assert A.normal_sigmas((1, 1, 4)) is None          # not more than NORMAL_RATIO times thicker
    assert A.normal_sigmas((0.7, 0.7, 2.5)) is None    # 3.6:1 (docs/thick-slices.md: nothing to remove there)
    assert A.normal_sigmas((0.5, 0.5, 2.5)) == pytest.approx((0.5 * np.sqrt(2.5 ** 2 - 0.25),) * 2 + (0.0,))
    assert A.normal_sigmas((6.0, 1.0, 1.0)) == pytest.approx((0.0, 0.5 * np.sqrt(35), 0.5 * np.sqrt(35)))


def test_isotropic_and_mild_spacing_normals_unchanged():
    x, _, _, _, _ = _smooth_sphere((24, 20, 16), (1.0, 1.0, 3.5), 2.0, noise=5.0)
    a = A.augment_array(x, (1.0, 1.0, 3.5), (0, 1000))
    b = A.augment_array(x, (1.0, 1.0, 3.5), (0, 1000), smooth_normals=False)
    for ch in ("density", "gradient_magnitude", "normal"):
        assert np.array_equal(a[ch], b[ch]), ch


def test_thick_slices_linear_field_normals_exact_inside():
    # smoothing keeps a linear field linear (odd reflection past the borders): the normals stay exact
    nk, nj, ni = 8, 30, 30
    s = (1.0, 1.0, 7.0)
    k, j, i = np.meshgrid(np.arange(nk), np.arange(nj), np.arange(ni), indexing="ij")
    x = (3.0 * i * s[0] - 2.0 * j * s[1] + 5.0 * k * s[2]).astype(np.float32)
    out = A.augment_array(x, s, window=(float(x.min()), float(x.max())))
    err = _angle_deg(N.decode(out["normal"]).astype(np.float64), np.array([3.0, -2.0, 5.0]))
    assert err.max() < 0.65
    # the magnitude channel is that of the plain differences, borders included
    plain = A.augment_array(x, s, window=(float(x.min()), float(x.max())), smooth_normals=False)
    assert np.array_equal(out["gradient_magnitude"], plain["gradient_magnitude"])
    assert out["gradient_magnitude_scale"] == plain["gradient_magnitude_scale"]


@pytest.mark.parametrize("sp,shape,width,noise", [
    ((1.0, 1.0, 7.0), (96, 96, 16), 3.0, 0.0),
    ((1.0, 1.0, 7.0), (96, 96, 16), 3.0, 2.0),
    ((0.5, 0.5, 2.5), (160, 160, 32), 1.0, 0.0),
    ((0.5, 0.5, 2.5), (160, 160, 32), 2.0, 0.0),
    ((5.0, 1.0, 1.0), (16, 80, 80), 3.0, 0.0),      # the thick axis along i: smoothing along j and k
])
def test_thick_slices_normals_closer_to_analytic(sp, shape, width, noise):
    """On a smooth ball sampled with thick slices the normals are within a bound of the analytic ones, and
    closer than the plain central differences' (mean and largest angle over the voxels near the surface)."""
    x, pos, r, R, k = _smooth_sphere(shape, sp, width, noise)
    near = np.abs(r - R) < 1.5 * width
    errs = []
    for smooth in (True, False):
        out = A.augment_array(x, sp, (0, 1000), smooth_normals=smooth)
        errs.append(_angle_deg(N.decode(out["normal"][near]).astype(np.float64), -pos[near]))
    new, old = errs
    assert near.sum() > 1000
    assert new.mean() <= old.mean() and new.max() <= old.max() + 0.1
    assert new.mean() < 2.0 and new.max() < 7.5


def test_thick_slices_slab_size_does_not_change_the_normals(monkeypatch, tmp_path):
    # thick along i: the normals' smoothing runs along k too, across slabs (a wider halo)
    x, _, _, _, _ = _smooth_sphere((10, 40, 36), (6.0, 1.0, 1.0), 3.0, noise=3.0)
    whole = A.augment_array(x, (6.0, 1.0, 1.0), (0, 1000))
    monkeypatch.setattr(A, "SLAB_VOXELS", 40 * 10 * 3)  # 3-slice slabs, less than the smoothing's reach
    np.save(tmp_path / "t.npy", x)
    A.augment_file(tmp_path / "t.npy", tmp_path / "t.aug.h5", spacing=(6.0, 1.0, 1.0), window=(0, 1000))
    aug = open_augmented(tmp_path / "t.aug.h5")
    for ch in ("density", "gradient_magnitude", "normal"):
        assert np.array_equal(aug.read(ch), whole[ch]), ch
