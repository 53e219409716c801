"""`isplat augment` and `isplat sample` from the command line: outputs, and one stderr line per bad input."""

import numpy as np
import pytest
from click.testing import CliRunner

from isplat.augfile import open_augmented
from isplat.cli.main import cli, main


def run(capsys, *argv):
    """Run ``isplat argv`` in-process through main(); return (exit code, stdout, stderr)."""
    with pytest.raises(SystemExit) as e:
        main(list(argv))
    out, err = capsys.readouterr()
    return e.value.code, out, err


@pytest.fixture
def head(tmp_path):
    from isplat.samples import make_sample

    x, _ = make_sample("head", (24, 20, 16))
    p = tmp_path / "in" / "head.npy"
    p.parent.mkdir()
    np.save(p, x)
    return p, x


def _one_error(code, err, *needles):
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("isplat: error: ")
    assert "Traceback" not in err
    for n in needles:
        assert n in lines[0], (n, lines[0])


def test_augment_npy_and_force(capsys, tmp_path, head):
    p, x = head
    out = tmp_path / "o.aug.h5"
    code, so, se = run(capsys, "augment", str(p), "-o", str(out), "--spacing", "0.5,0.5,2", "-q")
    assert code == 0 and so == "" and se == ""
    aug = open_augmented(out)
    assert aug.shape == x.shape and aug.spacing_ijk == (0.5, 0.5, 2.0)
    code, _, se = run(capsys, "augment", str(p), "-o", str(out))
    _one_error(code, se, str(out), "--force")
    code, _, _ = run(capsys, "augment", str(p), "-o", str(out), "--force", "--window=-100,3000", "-q")
    assert code == 0 and open_augmented(out).density_window == (-100.0, 3000.0)


def test_augment_raw_stdin_with_cli_runner(tmp_path):
    x = (np.arange(5 * 6 * 7) % 50).reshape(7, 6, 5).astype(">i2")
    out = tmp_path / "s.aug.h5"
    r = CliRunner().invoke(cli, ["augment", "-", "-o", str(out), "--shape", "5,6,7", "--dtype", "int16",
                                 "--byte-order", "big", "--window", "0,49", "-q"], input=x.tobytes())
    assert r.exit_code == 0, r.output
    d = open_augmented(out).read("density")
    assert np.array_equal(d, np.rint(x.astype(float) * 255 / 49).astype(np.uint8))


def test_sample_formats_round_trip(capsys, tmp_path):
    for ext in ("npy", "nrrd", "raw"):
        f = tmp_path / f"c.{ext}"
        code, so, se = run(capsys, "sample", "two-density-cube", "-o", str(f), "--shape", "8,6,4", "-q")
        assert code == 0 and se == ""
        cmd = so.strip().split()
        assert cmd[:3] == ["isplat", "augment", str(f)]
        code, _, se = run(capsys, *cmd[1:], "-q")
        assert code == 0, se
        aug = open_augmented(tmp_path / "c.aug.h5")
        assert aug.shape == (4, 6, 8)
        assert sorted(np.unique(aug.read("density"))) == [0, 127, 255]  # 100 * (255 / 200) rounds down
        (tmp_path / "c.aug.h5").unlink()
    code, so, _ = run(capsys, "sample", "head", "-o", str(tmp_path / "h.nrrd"), "--shape", "8,8,8", "-q")
    import nrrd

    data, hdr = nrrd.read(str(tmp_path / "h.nrrd"), index_order="C")
    assert data.dtype == np.uint16 and data.shape == (8, 8, 8) and np.allclose(np.diag(hdr["space directions"]), 1)
    assert hdr["space"] == "left-posterior-superior"


@pytest.mark.parametrize("ext", ["npy", "nrrd", "raw"])
def test_clinical_samples_carry_lps(capsys, tmp_path, ext):
    f = tmp_path / f"ct.{ext}"
    code, so, _ = run(capsys, "sample", "ct-head", "-o", str(f), "--shape", "12,10,8", "-q")
    assert code == 0 and ("--orientation LPS" in so) == (ext != "nrrd")
    code, _, se = run(capsys, *so.split()[1:])
    assert code == 0, se
    assert "orientation LPS" in se and "i, j, k point to the patient's left, posterior, superior" in se
    assert open_augmented(tmp_path / "ct.aug.h5").axes_lps.tolist() == np.eye(3).tolist()


def test_npy_without_orientation_says_so_once(capsys, tmp_path, head):
    code, _, se = run(capsys, "augment", str(head[0]), "-o", str(tmp_path / "o.aug.h5"))
    assert code == 0 and se.count("no orientation in npy input") == 1
    code, _, se = run(capsys, "augment", str(head[0]), "-o", str(tmp_path / "p.aug.h5"), "--orientation", "LPX")
    _one_error(code, se, "--orientation 'LPX' invalid")


def _bad_cases(tmp_path, head):
    p, x = head
    raw = tmp_path / "in" / "v.raw"
    raw.write_bytes(np.zeros(60, np.uint16).tobytes())
    flat = tmp_path / "in" / "flat.npy"
    np.save(flat, np.zeros((4, 5), np.float32))
    nan = tmp_path / "in" / "nan.npy"
    a = np.ones((3, 4, 5), np.float32)
    a[1, 2, 3] = np.nan
    np.save(nan, a)
    inf = tmp_path / "in" / "inf.npy"
    a[1, 2, 3] = -np.inf
    np.save(inf, a)
    const = tmp_path / "in" / "const.npy"
    np.save(const, np.full((3, 4, 5), 7, np.uint8))
    trunc = tmp_path / "in" / "trunc.npy"
    trunc.write_bytes(p.read_bytes()[:500])
    hdf = tmp_path / "in" / "t.nrrd"
    hdf.write_bytes(b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 4 4\nencoding: raw\n\n" + b"\0" * 10)
    unread = tmp_path / "in" / "unreadable.npy"
    np.save(unread, x)
    unread.chmod(0)
    return [
        (["missing.npy"], ["missing.npy", "does not exist"]),
        ([str(raw), "--shape", "5,4,4", "--dtype", "uint16"], ["120 bytes", "160 bytes"]),
        ([str(raw), "--shape", "5,4,3", "--dtype", "uint12"], ["uint12", "uint8"]),
        ([str(flat)], ["2 dimension"]),
        ([str(nan)], ["value nan", "i=3, j=2, k=1"]),
        ([str(inf), "--window", "0,1"], ["value -inf"]),
        ([str(const)], ["constant volume", "--window"]),
        ([str(trunc)], ["trunc.npy", "truncated"]),
        ([str(hdf)], ["t.nrrd", "NRRD"]),
        ([str(p), "--window", "5,5"], ["--window"]),
        ([str(p), "--spacing", "1,2"], ["--spacing"]),
        ([str(p), "--shape", "24,20,16"], ["needs --shape NI,NJ,NK and --dtype"]),
    ] + ([] if _root() else [([str(unread)], ["not readable"])])


def _root():
    import os

    return hasattr(os, "geteuid") and os.geteuid() == 0


def test_bad_inputs_one_line_and_no_output(capsys, tmp_path, head):
    outdir = tmp_path / "out"
    outdir.mkdir()
    for args, needles in _bad_cases(tmp_path, head):
        code, so, se = run(capsys, "augment", *args, "-o", str(outdir / "o.aug.h5"))
        _one_error(code, se, *needles)
        assert list(outdir.iterdir()) == [], args


def test_missing_output_folder(capsys, tmp_path, head):
    code, _, se = run(capsys, "augment", str(head[0]), "-o", str(tmp_path / "nope" / "o.aug.h5"))
    _one_error(code, se, "output folder", "does not exist")
    code, _, se = run(capsys, "sample", "sphere", "-o", str(tmp_path / "nope" / "s.npy"))
    _one_error(code, se, "does not exist")
    code, _, se = run(capsys, "sample", "sphere", "-o", str(tmp_path / "s.png"))
    _one_error(code, se, ".npy, .nrrd or .raw")


def test_help_texts_have_examples():
    r = CliRunner()
    for cmd in (["--help"], ["augment", "--help"], ["sample", "--help"]):
        res = r.invoke(cli, cmd)
        assert res.exit_code == 0 and "isplat augment" in res.output
    h = r.invoke(cli, ["augment", "--help"]).output
    for opt in ("--window", "--spacing", "--shape", "--dtype", "--byte-order", "--header-bytes", "--force", "-q"):
        assert opt in h
