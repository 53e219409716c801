"""Every reader: voxel values in [k, j, i] order and spacing in i, j, k order."""

import io
import sys

import numpy as np
import pytest

from isplat.errors import IsplatError
from isplat.volume_io import read_volume


@pytest.fixture
def vol():
    """A (n_k, n_j, n_i) = (3, 4, 5) volume whose value encodes its position: 100 k + 10 j + i."""
    k, j, i = np.meshgrid(np.arange(3), np.arange(4), np.arange(5), indexing="ij")
    return (100 * k + 10 * j + i).astype(np.uint16)


def test_npy_is_memory_mapped(tmp_path, vol):
    p = tmp_path / "v.npy"
    np.save(p, vol)
    v = read_volume(p)
    assert isinstance(v.array, np.memmap)
    assert np.array_equal(v.array, vol) and v.spacing_ijk == (1.0, 1.0, 1.0)
    assert read_volume(p, spacing=(0.5, 1, 2)).spacing_ijk == (0.5, 1.0, 2.0)


@pytest.mark.parametrize("dtype", ["uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64"])
@pytest.mark.parametrize("order", ["little", "big"])
def test_raw_dtypes_byte_orders_header(tmp_path, vol, dtype, order):
    p = tmp_path / "v.raw"
    data = vol.astype(dtype).astype(np.dtype(dtype).newbyteorder("<" if order == "little" else ">"))
    p.write_bytes(b"HEADER!" + data.tobytes())
    v = read_volume(p, shape=(5, 4, 3), dtype=dtype, byte_order=order, header_bytes=7)
    assert isinstance(v.array, np.memmap)
    assert np.array_equal(v.array, vol.astype(dtype))


def test_raw_size_mismatch_names_both_sizes(tmp_path, vol):
    p = tmp_path / "v.raw"
    p.write_bytes(vol.tobytes())
    with pytest.raises(IsplatError, match=r"file has 120 bytes.*needs 240 bytes"):
        read_volume(p, shape=(5, 4, 6), dtype="uint16")
    with pytest.raises(IsplatError, match="dtype 'uint12' unknown"):
        read_volume(p, shape=(5, 4, 3), dtype="uint12")
    with pytest.raises(IsplatError, match="needs --shape"):
        read_volume(p)


def test_raw_stdin(monkeypatch, vol):
    data = vol.astype(">u2").tobytes()
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(data)))
    v = read_volume("-", shape=(5, 4, 3), dtype="uint16", byte_order="big")
    assert np.array_equal(v.array, vol)


def test_nrrd_spacing_from_space_directions_and_spacings(tmp_path, vol):
    import nrrd

    p = tmp_path / "v.nrrd"
    nrrd.write(str(p), vol, {"space dimension": 3, "space directions": np.diag([0.5, 0.7, 2.0])}, index_order="C")
    v = read_volume(p)
    assert np.array_equal(v.array, vol) and v.spacing_ijk == pytest.approx((0.5, 0.7, 2.0))
    p2 = tmp_path / "s.nrrd"
    nrrd.write(str(p2), vol, {"spacings": [0.25, 0.5, 3.0]}, index_order="C")
    assert read_volume(p2).spacing_ijk == pytest.approx((0.25, 0.5, 3.0))


def test_nifti_axes_and_zooms(tmp_path, vol):
    import nibabel as nib

    xyz = vol.transpose(2, 1, 0)  # NIfTI data is [x, y, z]
    img = nib.Nifti1Image(xyz, np.diag([0.8, 0.9, 2.5, 1.0]))
    for name in ("v.nii", "v.nii.gz"):
        p = tmp_path / name
        nib.save(img, str(p))
        v = read_volume(p)
        assert np.array_equal(v.array, vol)
        assert v.spacing_ijk == pytest.approx((0.8, 0.9, 2.5))


def test_tiff_multipage_and_folder(tmp_path, vol):
    import tifffile

    p = tmp_path / "v.tif"
    tifffile.imwrite(str(p), vol, photometric="minisblack")
    assert np.array_equal(read_volume(p).array, vol)
    d = tmp_path / "slices"
    d.mkdir()
    for k in range(vol.shape[0]):  # natural order: slice2 before slice10
        tifffile.imwrite(str(d / f"slice{[2, 10, 11][k]}.tiff"), vol[k])
    v = read_volume(d)
    assert np.array_equal(v.array, vol) and v.meta["format"] == "tiff"


def _write_dicom(path, pixels, z, slope, intercept):
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid

    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = CTImageStorage
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID = CTImageStorage
    ds.SOPInstanceUID = meta.MediaStorageSOPInstanceUID
    ds.Modality = "CT"
    ds.Rows, ds.Columns = pixels.shape
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME2"
    ds.PixelSpacing = [0.6, 0.4]  # [between rows (j), between columns (i)]
    ds.ImageOrientationPatient = [1, 0, 0, 0, 1, 0]
    ds.ImagePositionPatient = [-10.0, 5.0, z]
    ds.RescaleSlope = slope
    ds.RescaleIntercept = intercept
    ds.PixelData = pixels.astype("<u2").tobytes()
    ds.save_as(str(path), enforce_file_format=True)


def test_dicom_series_ordered_by_position_and_rescaled(tmp_path, vol):
    d = tmp_path / "series"
    d.mkdir()
    zs = [30.0, 32.5, 35.0]
    # shuffled file names: file order must not matter, only ImagePositionPatient
    for name, k in zip(["b.dcm", "c.dcm", "a.dcm"], [2, 0, 1]):
        _write_dicom(d / name, vol[k], zs[k], 2, -1024)
    (d / "notes.txt").write_text("not dicom")
    v = read_volume(d)
    assert v.array.dtype == np.float32
    assert np.array_equal(v.array, vol.astype(np.float32) * 2 - 1024)
    assert v.spacing_ijk == pytest.approx((0.4, 0.6, 2.5))


def test_dicom_inconsistent_size_refused(tmp_path, vol):
    d = tmp_path / "bad"
    d.mkdir()
    _write_dicom(d / "1.dcm", vol[0], 0.0, 1, 0)
    _write_dicom(d / "2.dcm", vol[1, :3], 1.0, 1, 0)
    with pytest.raises(IsplatError, match="3x5"):
        read_volume(d)


def test_bad_inputs(tmp_path, vol):
    with pytest.raises(IsplatError, match="does not exist"):
        read_volume(tmp_path / "nope.npy")
    np.save(tmp_path / "flat.npy", vol[0])
    with pytest.raises(IsplatError, match="2 dimension"):
        read_volume(tmp_path / "flat.npy")
    (tmp_path / "x.xyz").write_text("?")
    with pytest.raises(IsplatError, match="unknown input format"):
        read_volume(tmp_path / "x.xyz")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(IsplatError, match="no .tif"):
        read_volume(empty)
    full = tmp_path / "t.npy"
    np.save(full, vol)
    (tmp_path / "trunc.npy").write_bytes(full.read_bytes()[:-10])
    with pytest.raises(IsplatError, match="truncated"):
        read_volume(tmp_path / "trunc.npy")
    np.save(tmp_path / "b.npy", np.ones((2, 2, 2), bool))
    with pytest.raises(IsplatError, match="not supported"):
        read_volume(tmp_path / "b.npy")
    with pytest.raises(IsplatError, match="spacing"):
        read_volume(full, spacing=(1, 0, 1))
    (tmp_path / "bad.nrrd").write_text("NRRD0004\ntype: short\n")
    with pytest.raises(IsplatError, match="NRRD"):
        read_volume(tmp_path / "bad.nrrd")


def test_missing_extra_names_it(tmp_path, vol, monkeypatch):
    import builtins

    real = builtins.__import__

    def fake(name, *a, **k):
        if name == "nrrd":
            raise ImportError("no")
        return real(name, *a, **k)

    (tmp_path / "v.nrrd").write_text("x")
    monkeypatch.setattr(builtins, "__import__", fake)
    with pytest.raises(IsplatError, match=r"reading \.nrrd needs pynrrd: pip install 'isplat\[nrrd\]'"):
        read_volume(tmp_path / "v.nrrd")


@pytest.mark.parametrize("order", ["C", "F"])
def test_streamed_npy_reads_what_the_memory_map_reads(tmp_path, order):
    """read_volume(stream=True): plain file reads (no memory map of the whole file) for augment; the same
    values for slabs, strided subsamples and single planes; Fortran order falls back to the memory map."""
    from isplat.volume_io import LazyFile, read_volume

    a = np.asarray(np.random.default_rng(0).integers(0, 4000, (7, 5, 6)), dtype=">i2", order=order)
    np.save(tmp_path / "a.npy", a)
    v = read_volume(tmp_path / "a.npy", stream=True)
    assert isinstance(v.array, LazyFile) == (order == "C") and v.array.shape == a.shape
    for key in (np.s_[2:5], np.s_[::3, ::2, ::4], np.s_[4], np.s_[6, 1:3], np.s_[5:2:-1], np.s_[9:]):
        assert np.array_equal(v.array[key], a[key]), key


def test_streamed_raw_file_that_ends_early_is_one_line(tmp_path):
    from isplat.volume_io import LazyFile

    (tmp_path / "a.raw").write_bytes(bytes(100))
    lf = LazyFile(tmp_path / "a.raw", 0, np.uint8, (5, 4, 6))       # needs 120 bytes
    assert lf[0:4].shape == (4, 4, 6)
    with pytest.raises(IsplatError, match="a.raw: file ended inside plane k=4; truncated"):
        lf[3:5]
