"""scripts/fetch_data.py without the network: extraction from archives made here, conversion, idempotence."""

import importlib.util
import io
import sys
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

from isplat.augfile import open_augmented
from isplat.index import open_index

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("fetch_data", ROOT / "scripts" / "fetch_data.py")
fd = importlib.util.module_from_spec(spec)
sys.modules["fetch_data"] = fd
spec.loader.exec_module(fd)


def test_sources_are_the_documented_ones():
    by = {s.name: s for s in fd.SOURCES}
    assert by["mri-head"].spec == "pydeface==2.1.0" and by["mri-head"].member.endswith("mean_reg2mean.nii.gz")
    assert by["concrete-ct"].spec == "spam==0.9.1" and by["concrete-ct"].member.endswith("x-ray-bin16.tif")
    assert by["mri-dicom"].registry == "npm" and by["mri-dicom"].member == "package/tests/data/volume/"


def test_extract_file_from_wheel_and_sdist(tmp_path):
    src = fd.Source("vol", "pypi", "x==1", "pkg/data/v.npy", ".npy", "test")
    arr = np.arange(24, dtype=np.int16).reshape(2, 3, 4)
    buf = io.BytesIO()
    np.save(buf, arr)
    whl = tmp_path / "pkg-1-py3-none-any.whl"
    with zipfile.ZipFile(whl, "w") as z:
        z.writestr("pkg/__init__.py", "")
        z.writestr("pkg/data/v.npy", buf.getvalue())
    out = fd.extract(whl, src, tmp_path / "a.npy")
    assert np.array_equal(np.load(out), arr) and not (tmp_path / "a.npy.part").exists()
    sdist = tmp_path / "pkg-1.tar.gz"                   # an sdist nests the member under pkg-1/src/
    with tarfile.open(sdist, "w:gz") as t:
        info = tarfile.TarInfo("pkg-1/src/pkg/data/v.npy")
        info.size = len(buf.getvalue())
        t.addfile(info, io.BytesIO(buf.getvalue()))
    assert np.array_equal(np.load(fd.extract(sdist, src, tmp_path / "b.npy")), arr)
    with pytest.raises(fd.FetchError, match="no member pkg/data/w.npy"):
        fd.extract(whl, fd.Source("vol", "pypi", "x==1", "pkg/data/w.npy", ".npy", "t"), tmp_path / "c.npy")


def test_extract_folder_from_npm_tarball(tmp_path):
    src = fd.Source("series", "npm", "x@1", "package/tests/data/volume/", "", "test")
    tgz = tmp_path / "x-1.tgz"
    with tarfile.open(tgz, "w:gz") as t:
        for name in ("package/tests/data/volume/a_001.dcm", "package/tests/data/volume/a_002.dcm",
                     "package/tests/data/other/z.dcm", "package/index.js"):
            data = name.encode()
            info = tarfile.TarInfo(name)
            info.size = len(data)
            t.addfile(info, io.BytesIO(data))
    out = fd.extract(tgz, src, tmp_path / "series")
    assert sorted(p.name for p in out.iterdir()) == ["a_001.dcm", "a_002.dcm"]
    assert (out / "a_002.dcm").read_text() == "package/tests/data/volume/a_002.dcm"


def test_convert_is_idempotent(tmp_path):
    rng = np.random.default_rng(0)
    vol = rng.integers(0, 1000, (5, 6, 7)).astype(np.uint16)
    raw = tmp_path / "v.npy"
    np.save(raw, vol)
    aug, idx = tmp_path / "v.aug.h5", tmp_path / "v.idx.h5"
    assert fd.convert(raw, aug, idx) == [aug, idx]
    a = open_augmented(aug)
    assert a.shape == (5, 6, 7) and open_index(idx).density_sha256 == a.density_sha256
    mtime = aug.stat().st_mtime_ns
    assert fd.convert(raw, aug, idx) == [] and aug.stat().st_mtime_ns == mtime


def test_convert_failure_is_one_line(tmp_path):
    bad = tmp_path / "bad.nii.gz"
    bad.write_bytes(b"not a nifti")
    with pytest.raises(fd.FetchError) as exc:
        fd.convert(bad, tmp_path / "b.aug.h5", tmp_path / "b.idx.h5")
    assert "bad.nii.gz" in str(exc.value) and "\n" not in str(exc.value)
    assert not (tmp_path / "b.aug.h5").exists()


def test_main_skips_what_is_there(tmp_path, capsys, monkeypatch):
    # with every output present nothing is downloaded and nothing is printed on stdout
    for s in fd.SOURCES:
        raw = tmp_path / (s.name + s.ext)
        raw.mkdir() if s.ext == "" else raw.write_bytes(b"")
        (tmp_path / f"{s.name}.aug.h5").write_bytes(b"")
        (tmp_path / f"{s.name}.idx.h5").write_bytes(b"")
    monkeypatch.setattr(fd, "download", lambda *a: pytest.fail("downloaded although present"))
    assert fd.main(["--out", str(tmp_path)]) == 0
    out, err = capsys.readouterr()
    assert out == "" and "exists, not downloading" in err


def test_download_failure_is_one_line(tmp_path, capsys, monkeypatch):
    def boom(src, tmp):
        raise fd.FetchError(f"{src.name}: pip download {src.spec} failed: no network")
    monkeypatch.setattr(fd, "download", boom)
    assert fd.main(["--out", str(tmp_path), "--only", "mri-head"]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.strip().splitlines()[-1].startswith("fetch_data: error: mri-head: pip download")
