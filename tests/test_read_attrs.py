"""isplat.fileio.ReadAttrs: an HDF5 object's attributes read once each, answering the checks' questions as h5py's
AttributeManager does (the openers of the augmented, index, values and runs files check through it)."""

import h5py
import numpy as np
import pytest

from isplat.errors import IsplatError
from isplat.fileio import ReadAttrs, attr_array, attr_string, attr_values, check_string_attrs, h5_type_name


@pytest.fixture()
def attrs(tmp_path):
    with h5py.File(tmp_path / "a.h5", "w") as f:
        f.attrs["shape"] = np.asarray([3, 4, 5], dtype="<i8")
        f.attrs["big"] = np.asarray(7, dtype=">i8")
        f.attrs.create("text", "héllo".encode("utf-8"), dtype=h5py.string_dtype("utf-8", 6))
        f.attrs["vlen"] = "variable"
        f.attrs["scale"] = np.float64(0.5)
    f = h5py.File(tmp_path / "a.h5", "r")
    yield f.attrs
    f.close()


def test_read_attrs_answers_as_h5py_does(attrs):
    a = ReadAttrs(attrs)
    assert list(a) == list(attrs) and a.keys() == list(attrs.keys())
    assert ("shape" in a, "missing" in a) == (True, False)
    assert a.get("missing") is None and a.get("missing", 3) == 3
    for k, v in attrs.items():
        assert np.array_equal(np.asarray(a[k]), np.asarray(v)) and np.asarray(a[k]).dtype == np.asarray(v).dtype
        assert h5_type_name(a, k) == h5_type_name(attrs, k)
        assert attr_string(a, k) == attr_string(attrs, k)
    assert [k for k, _ in a.items()] == list(attrs.keys())
    assert attr_values(a).keys() == attr_values(attrs).keys()
    with pytest.raises(KeyError):
        a["missing"]


def test_h5_type_name_names_numbers_by_their_stored_type_and_other_classes_by_class(attrs):
    assert [h5_type_name(attrs, k) for k in ("shape", "big", "scale")] == [
        "H5T_STD_I64LE", "H5T_STD_I64BE", "H5T_IEEE_F64LE"]
    assert h5_type_name(attrs, "text") == h5_type_name(attrs, "vlen") == \
        f"an HDF5 type of class {h5py.h5t.STRING}"        # (a string has no byte order: named, not raised)


def test_read_attrs_refuses_as_h5py_does(attrs):
    a = ReadAttrs(attrs)
    for src in (attrs, a):
        assert attr_array("f", src, "shape", "i", (3,)).tolist() == [3, 4, 5]
        with pytest.raises(IsplatError, match="stored as H5T_STD_I64BE"):
            attr_array("f", src, "big", "i")
        with pytest.raises(IsplatError, match="variable-length"):
            check_string_attrs("f", src, ("vlen",))
        with pytest.raises(IsplatError, match="missing attribute 'nope'"):
            check_string_attrs("f", src, ("nope",))
        check_string_attrs("f", src, ("text",))


def test_read_attrs_reads_each_attribute_once(attrs, monkeypatch):
    a = ReadAttrs(attrs)
    seen = []
    real = type(attrs).__getitem__
    monkeypatch.setattr(type(attrs), "__getitem__", lambda self, k: seen.append(k) or real(self, k))
    for _ in range(3):
        check_string_attrs("f", a, ("text",))
        attr_string(a, "text")
        attr_array("f", a, "shape", "i", (3,))
    assert sorted(seen) == ["shape", "text"]
