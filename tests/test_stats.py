"""`isplat stats`: figures equal direct numpy counts; --json keys; empty transfer function; one-line errors."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from isplat.augfile import write_augmented
from isplat.cli.main import main
from isplat.index import build_index_file, open_index
from isplat.stats import collect, format_table

SHAPE = (6, 7, 9)          # (n_k, n_j, n_i)


def make_volume(folder, name="v", seed=0, shape=SHAPE):
    rng = np.random.default_rng(seed)
    d = rng.integers(0, 256, shape).astype(np.uint8)
    d[:, :, :2] = 0                                             # some air
    gm = rng.integers(0, 256, shape).astype(np.uint8)
    nrm = rng.integers(0, 65536, shape).astype(np.uint16)
    aug = folder / f"{name}.aug.h5"
    idx = folder / f"{name}.idx.h5"
    write_augmented(aug, d, gm, nrm, (1.0, 2.0, 0.5), (-100.0, 155.0), 0.25)
    build_index_file(aug, idx)
    return d, aug, idx


def write_scene(folder, opacity="[[100, 0.0], [120, 1.0], [160, 1.0], [170, 0.0]]", extra="", name="s.toml",
                aug="v.aug.h5", idx="v.idx.h5", method="indexed"):
    p = folder / name
    p.write_text(f"""version = 1
[data]
augmented = "{aug}"
index = "{idx}"
[image]
width = 32
height = 24
[transfer]
opacity = {opacity}
[render]
method = "{method}"
threads = 1
{extra}""")
    return p


def run(capsys, *args):
    with pytest.raises(SystemExit) as exc:
        main(["stats", *map(str, args)])
    cap = capsys.readouterr()
    return exc.value.code, cap.out, cap.err


@pytest.fixture
def vol(tmp_path):
    d, aug, idx = make_volume(tmp_path)
    return tmp_path, d, aug, idx


def test_volume_and_index_figures_equal_direct_counts(vol):
    folder, d, aug, idx = vol
    s = collect(aug, idx)
    n = d.size
    a = s["augmented"]
    assert a["shape_ijk"] == [9, 7, 6] and a["voxels"] == n
    assert a["spacing_ijk"] == [1.0, 2.0, 0.5] and a["density_window"] == [-100.0, 155.0]
    assert a["channel_bytes"] == {"density": n, "gradient_magnitude": n, "normal": 2 * n}
    assert a["bytes"] == 4 * n and a["file_bytes"] == aug.stat().st_size
    ix = s["index"]
    assert ix["axes"] == "ijk" and ix["voxels_indexed"] == n
    f = open_index(idx)
    # the index's bytes: tables (257 pointers, 16 B per entry, E + 1 offsets) plus blocks, per axis
    for ax in "ijk":
        info = f.axis_info(ax)
        want = 257 * 8 + info["n_entries"] * 16 + 8 + info["n_bytes"]
        pa = ix["per_axis"][ax]
        assert pa["bytes"] == want and pa["voxels"] == n
        assert pa["entries"] == sum(np.unique(sl).size for sl in _slices(d, ax))   # one block per (slice, density)
        assert pa["bytes_per_voxel"] == pytest.approx(want / n)
    assert ix["bytes"] == sum(ix["per_axis"][a]["bytes"] for a in "ijk")
    assert ix["bytes_per_voxel"] == pytest.approx(ix["bytes"] / (3 * n))
    assert ix["per_density_range"][0]["densities"] == [0, 255] and ix["per_density_range"][0]["voxels"] == n


def test_pre_reads_no_brick_range_table(tmp_path):
    """Pre with a values file reads nothing from the augmented file but its opening, and the opening no longer
    reads ``/brick_range`` (issue 26: 29 KB of the engine's pre reads): ``augmented_file_bytes_read`` is the opening's
    bytes, fewer by the table's stored bytes than an opening that reads it; post reads it (its density bricks)."""
    import h5py

    from isplat.augfile import open_augmented

    _, aug, idx = make_volume(tmp_path, shape=(48, 56, 64))
    a = open_augmented(aug)
    opening = a.io.bytes
    with h5py.File(aug, "r") as f:
        stored = f["brick_range"].id.get_storage_size()
    assert a.brick_range.shape == (6, 7, 8, 2) and a.io.bytes - opening >= stored      # read when asked for
    ld = collect(aug, idx, scene=write_scene(tmp_path))["scene"]["loaded"]
    assert ld["values_from"] == "values file" and ld["augmented_bytes"] == 0
    assert ld["augmented_file_bytes_read"] == opening
    scene = write_scene(tmp_path, name="p.toml", extra='classification = "post"')
    scene.write_text(scene.read_text().replace("version = 1", "version = 4", 1))
    post = collect(aug, idx, scene=scene)
    assert post["scene"]["classification"] == "post"
    assert post["scene"]["loaded"]["augmented_file_bytes_read"] >= opening + stored + post["scene"]["loaded"][
        "augmented_bytes"]


def _slices(d, ax):
    n = {"k": d.shape[0], "j": d.shape[1], "i": d.shape[2]}[ax]
    take = {"k": lambda s: d[s], "j": lambda s: d[:, s], "i": lambda s: d[:, :, s]}[ax]
    return [take(s) for s in range(n)]


@pytest.mark.parametrize("with_index", [True, False])
def test_spatial_ratio_equals_numpy(vol, with_index):
    folder, d, aug, idx = vol
    scene = write_scene(folder, method="indexed" if with_index else "full")
    s = collect(aug, idx if with_index else None, scene=scene)
    if not with_index:                         # the scene names the index: it is still reported
        assert s["index"] is not None
    sc = s["scene"]
    want = int(((d >= 101) & (d <= 169)).sum())       # opacity > 0 strictly between 100 and 170
    assert sc["intervals"] == [[101, 169]]
    assert sc["voxels_of_interest"] == want and sc["spatial_ratio"] == pytest.approx(want / d.size)
    assert sc["ratio_source"] == "index"
    lo, hi = sc["intervals_input_units"][0]
    assert lo == pytest.approx(-100 + 101) and hi == pytest.approx(-100 + 169)
    ld = sc["loaded"]
    if with_index:
        assert sc["voxels_examined"] == want           # the indexed method visits exactly those voxels
        assert ld["channels"] == ["normal"] and ld["augmented_bytes"] == 0 and ld["values_from"] == "values file"
        assert ld["values_bytes"] == 2 * want + 257 * 8 and ld["index_decoded_bytes"] > 4 * want
        assert ld["bytes_needed"] == ld["index_bytes"] + ld["values_bytes"]   # blocks, tables, 2 B per normal
        assert ld["file_bytes_read"] == ld["augmented_file_bytes_read"] + ld["index_file_bytes_read"] + \
            ld["values_file_bytes_read"]
        assert ld["read_ratio"] == pytest.approx(ld["file_bytes_read"] / ld["bytes_needed"])
    else:
        assert sc["voxels_examined"] == d.size         # the full method visits every voxel
        assert ld["augmented_bytes"] == 3 * d.size and ld["index_bytes"] == 0
        assert ld["bytes_needed"] == 3 * want and ld["values_from"] == "whole channels"
        assert ld["file_bytes_read"] > ld["augmented_bytes"]          # chunk checksums and metadata
    drawn, other = ("samples", "voxels_splatted") if sc["classification"] == "post" else ("voxels_splatted",
                                                                                         "samples")
    assert 0 < sc[drawn] and sc[other] == 0                 # each counter counts its own technique's work
    assert sc["voxels_splatted"] <= want
    assert ld["bytes"] == ld["augmented_bytes"] + ld["index_bytes"] + ld["values_bytes"]
    assert ld["augmented_fraction"] == pytest.approx(ld["augmented_bytes"] / (4 * d.size))
    assert ld["held_bytes_per_voxel_of_interest"] == pytest.approx(ld["held_bytes"] / want)


def test_ratio_counts_density_without_index(tmp_path):
    d, aug, idx = make_volume(tmp_path)
    idx.unlink()
    scene = write_scene(tmp_path, method="full", extra="", idx="v.idx.h5")
    text = scene.read_text().replace('index = "v.idx.h5"\n', "")
    scene.write_text(text)
    s = collect(aug, scene=scene)
    assert s["index"] is None and s["scene"]["ratio_source"] == "augmented density"
    assert s["scene"]["voxels_of_interest"] == int(((d >= 101) & (d <= 169)).sum())


def test_partial_index_falls_back_to_density_counts(tmp_path):
    d, aug, idx = make_volume(tmp_path)
    build_index_file(aug, idx, ranges=[(150, 255)], force=True)
    scene = write_scene(tmp_path, method="full")
    s = collect(aug, idx, scene=scene)
    assert s["scene"]["ratio_source"] == "augmented density"
    assert s["scene"]["voxels_of_interest"] == int(((d >= 101) & (d <= 169)).sum())
    assert s["index"]["per_density_range"][0]["voxels"] == int((d >= 150).sum())


def test_json_keys(vol, capsys):
    folder, d, aug, idx = vol
    scene = write_scene(folder)
    code, out, err = run(capsys, aug, idx, "--scene", scene, "--json", "-q")
    assert code == 0 and err == ""
    s = json.loads(out)
    assert out.count("\n") == 1
    assert set(s) == {"stats_version", "augmented", "index", "scene"}
    assert {"path", "file_bytes", "shape_ijk", "voxels", "spacing_ijk", "density_window", "density_step",
            "gradient_magnitude_scale", "density_sha256", "source", "source_format", "axes_lps", "channel_bytes",
            "bytes", "bytes_per_voxel"} == set(s["augmented"])
    assert {"path", "file_bytes", "file_bytes_per_voxel", "axes", "density_ranges", "voxels_indexed", "bytes",
            "bytes_per_voxel", "bytes_per_volume_voxel", "decoded_bytes", "per_axis", "per_density_range",
            "format_version", "values", "runs"} == set(s["index"])
    assert s["index"]["format_version"] == 7
    vpath = Path(str(idx).replace(".idx.h5", ".values.idx.h5"))
    assert s["index"]["file_bytes_per_voxel"] == pytest.approx(os.path.getsize(idx) / (3 * d.size))
    assert s["index"]["values"] == {"in": "values file", "path": str(vpath), "voxels": d.size,
                                    "bytes": 257 * 8 + 3 * d.size, "file_bytes": os.path.getsize(vpath)}
    assert {"bytes", "block_bytes", "entries", "voxels", "escape_width", "bytes_per_voxel",
            "block_bytes_per_voxel", "decoded_bytes"} == set(s["index"]["per_axis"]["k"])
    assert {"path", "view", "method", "projection", "image", "intervals", "intervals_input_units", "ratio_source",
            "voxels_of_interest", "spatial_ratio", "axis", "slices", "voxels_examined", "classification",
            "voxels_splatted", "splatted_ratio", "samples", "render_seconds", "loaded", "labels"} == set(s["scene"])
    assert {"channels", "axes", "augmented_bytes", "index_bytes", "bytes", "index_decoded_bytes", "held_bytes",
            "augmented_fraction", "index_fraction", "files_bytes", "files_fraction", "values_from",
            "augmented_file_bytes_read", "index_file_bytes_read", "file_bytes_read", "bytes_needed", "read_ratio",
            "values_bytes", "values_file_bytes_read", "runs_file_bytes_read", "runs_path", "file_pages_read",
            "page_ratio",
            "held_bytes_per_voxel_of_interest", "technique", "needed_voxels", "needed_axis",
            "channel_bytes_per_voxel", "channel_bytes_needed", "index_bytes_needed"} == set(s["scene"]["loaded"])
    assert s["stats_version"] == 9
    # the table carries the same figures
    code, table, _ = run(capsys, aug, idx, "--scene", scene, "-q")
    assert code == 0 and f"{s['scene']['voxels_of_interest']:,}" in table and "spatial ratio" in table
    assert format_table(s) == table


def test_set_override_and_no_scene_json(vol, capsys):
    folder, d, aug, idx = vol
    scene = write_scene(folder)
    code, out, _ = run(capsys, aug, idx, "--scene", scene, "--set", "transfer.opacity=[[200,0],[210,1],[255,1]]",
                       "--json", "-q")
    assert code == 0 and json.loads(out)["scene"]["voxels_of_interest"] == int((d >= 201).sum())
    code, out, _ = run(capsys, aug, "--json")
    s = json.loads(out)
    assert code == 0 and s["index"] is None and s["scene"] is None


def test_transfer_function_selecting_nothing(vol, capsys):
    folder, d, aug, idx = vol
    scene = write_scene(folder, opacity="[[120, 0.0]]")
    code, out, err = run(capsys, aug, idx, "--scene", scene, "--json", "-q")
    assert code == 0, err
    sc = json.loads(out)["scene"]
    assert sc["intervals"] == [] and sc["voxels_of_interest"] == 0 and sc["spatial_ratio"] == 0
    assert sc["voxels_examined"] == 0 and sc["voxels_splatted"] == sc["samples"] == 0
    assert sc["loaded"]["index_bytes"] >= 0
    assert sc["loaded"]["augmented_bytes"] == 0
    code, out, _ = run(capsys, aug, idx, "--scene", scene, "-q")
    assert code == 0 and "selects nothing" in out


def test_index_from_command_line_fills_scene_without_one(vol, capsys):
    folder, d, aug, idx = vol
    scene = write_scene(folder, method="indexed")
    scene.write_text(scene.read_text().replace('index = "v.idx.h5"\n', ""))
    # without IDX, the index beside AUG.h5 (the same stem) is taken
    code, out, err = run(capsys, aug, "--scene", scene, "--json", "-q")
    assert code == 0, err
    assert json.loads(out)["scene"]["method"] == "indexed" and json.loads(out)["index"] is not None
    # without IDX and none beside AUG.h5, an indexed scene without an index is refused by the scene reader
    moved = idx.rename(folder / "elsewhere.idx.h5")
    code, _, err = run(capsys, aug, "--scene", scene, "-q")
    assert code == 2 and err.count("\n") == 1 and "data.index" in err
    code, out, err = run(capsys, aug, moved, "--scene", scene, "--json", "-q")
    assert code == 0, err
    assert json.loads(out)["scene"]["method"] == "indexed"


def one_error(code, out, err, *words):
    assert code != 0 and out == ""
    assert err.startswith("isplat: error: ") and err.count("\n") == 1, err
    for w in words:
        assert w in err, err


def test_bad_input(vol, capsys):
    folder, d, aug, idx = vol
    one_error(*run(capsys, folder / "missing.aug.h5"), "missing.aug.h5")
    one_error(*run(capsys, aug, folder / "missing.idx.h5"), "missing.idx.h5")
    other = folder / "other"
    other.mkdir()
    _, oaug, oidx = make_volume(other, seed=1)
    one_error(*run(capsys, aug, oidx), "another volume")
    one_error(*run(capsys, idx), "format")                       # an index given as the augmented file
    one_error(*run(capsys, aug, idx, "--scene", folder / "nope.toml"), "nope.toml")
    # the scene names another volume's index, and no IDX.h5 is given: it is checked against AUG.h5
    scene = write_scene(folder, name="oi.toml", idx="other/v.idx.h5")
    (folder / "v.idx.h5").rename(folder / "kept.idx.h5")
    one_error(*run(capsys, aug, "--scene", scene, "-q"), "another volume", "isplat index")
    (folder / "kept.idx.h5").rename(folder / "v.idx.h5")
    one_error(*run(capsys, aug, idx, "--set", "camera.azimuth=3"), "--scene")
    one_error(*run(capsys, aug, idx, "--scene", write_scene(folder), "--view", "3", "-q"), "--view")
    bad = write_scene(folder, name="bad.toml", opacity="[[100, 2.0]]")
    one_error(*run(capsys, aug, idx, "--scene", bad, "-q"), "bad.toml", "opacity")


def test_runs_file_beside_the_index(vol, capsys):
    """The runs file beside the index (formats/runs.md): its path, size, runs and voxels, tied to AUG.h5, in the
    JSON and the table; none beside: null, and the table says how to write it (stats_version 9)."""
    import h5py

    from isplat.runsfile import build_runs_file, runs_path

    folder, d, aug, idx = vol
    code, out, err = run(capsys, aug, idx, "--json")
    assert code == 0 and json.loads(out)["index"]["runs"] is None
    code, out, _ = run(capsys, aug, idx)
    assert "runs file" in out and "isplat index --no-runs" in out
    rp = build_runs_file(aug, idx)
    code, out, err = run(capsys, aug, idx, "--json")
    assert code == 0, err
    r = json.loads(out)["index"]["runs"]
    with h5py.File(rp, "r") as f:
        ptr = f["runs/run_voxel_ptr"][()]
        bins = [len(f.attrs["lo_first"]), len(f.attrs["hi_first"])]
    assert r == {"path": str(rp), "file_bytes": os.path.getsize(rp), "format_version": 2, "runs": len(ptr) - 1,
                 "runs_with_voxels": int(np.count_nonzero(np.diff(ptr))), "bins": bins, "voxels": d.size,
                 "tied": True}
    assert r["path"] == str(runs_path(idx))
    code, out, _ = run(capsys, aug, idx)
    assert code == 0 and f"{rp}: " in out and f"{r['runs']} runs" in out and "tied to this augmented file" in out


@pytest.mark.parametrize("what", ["edited", "other volume", "truncated", "folder"])
def test_bad_runs_file_is_one_line(vol, capsys, what):
    """A runs file that a render would refuse is refused by stats too, with one line naming it and the command
    that rebuilds it; stats checks every chunk (a normal no figure reads, edited through HDF5)."""
    import h5py

    from isplat.runsfile import build_runs_file, runs_path

    folder, d, aug, idx = vol
    rp = runs_path(idx)
    if what == "other volume":
        other = folder / "other"
        other.mkdir()
        _, oaug, oidx = make_volume(other, seed=1)
        build_runs_file(oaug, idx)
    elif what == "folder":
        rp.mkdir()
    else:
        build_runs_file(aug, idx)
        if what == "truncated":
            rp.write_bytes(rp.read_bytes()[:1000])
        else:
            with h5py.File(rp, "r+") as f:
                f["runs/normal"][-1] = (int(f["runs/normal"][-1]) + 1) % 65536
    word = {"edited": "'runs/normal', chunk at (", "other volume": "another volume", "truncated": "truncated",
            "folder": "folder"}[what]
    one_error(*run(capsys, aug, idx, "--json"), str(rp), word, f"isplat index {aug} -o {idx} --force")


def test_scene_applied_to_the_command_line_files(vol, capsys):
    """The files on the command line are the ones described, whatever the scene's [data] names (issue 28): a
    scene in data units naming a file that does not exist, and one naming another volume."""
    folder, d, aug, idx = vol
    other = folder / "other"
    other.mkdir()
    make_volume(other, seed=1)
    own = json.loads(run(capsys, aug, idx, "--scene", write_scene(folder), "--json", "-q")[1])["scene"]
    for name, scene_aug in (("gone.toml", "gone.aug.h5"), ("o.toml", "other/v.aug.h5")):
        # the same transfer function in data units (window -100..155: code c is value c - 100), version 2
        scene = write_scene(folder, name=name, aug=scene_aug, idx=scene_aug.replace(".aug.", ".idx."),
                            opacity="[[0, 0.0], [20, 1.0], [60, 1.0], [70, 0.0]]")
        scene.write_text(scene.read_text().replace("version = 1", "version = 2").replace(
            "[render]", 'units = "data"\n[render]'))
        for args in ((aug, idx), (aug,)):                 # IDX.h5 given, or the one beside AUG.h5
            code, out, err = run(capsys, *args, "--scene", scene, "--json", "-q")
            assert code == 0, err
            got = json.loads(out)["scene"]
            assert got["spatial_ratio"] == own["spatial_ratio"] and got["method"] == "indexed"
            assert got["voxels_examined"] == own["voxels_examined"]


# --- the density histogram (--histogram, --plot) ----------------------------------------------------------------

def _scan_file(folder, seed, window=(-50.0, 400.0), hu=True):
    """A float scan with values below, inside and above the window, augmented; returns (values, path)."""
    from isplat.augment import augment_array

    rng = np.random.default_rng(seed)
    x = rng.normal(150, 120, (5, 6, 7)).astype(np.float64)
    a = augment_array(x, (1, 1, 1), window)
    p = folder / f"h{seed}.aug.h5"
    extra = {"density_units": "HU"} if hu else {}
    extra["density_clipped_fraction"] = np.asarray(a["clipped"], dtype="<f8")
    write_augmented(p, a["density"], a["gradient_magnitude"], a["normal"], a["spacing_ijk"], a["density_window"],
                    a["gradient_magnitude_scale"], extra)
    return x, a, p


@pytest.mark.parametrize("seed,bins", [(0, 256), (1, 32), (2, 16), (3, 1)])
def test_histogram_counts_equal_numpy(tmp_path, seed, bins):
    from isplat.augfile import open_augmented
    from isplat.stats import histogram_section

    x, a, p = _scan_file(tmp_path, seed)
    h = histogram_section(open_augmented(p), bins)
    assert h["code_counts"] == np.bincount(a["density"].ravel(), minlength=256).tolist()
    lo, hi = a["density_window"]
    # in data units: numpy's histogram of the values (clipped to the window as the density is) over the edges
    counts, _ = np.histogram(np.clip(x, lo, hi), bins=np.asarray(h["edges"]))
    assert h["counts"] == counts.tolist() and h["voxels"] == x.size
    assert h["edges"][0] == pytest.approx(lo - 0.5 * (hi - lo) / 255)
    assert h["clipped_fraction"] == pytest.approx([np.mean(x < lo), np.mean(x > hi)])
    # percentiles: numpy's inverted-CDF percentiles of the codes' data values
    values = lo + a["density"].astype(np.float64) * ((hi - lo) / 255)
    for q in (1, 5, 25, 50, 75, 95, 99):
        assert h["percentiles"][f"p{q}"] == pytest.approx(np.percentile(values, q, method="inverted_cdf"))


def test_histogram_cli_text_json_and_plot(capsys, tmp_path):
    x, a, p = _scan_file(tmp_path, 4)
    code, out, err = run(capsys, p, "--histogram", "--bins", "8")
    assert code == 0, err
    text = out.split("density histogram (HU; window -50 .. 400, 8 bins of 32 density codes")[1]
    assert len([ln for ln in text.splitlines() if "%" in ln and ".." in ln]) == 8 and "percentiles: p1" in text
    code, out, _ = run(capsys, p, "--histogram", "--json")
    assert code == 0 and sum(json.loads(out)["histogram"]["counts"]) == x.size
    code, out, _ = run(capsys, p, "--json")
    assert "histogram" not in json.loads(out)
    code, _, err = run(capsys, p, "--histogram", "--bins", "3")
    assert code == 2 and err.count("\n") == 1 and "--bins 3 invalid" in err
    pytest.importorskip("matplotlib")
    png = tmp_path / "h.png"
    code, _, err = run(capsys, p, "--plot", png, "-q")
    assert code == 0 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    code, _, err = run(capsys, p, "--plot", png)
    assert code == 2 and "--force" in err and err.count("\n") == 1
    code, _, err = run(capsys, p, "--plot", tmp_path / "h.xyz")
    assert code == 2 and "--plot writes" in err and not (tmp_path / "h.xyz").exists()


def test_plot_ramps_fit_the_data(tmp_path):
    from isplat.augfile import open_augmented
    from isplat.stats import histogram_section, preset_ramps

    _, _, p = _scan_file(tmp_path, 5, hu=True)
    assert "ct-bone" in preset_ramps(histogram_section(open_augmented(p))) and \
        "mri-t1-head" not in preset_ramps(histogram_section(open_augmented(p)))
    _, _, q = _scan_file(tmp_path, 6, window=(0.0, 1000.0), hu=False)
    ramps = preset_ramps(histogram_section(open_augmented(q)))
    assert set(ramps) == {"mri-t1-head", "micro-ct"}
    assert ramps["micro-ct"][0][0] == pytest.approx(250.0)          # 0.25 of the window 0..1000
    # the MRI preset drawn where a scene places it: its first point at the start of the histogram's tissue range
    h = histogram_section(open_augmented(q))
    assert ramps["mri-t1-head"][0][0] == pytest.approx(h["tissue_range"][0])
    assert ramps["mri-t1-head"][0][-1] == pytest.approx(h["tissue_range"][1])


def test_plot_without_matplotlib_is_one_line(capsys, tmp_path, monkeypatch):
    import builtins

    _, _, p = _scan_file(tmp_path, 7)
    real = builtins.__import__

    def fake(name, *args, **kw):
        if name == "matplotlib" or name.startswith("matplotlib."):
            raise ImportError(name)
        return real(name, *args, **kw)

    monkeypatch.setattr(builtins, "__import__", fake)
    code, _, err = run(capsys, p, "--plot", tmp_path / "h.png")
    assert code == 2 and err.strip() == f"isplat: error: {tmp_path / 'h.png'}: --plot needs matplotlib: " \
                                         "pip install 'isplat[plot]'"
    assert not (tmp_path / "h.png").exists()


@pytest.mark.parametrize("shaded", [True, False])
def test_post_bytes_needed_are_the_quads_footprint(vol, capsys, shaded):
    """Post: the voxels its quads read on the view's axis (tests/test_needed.py's reference) x density, normal
    and gradient magnitude (shaded) or density alone; labelled by technique in the table and the JSON."""
    from test_needed import reference_footprint

    folder, d, aug, idx = vol
    extra = 'classification = "post"\n' + ("" if shaded else "[shading]\nenabled = false\n")
    scene = write_scene(folder, extra=extra)
    scene.write_text(scene.read_text().replace("version = 1", "version = 4"))
    s = collect(aug, idx, scene=scene)
    ld = s["scene"]["loaded"]
    axis = s["scene"]["axis"][1]
    want = int(reference_footprint(d, [(101, 169)], axis).sum())
    assert ld["technique"] == "post" and ld["needed_axis"] == axis and ld["needed_voxels"] == want
    assert ld["channel_bytes_per_voxel"] == (4 if shaded else 1)
    assert ld["bytes_needed"] == want * ld["channel_bytes_per_voxel"] + ld["index_bytes_needed"]
    assert ld["read_ratio"] == pytest.approx(ld["file_bytes_read"] / ld["bytes_needed"])
    code, table, _ = run(capsys, aug, idx, "--scene", scene, "-q")
    assert code == 0 and "bytes needed (post)" in table and "read / needed (post)" in table
