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
    assert ("isplat augment: window -1024,3071 HU (Hounsfield data (values start at -1024): ct-full); clipped "
            f"0.00% of voxels below -1024, {100 * above:.2f}% above 3071\n") in err     # nothing above: no note
    a = open_augmented(out)
    assert a.attrs["density_units"] == "HU" and a.attrs["density_window_method"].endswith("ct-full")
    code, _, err = run(capsys, "augment", str(p), "-o", str(out), "--force", "--window", "ct-soft-tissue")
    assert code == 0 and "window -160,240 HU (named ct-soft-tissue; Hounsfield data: values start at -1024)" in err
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


# --- every default said once (issue 28 item 4) -------------------------------------------------------------------

def _lines(err, needle):
    return [ln for ln in err.splitlines() if needle in ln]


def test_spacing_said_once_with_its_source(capsys, tmp_path):
    p = tmp_path / "ct.npy"
    np.save(p, _ct())
    code, _, err = run(capsys, "augment", str(p), "-o", str(tmp_path / "a.aug.h5"))
    (line,) = _lines(err, "augment: spacing")
    assert code == 0 and line == ("isplat augment: spacing 1,1,1 (i, j, k): the default (.npy has no spacing); give "
                                  "the scan's with --spacing SX,SY,SZ in i, j, k order (i the fastest axis: the last "
                                  "of a .npy's [k, j, i] shape)")
    code, _, err = run(capsys, "augment", str(p), "-o", str(tmp_path / "b.aug.h5"), "--spacing", "0.5,0.6,2.5")
    assert code == 0
    assert _lines(err, "augment: spacing")[0] == "isplat augment: spacing 0.5,0.6,2.5 (i, j, k): from --spacing"
    nrrd = pytest.importorskip("nrrd")
    nrrd.write(str(tmp_path / "c.nrrd"), _ct(), {"space directions": np.diag([0.7, 0.8, 0.9]),
                                                  "space": "left-posterior-superior"}, index_order="C")
    code, _, err = run(capsys, "augment", str(tmp_path / "c.nrrd"), "-o", str(tmp_path / "c.aug.h5"))
    assert code == 0 and "spacing 0.7,0.8,0.9 (i, j, k): from NRRD 'space directions'" in err
    assert len(_lines(err, "orientation LPS")) == 1 and len(_lines(err, "augment: window")) == 1


@pytest.mark.parametrize("window,expect", [("-1024,2000", "above 2000 (teeth, dense bone or contrast, or metal?)"),
                                           ("ct-soft-tissue", "below -160 (fat, lung or air?)"),
                                           (None, "above 3071 (metal?)")])
def test_clipped_ends_named_for_hounsfield_data(capsys, tmp_path, window, expect):
    p = tmp_path / "ct.npy"
    x = _ct()
    x[0, 1, 0] = 3100                                               # a little metal above ct-full
    np.save(p, x)
    args = ["--window", window] if window else []
    code, _, err = run(capsys, "augment", str(p), "-o", str(tmp_path / "a.aug.h5"), *args)
    assert code == 0 and expect in err
    assert open_augmented(tmp_path / "a.aug.h5").attrs["density_units"] == "HU"   # whatever the window


def test_non_hounsfield_data_keeps_its_brightest_apart(capsys, tmp_path):
    rng = np.random.default_rng(1)
    x = rng.normal(300, 40, (20, 20, 20)).astype(np.float32)
    x[10, 10, 5:10] = 5000                                          # a thin bright wire, 0.06%
    p = tmp_path / "s.npy"
    np.save(p, x)
    code, _, err = run(capsys, "augment", str(p), "-o", str(tmp_path / "s.aug.h5"))
    (line,) = _lines(err, "augment: window")
    lo = open_augmented(tmp_path / "s.aug.h5").density_window[0]
    assert code == 0 and f"--window={lo:g},p100 keeps them apart" in line and "HU" not in line
    assert "density_units" not in open_augmented(tmp_path / "s.aug.h5").attrs
    code, _, err = run(capsys, "augment", str(p), "-o", str(tmp_path / "t.aug.h5"), "--window", "0,10000")
    assert code == 0 and "density_units" not in open_augmented(tmp_path / "t.aug.h5").attrs
    assert "0.00% of voxels below 0, 0.00% above 10000" in err


@pytest.mark.parametrize("window", [None, "p1,p99", "ct-bone"])
def test_thin_slices_keeps_the_window(capsys, tmp_path, window):
    rng = np.random.default_rng(2)
    x = rng.normal(500, 200, (6, 30, 30)).astype(np.float32)
    x[::2] += 400                                                   # thin-slice interpolation changes percentiles
    p = tmp_path / "v.npy"
    np.save(p, x)
    args = ["--spacing", "1,1,5"] + (["--window", window] if window else [])
    code, _, err = run(capsys, "augment", str(p), "-o", str(tmp_path / "a.aug.h5"), *args)
    code2, _, err2 = run(capsys, "augment", str(p), "-o", str(tmp_path / "b.aug.h5"), *args, "--thin-slices")
    assert code == code2 == 0, err2
    a, b = open_augmented(tmp_path / "a.aug.h5"), open_augmented(tmp_path / "b.aug.h5")
    assert b.shape[0] > a.shape[0] and a.density_window == b.density_window
    assert a.attrs["density_window_method"] == b.attrs["density_window_method"]
    assert "refined by --thin-slices from 1,1,5" in err2


def test_spacing_help_gives_the_order_and_an_example(capsys):
    code, out, _ = run(capsys, "augment", "--help")
    text = " ".join(out.split())
    assert code == 0 and "Voxel spacing along i, j, k, in that order" in text
    assert "--spacing 0.5,0.5,2.5" in text or "--spacing 0.7,0.7,2.5" in text
