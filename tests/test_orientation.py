"""Orientation: readers keep the scan's LPS axes, the augmented file records them, named views see the patient
from the side they name with superior (or anterior) up."""

import itertools

import h5py
import numpy as np
import pytest
from hypothesis import given, strategies as st

from isplat.augfile import open_augmented, write_augmented
from isplat.augment import augment_array, augment_file
from isplat.camera import NAMED_VIEWS, _frame_from, ViewFrame, named_view, project_points, volume_geometry
from isplat.errors import IsplatError
from isplat.orientation import axes_from_code, code_of, describe, orthonormal
from isplat.volume_io import read_volume

CODES = ["".join(p) for letters in itertools.product("LR", "AP", "SI") for p in itertools.permutations(letters)]
MARKERS = {"A": 1, "S": 2, "L": 3}           # marker value at the patient's anterior, superior, left
R = 6.0                                      # marker distance from the centre, mm
# view: (marker nearest (+1) or farthest (-1) from the viewer, marker at the top, marker right (+1) / left (-1))
EXPECTED = {"anterior": ("A", 1, "S", "L", 1), "posterior": ("A", -1, "S", "L", -1),
            "left": ("L", 1, "S", "A", -1), "right": ("L", -1, "S", "A", 1),
            "superior": ("S", 1, "A", "L", -1), "inferior": ("S", -1, "A", "L", 1)}


@given(st.sampled_from(CODES))
def test_codes_round_trip(code):
    a = axes_from_code(code)
    assert code_of(a) == code
    assert np.allclose(a @ a.T, np.eye(3))
    assert code in describe(a)


def test_bad_codes_one_line():
    for bad in ("LPX", "LLS", "LP", "", "lpss"):
        with pytest.raises(IsplatError, match="three letters"):
            axes_from_code(bad)
    with pytest.raises(IsplatError, match="singular"):
        orthonormal(np.zeros((3, 3)))


def _phantom(shape_ijk, to_lps):
    """[k, j, i] volume: 0, and three markers at LPS (0, -R, 0) anterior, (0, 0, R) superior, (R, 0, 0) left;
    ``to_lps(i, j, k)`` is a voxel's LPS position relative to the centre."""
    ni, nj, nk = shape_ijk
    k, j, i = np.meshgrid(np.arange(nk), np.arange(nj), np.arange(ni), indexing="ij")
    pos = to_lps(i, j, k)
    vol = np.zeros((nk, nj, ni), np.int16)
    for name, at in (("A", (0, -R, 0)), ("S", (0, 0, R)), ("L", (R, 0, 0))):
        d2 = sum((p - c) ** 2 for p, c in zip(pos, at))
        vol[d2 <= 2.5 ** 2] = MARKERS[name]
    return vol


def _check_views(arr, spacing, axes_lps, unit_axes):
    geom = volume_geometry(arr.shape, spacing, axes=unit_axes)
    for view, (near, sign, top, side, side_sign) in EXPECTED.items():
        w, up = named_view(view, axes_lps, unit_axes=geom.unit_axes)
        u, v, w = _frame_from(w, up, 0.0)
        frame = ViewFrame("orthographic", geom.centre, u, v, w, None, 0.25, 200, 200, 0.0)
        centre = {}
        depth = {}
        for name, value in MARKERS.items():
            kji = np.argwhere(arr == value)
            assert len(kji), name
            world = geom.q + kji[:, ::-1].astype(float) @ geom.steps
            centre[name] = project_points(frame, world).mean(axis=0)
            depth[name] = float(((world - geom.centre) @ w).mean())
        assert depth[near] * sign > 0.8 * R, (view, depth)
        assert min(centre, key=lambda n: centre[n][1]) == top, (view, centre)      # pixel y grows downwards
        assert (centre[side][0] - 99.5) * side_sign > 0.8 * R / 0.25, (view, centre)


def _nifti(tmp_path, affine_cols, shape=(21, 19, 19)):
    nib = pytest.importorskip("nibabel")
    A = np.asarray(affine_cols, float).T            # columns: the RAS vectors of x, y, z (= i, j, k)
    ctr = (np.asarray(shape) - 1) / 2.0

    def to_lps(i, j, k):
        ras = [A[r, 0] * (i - ctr[0]) + A[r, 1] * (j - ctr[1]) + A[r, 2] * (k - ctr[2]) for r in range(3)]
        return -ras[0], -ras[1], ras[2]

    vol = _phantom(shape, to_lps)
    aff = np.eye(4)
    aff[:3, :3] = A
    aff[:3, 3] = [5.0, -3.0, 20.0]
    img = nib.Nifti1Image(np.ascontiguousarray(vol.transpose(2, 1, 0)), aff)
    img.set_sform(aff, code=1)
    img.set_qform(aff, code=1)
    p = tmp_path / "ph.nii.gz"
    nib.save(img, str(p))
    return p, vol


# RAS columns. i towards inferior (2 mm), j towards the right (1.5 mm), k posterior (1 mm): a rotation ...
ROTATED = [(0, 0, -2.0), (1.5, 0, 0), (0, -1.0, 0)]
# ... and a mirror: i posterior, j superior, k right (det -1)
MIRRORED = [(0, -1.2, 0), (0, 0, 1.0), (1.4, 0, 0)]


@pytest.mark.parametrize("cols,code", [(ROTATED, "IRP"), (MIRRORED, "PSR")])
def test_nifti_orientation_and_named_views(tmp_path, cols, code):
    p, vol = _nifti(tmp_path, cols)
    v = read_volume(p)
    assert np.array_equal(v.array, vol)
    assert code_of(v.meta["axes_lps"]) == code
    _check_views(v.array, v.spacing_ijk, v.meta["axes_lps"], v.meta["axes_lps"])   # world = patient space
    if np.linalg.det(v.meta["axes_lps"]) > 0:
        _check_views(v.array, v.spacing_ijk, v.meta["axes_lps"], None)             # world = grid space


def test_nifti_without_orientation_codes_has_none(tmp_path):
    nib = pytest.importorskip("nibabel")
    img = nib.Nifti1Image(np.zeros((4, 5, 6), np.int16), np.eye(4))
    img.set_sform(None, code=0)
    img.set_qform(None, code=0)
    nib.save(img, str(tmp_path / "a.nii"))
    assert "axes_lps" not in read_volume(tmp_path / "a.nii").meta


NRRD_DIRS = np.array([[0, 0, 1.5], [-2.0, 0, 0], [0, 1.0, 0]])     # RAS: i superior, j left, k anterior


def _nrrd(tmp_path, shape=(21, 19, 19)):
    nrrd = pytest.importorskip("nrrd")
    dirs = NRRD_DIRS
    ctr = (np.asarray(shape) - 1) / 2.0

    def to_lps(i, j, k):
        ras = [dirs[0, r] * (i - ctr[0]) + dirs[1, r] * (j - ctr[1]) + dirs[2, r] * (k - ctr[2]) for r in range(3)]
        return -ras[0], -ras[1], ras[2]

    vol = _phantom(shape, to_lps)
    p = tmp_path / "ph.nrrd"
    nrrd.write(str(p), vol, {"space": "right-anterior-superior", "space directions": dirs,
                             "space origin": np.zeros(3)}, index_order="C")
    return p, vol


def test_nrrd_space_directions(tmp_path):
    nrrd = pytest.importorskip("nrrd")
    p, vol = _nrrd(tmp_path)
    dirs = NRRD_DIRS
    v = read_volume(p)
    assert code_of(v.meta["axes_lps"]) == "SLA"
    assert v.spacing_ijk == pytest.approx((1.5, 2.0, 1.0))
    _check_views(v.array, v.spacing_ijk, v.meta["axes_lps"], v.meta["axes_lps"])
    nrrd.write(str(tmp_path / "s.nrrd"), vol, {"space dimension": 3, "space directions": dirs}, index_order="C")
    assert "axes_lps" not in read_volume(tmp_path / "s.nrrd").meta    # no patient space: no orientation


def _dicom_slice(path, pixels, iop, ipp):
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian, MRImageStorage, generate_uid

    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = MRImageStorage
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID, ds.SOPInstanceUID, ds.Modality = MRImageStorage, meta.MediaStorageSOPInstanceUID, "MR"
    ds.SeriesInstanceUID = "1.2.3"
    ds.Rows, ds.Columns = pixels.shape
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.PixelSpacing = [1.0, 1.0]
    ds.ImageOrientationPatient = list(iop)
    ds.ImagePositionPatient = list(ipp)
    ds.PixelData = pixels.astype("<u2").tobytes()
    ds.save_as(str(path), enforce_file_format=True)


def _dicom_series(tmp_path, shape=(21, 19, 19)):
    """A sagittal series: rows along P, columns down (I), slices towards the patient's right; files out of order."""
    pytest.importorskip("pydicom")
    row, col = np.array([0, 1.0, 0]), np.array([0, 0, -1.0])
    normal = np.cross(row, col)                                     # (-1, 0, 0): towards the patient's right
    ctr = (np.asarray(shape) - 1) / 2.0

    def to_lps(i, j, k):
        return tuple(row[r] * (i - ctr[0]) + col[r] * (j - ctr[1]) + normal[r] * (k - ctr[2]) for r in range(3))

    vol = _phantom(shape, to_lps).astype(np.uint16)
    d = tmp_path / "sag"
    d.mkdir(exist_ok=True)
    for k in range(shape[2]):
        _dicom_slice(d / f"{(7 * k) % shape[2]:03d}.dcm", vol[k], (*row, *col), tuple(normal * k + [3, 4, 5]))
    return d, vol


def test_dicom_sagittal_series(tmp_path):
    d, vol = _dicom_series(tmp_path)
    v = read_volume(d)
    assert np.array_equal(v.array, vol)
    assert code_of(v.meta["axes_lps"]) == "PIR"
    _check_views(v.array, v.spacing_ijk, v.meta["axes_lps"], v.meta["axes_lps"])
    _check_views(v.array, v.spacing_ijk, v.meta["axes_lps"], None)


def test_metaimage_direction(tmp_path):
    sitk = pytest.importorskip("SimpleITK")
    img = sitk.GetImageFromArray(np.zeros((3, 4, 5), np.int16))
    img.SetDirection((0, 0, 1, -1, 0, 0, 0, -1, 0))                # columns: i -> (0,-1,0) A, j -> I, k -> L
    sitk.WriteImage(img, str(tmp_path / "a.mha"))
    assert code_of(read_volume(tmp_path / "a.mha").meta["axes_lps"]) == "AIL"


def test_augmented_file_keeps_orientation(tmp_path):
    p, vol = _nifti(tmp_path, ROTATED)
    info = augment_file(p, tmp_path / "o.aug.h5", window=(0, 3))
    aug = open_augmented(tmp_path / "o.aug.h5")
    assert code_of(aug.axes_lps) == "IRP" and np.allclose(aug.axes_lps, info["axes_lps"])
    np.save(tmp_path / "v.npy", vol)
    augment_file(tmp_path / "v.npy", tmp_path / "n.aug.h5", window=(0, 3))
    assert open_augmented(tmp_path / "n.aug.h5").axes_lps is None               # .npy: orientation unknown
    augment_file(tmp_path / "v.npy", tmp_path / "c.aug.h5", window=(0, 3), orientation="RAS")
    assert code_of(open_augmented(tmp_path / "c.aug.h5").axes_lps) == "RAS"
    from isplat.stats import collect, format_table

    assert "orientation                 RAS: i, j, k point to the patient's right, anterior, superior" in \
        format_table(collect(tmp_path / "c.aug.h5"))
    assert collect(tmp_path / "n.aug.h5")["augmented"]["axes_lps"] is None


@pytest.mark.parametrize("value,what", [(np.eye(3) * 2, "orthonormal"), (np.eye(3)[:2], "shape"),
                                        (np.eye(3, dtype=np.float32), "type"), (np.full((3, 3), np.nan), "finite")])
def test_bad_axes_attribute_refused(tmp_path, value, what):
    a = augment_array(np.arange(24, dtype=np.float32).reshape(2, 3, 4))
    p = tmp_path / "a.aug.h5"
    write_augmented(p, a["density"], a["gradient_magnitude"], a["normal"], a["spacing_ijk"], a["density_window"],
                    a["gradient_magnitude_scale"])
    assert open_augmented(p).axes_lps is None                                    # a file without it: unknown
    with h5py.File(p, "a") as f:
        f.attrs["axes_lps"] = value
    with pytest.raises(IsplatError, match=f"axes_lps.*{what}"):
        open_augmented(p)


def test_named_view_errors():
    with pytest.raises(IsplatError, match="expected one of anterior"):
        named_view("front", np.eye(3))
    with pytest.raises(IsplatError, match="--orientation"):
        named_view("anterior", None)


@given(st.sampled_from(CODES), st.sampled_from(sorted(NAMED_VIEWS)), st.floats(-360, 360), st.floats(-89, 89))
def test_named_view_azimuth_elevation(code, view, az, el):
    """az/el act as the orbit camera's about the view's up; w and up stay orthonormal."""
    a = axes_from_code(code)
    w0, up0 = named_view(view, a, unit_axes=a)                   # world = patient space: the table itself
    assert np.allclose(w0, NAMED_VIEWS[view][0]) and np.allclose(up0, NAMED_VIEWS[view][1])
    w, up = named_view(view, a, az, el, unit_axes=a)
    assert abs(w @ up) < 1e-9 and np.isclose(np.linalg.norm(w), 1) and np.isclose(np.linalg.norm(up), 1)
    assert np.isclose(w @ up0, np.sin(np.radians(el)))            # elevation lifts towards the view's up
    g, _ = named_view(view, a, az, el)                           # grid world: the same vector, mapped
    assert np.allclose(g, a @ w)


def test_singular_nifti_affine_is_a_warning_not_an_error(tmp_path, caplog):
    nib = pytest.importorskip("nibabel")
    hdr = nib.Nifti1Header()
    hdr.set_data_shape((4, 5, 6))
    hdr.set_data_dtype(np.int16)
    hdr["sform_code"], hdr["qform_code"] = 1, 0
    hdr["srow_x"], hdr["srow_y"], hdr["srow_z"] = [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0]   # z collapses
    nib.save(nib.Nifti1Image(np.zeros((4, 5, 6), np.int16), None, header=hdr), str(tmp_path / "s.nii"))
    v = read_volume(tmp_path / "s.nii")
    assert "axes_lps" not in v.meta and "orientation is taken as unknown" in caplog.text


# --- rendered: data with an orientation is seen from the front, superior up, by default (scene version 5) -------

def _marker_centres(png):
    """Pixel centroid (x, y) of each marker, by its colour: A red, S green, L blue (``png``: a file or an RGB
    array in 0..255)."""
    import imageio.v3 as iio

    img = (iio.imread(png) if not isinstance(png, np.ndarray) else png)[..., :3].astype(float)
    out = {}
    for name, c in (("A", 0), ("S", 1), ("L", 2)):
        mask = (img[..., c] > 60) & (img[..., c] > 2 * np.delete(img, c, axis=-1).max(axis=-1))
        assert mask.sum() > 4, name
        y, x = np.nonzero(mask)
        out[name] = (x.mean(), y.mean())
    return out


def _flat(centres):
    return np.array([centres[n] for n in "ASL"])


def _render_phantom(tmp_path, monkeypatch, cols, *extra, out="a.png"):
    """The phantom written by ``cols`` (NIfTI affine columns, or a writer of tmp_path), augmented once, rendered
    with the defaults and ``extra``: the markers' pixel centres."""
    from isplat.cli.main import main

    p, _ = cols(tmp_path) if callable(cols) else _nifti(tmp_path, cols)
    monkeypatch.chdir(tmp_path)
    if not (tmp_path / "ph.aug.h5").exists():
        augment_file(p, tmp_path / "ph.aug.h5", window=(0.0, 3.0))
    opts = ["--set", 'transfer.opacity=[[0.5, 0], [0.6, 1], [3, 1]]', "--set", "transfer.units=data",
            "--set", "transfer.color=[[1, 1, 0, 0], [1.5, 1, 0, 0], [1.51, 0, 1, 0], [2.5, 0, 1, 0], [2.51, 0, 0, 1],"
                     " [3, 0, 0, 1]]",
            "--set", "shading.enabled=false", "--set", "render.classification=pre", "--size", "96", "-q"]   # pre: a
    # voxel keeps its own colour (post would give the blue marker red and green rims)
    with pytest.raises(SystemExit) as exc:
        main(["render", "ph.aug.h5", *opts, *extra, "-o", out])
    assert exc.value.code == 0
    return _marker_centres(tmp_path / out)


@pytest.mark.parametrize("cols", [ROTATED, MIRRORED, _nrrd, _dicom_series],
                         ids=["nifti-rotated", "nifti-mirrored", "nrrd", "dicom-sagittal"])
def test_default_render_is_anterior_superior_up(tmp_path, monkeypatch, cols):
    """A scan whose axes are not the patient's (a NIfTI with a rotated and with a mirrored affine, an NRRD with
    non-identity space directions, a sagittal DICOM series whose files are out of order), read by its own reader
    and rendered with the defaults: the anterior marker in the middle (nearest), superior above it, the patient's
    left on the image's right."""
    c = _render_phantom(tmp_path, monkeypatch, cols)
    mid = 47.5
    assert abs(c["A"][0] - mid) < 3 and abs(c["A"][1] - mid) < 3, c
    assert c["S"][1] < mid - 4 and abs(c["S"][0] - mid) < 3, c               # pixel y grows downwards
    assert c["L"][0] > mid + 4 and abs(c["L"][1] - mid) < 3, c
    # a named view turns from there: the patient's left side, anterior on the image's left, superior up
    c = _render_phantom(tmp_path, monkeypatch, cols, "--set", "camera.view=left", out="left.png")
    assert c["A"][0] < mid - 4 and c["S"][1] < mid - 4 and abs(c["L"][0] - mid) < 3, c
    # azimuth is relative to the view: 90 from anterior is the left view
    az = _render_phantom(tmp_path, monkeypatch, cols, "--set", "camera.azimuth=90", out="az.png")
    assert np.allclose(_flat(az), _flat(c), atol=0.5), (az, c)


def test_version_4_keeps_the_grid_convention(tmp_path, monkeypatch):
    """A scene that says version 4 renders in grid space, as before: the rotated phantom is not seen from the
    front; the same scene file without the version is."""
    c4 = _render_phantom(tmp_path, monkeypatch, ROTATED, "--set", "version=4", out="v4.png")
    c5 = _render_phantom(tmp_path, monkeypatch, ROTATED, out="v5.png")
    assert np.abs(_flat(c4) - _flat(c5)).max() > 4, (c4, c5)


def test_named_view_without_orientation_is_one_line(tmp_path, capsys):
    """Data without an orientation: the default keeps the grid convention; a named view is refused in one line
    naming isplat augment --orientation."""
    from conftest import write_volume
    from isplat.cli.main import main

    dens = np.zeros((8, 8, 8), np.uint8)
    dens[2:6, 2:6, 2:6] = 200
    aug, _ = write_volume(tmp_path, dens, name="v")
    base = [str(aug), "--set", "transfer.opacity=[[100, 0], [200, 1]]", "--size", "16", "-q"]
    with pytest.raises(SystemExit) as exc:
        main(["render", *base, "-o", str(tmp_path / "a.png")])
    assert exc.value.code == 0
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        main(["render", *base, "--set", "camera.view=left", "-o", str(tmp_path / "b.png")])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and "--orientation" in err[0], err
    assert not (tmp_path / "b.png").exists()


def test_api_render_of_a_path_is_anterior(tmp_path):
    """isplat.render(path) keeps the file's orientation as the command line does; the array alone has none."""
    import isplat

    p, vol = _nifti(tmp_path, ROTATED)
    kw = dict(opacity=[[0.5, 0], [0.6, 1], [3, 1]], window=(0.0, 3.0), shading=False, size=96,
              color=[[1, 1, 0, 0], [1.5, 1, 0, 0], [1.51, 0, 1, 0], [2.5, 0, 1, 0], [2.51, 0, 0, 1], [3, 0, 0, 1]],
              set=["render.classification=pre"])
    c = _marker_centres(isplat.render(str(p), **kw) * 255.0)
    mid = 47.5
    assert abs(c["A"][0] - mid) < 3 and c["S"][1] < mid - 4 and c["L"][0] > mid + 4, c
    c0 = _marker_centres(isplat.render(vol, spacing=read_volume(p).spacing_ijk, **kw) * 255.0)
    assert np.abs(_flat(c0) - _flat(c)).max() > 4, (c0, c)
