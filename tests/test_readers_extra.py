"""MetaImage, VTK image data, Zarr / OME-Zarr and multi-series DICOM folders, each written by its own library."""

from __future__ import annotations

import numpy as np
import pytest

from isplat.errors import IsplatError
from isplat.cli.main import main
from isplat.volume_io import LazyZarr, read_volume

from test_volume_io import _write_dicom


@pytest.fixture
def vol():
    rng = np.random.default_rng(3)
    return rng.integers(-1024, 3000, size=(5, 6, 7)).astype(np.int16)  # [k, j, i]


@pytest.mark.parametrize("ext", [".mha", ".mhd"])
def test_metaimage_simpleitk(tmp_path, vol, ext):
    sitk = pytest.importorskip("SimpleITK")
    img = sitk.GetImageFromArray(vol)  # numpy [z, y, x] -> image (x, y, z)
    img.SetSpacing((0.5, 0.7, 2.0))
    sitk.WriteImage(img, str(tmp_path / f"v{ext}"))
    v = read_volume(tmp_path / f"v{ext}")
    assert np.array_equal(v.array, vol) and v.array.dtype == np.int16
    assert v.spacing_ijk == (0.5, 0.7, 2.0) and v.meta["format"] == "metaimage"


def test_metaimage_unreadable(tmp_path):
    pytest.importorskip("SimpleITK")
    (tmp_path / "bad.mha").write_text("ObjectType = Image\nNDims = 3\n")
    with pytest.raises(IsplatError, match=r"bad\.mha: not a readable MetaImage file"):
        read_volume(tmp_path / "bad.mha")


def test_vti_vtk(tmp_path, vol):
    pytest.importorskip("vtkmodules")
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    img = vtkImageData()
    img.SetDimensions(7, 6, 5)
    img.SetSpacing(0.5, 0.7, 2.0)
    arr = numpy_to_vtk(vol.ravel(), deep=True)
    arr.SetName("density")
    img.GetPointData().SetScalars(arr)
    w = vtkXMLImageDataWriter()
    w.SetFileName(str(tmp_path / "v.vti"))
    w.SetInputData(img)
    assert w.Write() == 1
    v = read_volume(tmp_path / "v.vti")
    assert np.array_equal(v.array, vol) and v.spacing_ijk == (0.5, 0.7, 2.0)
    (tmp_path / "bad.vti").write_text("<VTKFile>")
    with pytest.raises(IsplatError, match=r"bad\.vti: not a readable VTK"):
        read_volume(tmp_path / "bad.vti")


def _ome(tmp_path, vol, levels=2, tc=True):
    zarr = pytest.importorskip("zarr")
    g = zarr.open_group(str(tmp_path / "v.ome.zarr"), mode="w")
    datasets = []
    for lv in range(levels):
        data = vol[::2 ** lv, ::2 ** lv, ::2 ** lv]
        shape = ((1, 1) if tc else ()) + data.shape
        a = g.create_array(str(lv), shape=shape, chunks=((1, 1) if tc else ()) + (2,) + data.shape[1:],
                           dtype=data.dtype)
        a[...] = data.reshape(shape)
        s = 2.0 ** lv
        datasets.append({"path": str(lv), "coordinateTransformations": [
            {"type": "scale", "scale": ([1.0, 1.0] if tc else []) + [2.0 * s, 0.7 * s, 0.5 * s]}]})
    axes = ([{"name": "t", "type": "time"}, {"name": "c", "type": "channel"}] if tc else []) + \
        [{"name": n, "type": "space", "unit": "millimeter"} for n in "zyx"]
    g.attrs["multiscales"] = [{"version": "0.4", "axes": axes, "datasets": datasets}]
    return tmp_path / "v.ome.zarr"


def test_ome_zarr_levels_lazy(tmp_path, vol):
    p = _ome(tmp_path, vol)
    v = read_volume(p)
    assert isinstance(v.array, LazyZarr) and v.array.shape == vol.shape
    assert np.array_equal(v.array[1:3], vol[1:3]) and np.array_equal(v.array[::2, ::3, ::2], vol[::2, ::3, ::2])
    assert v.spacing_ijk == (0.5, 0.7, 2.0)
    v1 = read_volume(p, level=1)
    assert np.array_equal(np.asarray(v1.array), vol[::2, ::2, ::2]) and v1.spacing_ijk == (1.0, 1.4, 4.0)
    with pytest.raises(IsplatError, match=r"--level 2 invalid; this OME-Zarr has levels 0\.\.1"):
        read_volume(p, level=2)


def test_ome_zarr_reads_only_the_slab(tmp_path, vol, monkeypatch):
    p = _ome(tmp_path, vol, levels=1, tc=False)
    v = read_volume(p)
    seen = []
    real = type(v.array.array).__getitem__
    monkeypatch.setattr(type(v.array.array), "__getitem__", lambda self, key: seen.append(key) or real(self, key))
    assert np.array_equal(v.array[2:4], vol[2:4])
    assert seen == [(slice(2, 4), slice(None), slice(None))]


def test_plain_zarr_array_and_errors(tmp_path, vol):
    zarr = pytest.importorskip("zarr")
    a = zarr.open_array(str(tmp_path / "plain.zarr"), mode="w", shape=vol.shape, chunks=(1, 6, 7), dtype="i2")
    a[...] = vol
    v = read_volume(tmp_path / "plain.zarr")
    assert np.array_equal(np.asarray(v.array), vol) and v.spacing_ijk == (1.0, 1.0, 1.0)
    with pytest.raises(IsplatError, match="has one level"):
        read_volume(tmp_path / "plain.zarr", level=1)
    with pytest.raises(IsplatError, match="--level 1 applies to Zarr"):
        read_volume(_npy(tmp_path, vol), level=1)
    g = zarr.open_group(str(tmp_path / "g.zarr"), mode="w")
    g.create_array("x", shape=(2, 2, 2), dtype="u1")
    with pytest.raises(IsplatError, match="without OME-Zarr 'multiscales' metadata"):
        read_volume(tmp_path / "g.zarr")


def test_ome_zarr_refuses_several_channels(tmp_path, vol):
    zarr = pytest.importorskip("zarr")
    g = zarr.open_group(str(tmp_path / "c.zarr"), mode="w")
    g.create_array("0", shape=(2,) + vol.shape, dtype="i2")
    g.attrs["multiscales"] = [{"axes": [{"name": "c", "type": "channel"}] +
                               [{"name": n, "type": "space"} for n in "zyx"], "datasets": [{"path": "0"}]}]
    with pytest.raises(IsplatError, match="axis 'c' has 2 entries"):
        read_volume(tmp_path / "c.zarr")


def _npy(tmp_path, vol):
    np.save(tmp_path / "v.npy", vol)
    return tmp_path / "v.npy"


def _two_series(tmp_path, vol):
    from pydicom.uid import generate_uid

    d = tmp_path / "study"
    d.mkdir()
    uids = sorted(generate_uid() for _ in range(2))
    for s, uid in enumerate(uids):
        for k in range(3):
            f = d / f"s{s}_{k}.dcm"
            _write_dicom(f, (vol[k] + 1024).astype(np.uint16), 2.0 * k, 1, -1024)
            import pydicom
            ds = pydicom.dcmread(str(f))
            ds.SeriesInstanceUID = uid
            ds.SeriesDescription = f"series {s}"
            ds.save_as(str(f), enforce_file_format=True)
    return d, uids


def test_dicom_several_series(tmp_path, vol):
    pytest.importorskip("pydicom")
    d, uids = _two_series(tmp_path, vol)
    with pytest.raises(IsplatError) as info:
        read_volume(d)
    msg = str(info.value)
    assert "holds 2 DICOM series; choose one with --series UID" in msg and "\n" not in msg
    assert f"{uids[0]} (3 slices, series 0)" in msg and uids[1] in msg
    v = read_volume(d, series=uids[1])
    assert np.array_equal(v.array, vol[:3].astype(np.float32)) and v.meta["hounsfield"]
    with pytest.raises(IsplatError, match="no DICOM series with --series 1.2.3"):
        read_volume(d, series="1.2.3")
    with pytest.raises(IsplatError, match="--series applies to a DICOM folder only"):
        read_volume(_npy(tmp_path, vol), series=uids[0])


def test_ome_zarr_0_5_metadata_under_ome_key(tmp_path, vol):
    zarr = pytest.importorskip("zarr")
    g = zarr.open_group(str(tmp_path / "v5.zarr"), mode="w")
    g.create_array("s0", shape=vol.shape, dtype=vol.dtype)[...] = vol
    g.attrs["ome"] = {"version": "0.5", "multiscales": [{
        "axes": [{"name": n, "type": "space"} for n in "zyx"],
        "datasets": [{"path": "s0", "coordinateTransformations": [{"type": "scale", "scale": [3.0, 2.0, 1.0]}]}]}]}
    v = read_volume(tmp_path / "v5.zarr")
    assert np.array_equal(np.asarray(v.array), vol) and v.spacing_ijk == (1.0, 2.0, 3.0)


def test_nifti_ct_rescale_marks_hounsfield(tmp_path, vol):
    nib = pytest.importorskip("nibabel")
    img = nib.Nifti1Image((vol + 1024).astype(np.uint16).transpose(2, 1, 0), np.eye(4))
    img.header.set_slope_inter(1.0, -1024.0)
    nib.save(img, str(tmp_path / "ct.nii.gz"))
    v = read_volume(tmp_path / "ct.nii.gz")
    assert v.meta["hounsfield"] and np.allclose(v.array, vol)


@pytest.mark.parametrize("name, module, message", [
    ("v.mha", "SimpleITK", r"reading \.mha/\.mhd needs SimpleITK: pip install 'isplat\[metaimage\]'"),
    ("v.vti", "vtkmodules", r"reading \.vti needs vtk: pip install 'isplat\[vtk\]'"),
    ("v.zarr", "zarr", r"reading Zarr / OME-Zarr needs zarr: pip install 'isplat\[zarr\]'"),
])
def test_missing_extra_named(tmp_path, monkeypatch, name, module, message):
    import builtins

    real = builtins.__import__

    def fake(n, *a, **k):
        if n == module:
            raise ImportError("no")
        return real(n, *a, **k)

    p = tmp_path / name
    if name.endswith(".zarr"):
        p.mkdir()
    else:
        p.write_text("x")
    monkeypatch.setattr(builtins, "__import__", fake)
    with pytest.raises(IsplatError, match=message):
        read_volume(p)


def test_cli_series_and_level(capsys, tmp_path, vol):
    pytest.importorskip("pydicom")
    from test_cli_augment import _one_error, run

    d, uids = _two_series(tmp_path, vol)
    code, _, err = run(capsys, "augment", str(d), "-o", str(tmp_path / "s.aug.h5"))
    _one_error(code, err, "holds 2 DICOM series; choose one with --series UID", uids[0], uids[1])
    assert not (tmp_path / "s.aug.h5").exists()
    code, _, err = run(capsys, "augment", str(d), "-o", str(tmp_path / "s.aug.h5"), "--series", uids[0])
    assert code == 0 and "Hounsfield data (dicom rescale): ct-full" in err
    p = _ome(tmp_path, vol)
    code, _, err = run(capsys, "augment", str(p), "-o", str(tmp_path / "z.aug.h5"), "--level", "1", "-q")
    from isplat.augfile import open_augmented
    assert code == 0 and open_augmented(tmp_path / "z.aug.h5").shape == vol[::2, ::2, ::2].shape


def test_cli_bad_files_one_line(capsys, tmp_path):
    """Libraries that print their own errors (ITK's MetaIO, VTK's log) still give one line and no output."""
    from test_cli_augment import _one_error, run

    pytest.importorskip("SimpleITK")
    pytest.importorskip("vtkmodules")
    (tmp_path / "bad.mha").write_text("ObjectType = Image\nNDims = 3\n")
    (tmp_path / "cut.vti").write_text('<?xml version="1.0"?>\n<VTKFile type="ImageData" version="0.1">\n'
                                      '<ImageData WholeExtent="0 1 0 1 0 1" Origin="0 0 0" Spacing="1 1 1">\n<Pie')
    (tmp_path / "short.vti").write_text(
        '<?xml version="1.0"?>\n<VTKFile type="ImageData" version="0.1" byte_order="LittleEndian">\n'
        '<ImageData WholeExtent="0 1 0 1 0 1" Origin="0 0 0" Spacing="1 1 1">\n<Piece Extent="0 1 0 1 0 1">'
        '<PointData Scalars="d"><DataArray type="UInt8" Name="d" format="ascii">1 2 3</DataArray></PointData>'
        '</Piece></ImageData></VTKFile>\n')
    for name, needle in [("bad.mha", "not a readable MetaImage file (DimSize required and not defined.)"),
                         ("cut.vti", "not a readable VTK image data (.vti) file (Error parsing XML"),
                         ("short.vti", "not a readable VTK image data (.vti) file (Error reading extent")]:
        code, _, err = run(capsys, "augment", str(tmp_path / name), "-o", str(tmp_path / "o.aug.h5"))
        _one_error(code, err, needle)
        assert not (tmp_path / "o.aug.h5").exists()


def test_ome_zarr_0_4_in_zarr_format_2(tmp_path, vol):
    """OME-NGFF 0.4 stores are Zarr format 2 (.zgroup, .zattrs, .zarray), as most existing data."""
    zarr = pytest.importorskip("zarr")
    g = zarr.open_group(str(tmp_path / "v2.zarr"), mode="w", zarr_format=2)
    g.create_array("0", shape=vol.shape, chunks=(1,) + vol.shape[1:], dtype=vol.dtype)[...] = vol
    g.attrs["multiscales"] = [{"version": "0.4", "axes": [{"name": n, "type": "space"} for n in "zyx"],
                               "datasets": [{"path": "0", "coordinateTransformations": [
                                   {"type": "scale", "scale": [2.0, 0.7, 0.5]}]}]}]
    assert (tmp_path / "v2.zarr" / ".zgroup").exists()
    v = read_volume(tmp_path / "v2.zarr")
    assert np.array_equal(v.array[1:4], vol[1:4]) and v.spacing_ijk == (0.5, 0.7, 2.0)


# --- InVesalius .inv3 --------------------------------------------------------------------------------------------

def _inv3(path, vol, mode="w:gz", spacing=(0.5, 0.6, 2.0), matrix=None, data=None):
    """An InVesalius-style project: a tar of a folder holding main.plist and matrix.dat (the raw [z, y, x] array)."""
    import io
    import plistlib
    import tarfile

    plist = {"format_version": 2, "modality": "CT", "orientation": "AXIAL", "spacing": list(spacing),
             "window_width": 400.0, "window_level": 40.0, "scalar_range": [0, 1000],
             "matrix": matrix or {"filename": "matrix.dat", "shape": list(vol.shape), "dtype": str(vol.dtype)}}
    with tarfile.open(path, mode) as tar:
        for name, blob in (("main.plist", plistlib.dumps(plist)),
                           ("matrix.dat", vol.astype(vol.dtype.newbyteorder("<")).tobytes() if data is None else data)):
            info = tarfile.TarInfo(f"tmpa1b2c3/{name}")
            info.size = len(blob)
            tar.addfile(info, io.BytesIO(blob))
    return path


@pytest.mark.parametrize("mode", ["w:gz", "w"])
def test_inv3_project(tmp_path, vol, mode):
    p = _inv3(tmp_path / "case.inv3", vol.astype(np.int16) - 1024, mode)
    v = read_volume(p)
    assert v.array.dtype == np.int16 and np.array_equal(v.array, vol.astype(np.int16) - 1024)
    assert v.spacing_ijk == (0.5, 0.6, 2.0) and v.meta["format"] == "inv3"
    assert v.meta["spacing_source"] == "InVesalius project spacing" and "axes_lps" not in v.meta


def test_inv3_bad_projects_one_line(tmp_path, vol):
    cases = [(_inv3(tmp_path / "a.inv3", vol, data=b"\0" * 10), "has 10 bytes"),
             (_inv3(tmp_path / "b.inv3", vol, matrix={"filename": "m.dat", "shape": [3, 4], "dtype": "int16"}),
              "expected a 3-D volume"),
             (_inv3(tmp_path / "c.inv3", vol, matrix={"filename": "other.dat", "shape": [3, 4, 5],
                                                      "dtype": "uint16"}), "'other.dat' is missing"),
             (_inv3(tmp_path / "d.inv3", vol, matrix={"shape": [3, 4, 5]}), "no valid 'matrix'")]
    (tmp_path / "e.inv3").write_bytes(b"\x1f\x8b not really gzip")
    cases.append((tmp_path / "e.inv3", "not a readable InVesalius project"))
    for p, needle in cases:
        with pytest.raises(IsplatError, match=needle) as e:
            read_volume(p)
        assert "\n" not in str(e.value)


def test_inv3_through_augment_cli(capsys, tmp_path, vol):
    p = _inv3(tmp_path / "case.inv3", vol.astype(np.int16) - 1024)
    with pytest.raises(SystemExit) as e:
        main(["augment", str(p), "-o", str(tmp_path / "c.aug.h5")])
    err = capsys.readouterr().err
    assert e.value.code == 0 and "spacing 0.5,0.6,2 (i, j, k): from InVesalius project spacing" in err
    assert "no orientation in inv3 input" in err
