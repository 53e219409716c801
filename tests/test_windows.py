"""Augment windows for real data: named windows, percentiles, the Hounsfield default, clipped shares."""

from __future__ import annotations

import numpy as np
import pytest

from isplat import augment as A
from isplat.augfile import open_augmented
from isplat.errors import IsplatError

from test_cli_augment import _one_error, run


def _ct(metal=True):
    """A Hounsfield volume: air -1000 (padding -1024 in a corner), tissue 40, bone 1200, metal 3000."""
    x = np.full((16, 16, 16), -1000, np.int16)
    x[0, 0, :4] = -1024
    x[4:12, 4:12, 4:12] = 40
    x[6:10, 6:10, 6:10] = 1200
    if metal:
        x[7:9, 7:9, 7:9] = 3000
    return x


def test_named_and_percentile_windows():
    x = np.arange(64 ** 3, dtype=np.float64).reshape(64, 64, 64)
    assert A.resolve_window("ct-bone", x) == ((-700.0, 1300.0), "named ct-bone")
    (lo, hi), method = A.resolve_window("p0.5,p99.9", x)
    assert method == "percentiles p0.5/p99.9"
    assert (lo, hi) == pytest.approx(tuple(np.percentile(x, [0.5, 99.9])))
    (lo2, hi2), _ = A.resolve_window("-5,p50", x)
    assert lo2 == -5 and hi2 == pytest.approx(np.median(x))
    for bad in ("ct-bones", "1", "a,b", "p101,p2", "p50,p10"):
        with pytest.raises(IsplatError, match="--window"):
            A.resolve_window(bad, x)


def test_hounsfield_default_keeps_metal_above_bone():
    x = _ct()
    out = A.augment_array(x)
    assert out["density_window"] == (-1024.0, 3071.0)
    assert out["density_window_method"] == "Hounsfield data (values start at -1024): ct-full"
    d = out["density"]
    bone, metal, tissue = d[6, 6, 6], d[8, 8, 8], d[5, 5, 5]
    assert tissue < bone < metal < 255 and metal - bone > 100
    assert out["clipped"] == (0.0, 0.0)
    # without the -1024 padding, air near -1000 still says Hounsfield
    y = _ct()
    y[0, 0, :4] = -1000
    assert A.augment_array(y)["density_window_method"].startswith("Hounsfield data (values start at -1000)")
    # a positive-valued scan keeps the robust default
    assert A.augment_array(x + 1024)["density_window_method"] == "robust 0.1/99.9 percentiles"


def test_file_rescale_marks_hounsfield():
    x = _ct() + 500  # values no longer start near -1000, but the file says they are HU
    (lo, hi), method = A.resolve_window(None, x, {"hounsfield": True, "format": "dicom"})
    assert (lo, hi) == (-1024.0, 3071.0) and method == "Hounsfield data (dicom rescale): ct-full"


def test_clipped_shares_counted_once_per_voxel():
    x = _ct()
    out = A.augment_array(x, window="ct-bone")
    n = x.size
    assert out["clipped"] == (np.count_nonzero(x < -700) / n, np.count_nonzero(x > 1300) / n)


def test_cli_prints_window_and_clipping(capsys, tmp_path):
    p = tmp_path / "ct.npy"
    np.save(p, _ct())
    out = tmp_path / "ct.aug.h5"
    code, _, err = run(capsys, "augment", str(p), "-o", str(out))
    assert code == 0
    n = 16 ** 3
    above = np.count_nonzero(_ct() > 3071) / n
    assert ("isplat augment: window -1024,3071 (Hounsfield data (values start at -1024): ct-full); clipped "
            f"0.00% of voxels below -1024, {100 * above:.2f}% above 3071") in err
    a = open_augmented(out)
    assert a.attrs["density_units"] == "HU" and a.attrs["density_window_method"].endswith("ct-full")
    code, _, err = run(capsys, "augment", str(p), "-o", str(out), "--force", "--window", "ct-soft-tissue")
    assert code == 0 and "window -160,240 (named ct-soft-tissue)" in err
    assert open_augmented(out).density_window == (-160.0, 240.0)
    code, _, err = run(capsys, "augment", str(p), "-o", str(out), "--force", "--window", "ct-skull")
    _one_error(code, err, "--window 'ct-skull' invalid", "ct-full, ct-bone")


def test_augment_index_flag_writes_both(capsys, tmp_path):
    from isplat.index import open_index

    p = tmp_path / "ct.npy"
    np.save(p, _ct())
    code, _, err = run(capsys, "augment", str(p), "-o", str(tmp_path / "ct.aug.h5"), "--index")
    assert code == 0 and open_index(tmp_path / "ct.idx.h5").axes == "ijk"
    code, _, err = run(capsys, "augment", str(p), "-o", str(tmp_path / "ct.aug.h5"), "--index")
    _one_error(code, err, "ct.idx.h5: output exists; use --force")  # checked before any work
