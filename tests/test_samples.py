"""Synthetic samples: deterministic, the documented types and sizes, and the tissue fractions the paper's data had."""

import numpy as np
import pytest

from isplat.errors import IsplatError
from isplat.samples import DEFAULT_SHAPES, make_sample


@pytest.mark.parametrize("name", ["marschner-lobb", "sphere", "two-density-cube"])
def test_small_samples_defaults(name):
    x, s = make_sample(name)
    ni, nj, nk = DEFAULT_SHAPES[name]
    assert x.shape == (nk, nj, ni) and len(s) == 3


def test_head_is_deterministic_and_ct_like():
    a, s = make_sample("head", (64, 64, 56), seed=3)
    b, _ = make_sample("head", (64, 64, 56), seed=3)
    c, _ = make_sample("head", (64, 64, 56), seed=4)
    assert a.dtype == np.uint16 and a.shape == (56, 64, 64) and s == (1.0, 1.0, 1.0)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert a.min() == 0 and a[0, 0, 0] < 20            # air is the lowest value
    bone = (a > 1650).mean()
    assert 0.05 <= bone <= 0.10                        # like the paper's H1


def test_engine_has_a_small_distinct_component():
    x, _ = make_sample("engine", (128, 128, 55))
    assert x.dtype == np.uint8
    bolts = (x > 210).mean()
    assert 0.005 < bolts < 0.015                       # E2: a TF can select ~1 % of the voxels
    assert 0.15 < ((x > 45) & (x <= 210)).mean() < 0.35


def test_marschner_lobb_formula():
    x, s = make_sample("marschner-lobb", (5, 7, 9))
    assert x.dtype == np.float32 and x.shape == (9, 7, 5) and s == pytest.approx((0.5, 2 / 6, 0.25))
    # at (x, y, z) = (0, 0, -1): r = 0, rho_r = cos(12 pi) = 1, value (1 + 1 + 0.25 * 2) / 2.5 = 1
    assert x[0, 3, 2] == pytest.approx(1.0)
    assert 0 <= x.min() and x.max() <= 1


def test_sphere_and_cube_dtypes():
    assert make_sample("sphere", dtype="uint8")[0].dtype == np.uint8
    c, _ = make_sample("two-density-cube", (8, 8, 8))
    assert sorted(np.unique(c)) == [0, 100, 200] and (c == 100).sum() == (c == 200).sum() == 32


def test_bad_names_and_shapes():
    with pytest.raises(IsplatError, match="unknown"):
        make_sample("teapot")
    with pytest.raises(IsplatError, match="shape"):
        make_sample("sphere", (1, 4, 4))
    with pytest.raises(IsplatError, match="dtype"):
        make_sample("head", (8, 8, 8), dtype="uint8")


def test_mr_head_background_raises_every_voxel_and_widens_the_airs_noise():
    """``isplat sample mr-head --background B``: an MRI whose background is not zero (docs/presets.md)."""
    from isplat.errors import IsplatError
    from isplat.samples import T1

    plain, _ = make_sample("mr-head", (32, 32, 28))
    raised, _ = make_sample("mr-head", (32, 32, 28), background=450.0)
    air = plain <= 20
    grey = np.abs(plain.astype(float) - T1["grey"]) <= 15
    assert 400 < np.median(raised[air]) < 500 and 30 < raised[air].std() < 90
    assert np.median(raised[grey]) == pytest.approx(np.median(plain[grey]) + 450, abs=3)
    with pytest.raises(IsplatError, match="--background applies to mr-head only"):
        make_sample("ct-head", (8, 8, 8), background=450.0)
    with pytest.raises(IsplatError, match=r"background -3 invalid; expected a value in \(0, 20000\]"):
        make_sample("mr-head", (8, 8, 8), background=-3.0)
