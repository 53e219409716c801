"""Index benchmark: build time, index size per indexed voxel, load efficiency and peak memory (paper §2.3, §4).

``python -m benchmarks index [--quick]`` writes ``index-performance.md``.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from . import _doc

TECHNIQUES = []     # render.classification of its rows (the page's stamp)
SOURCES = _doc.sources(("isplat/index/**", "isplat/augfile.py", "isplat/fileio.py", "isplat/augment.py",
                        "isplat/runs.py", "isplat/runsfile.py"),     # (`isplat index` writes the runs file too)
                       _doc.SAMPLES, ("benchmarks/index.py",))


# density ranges of the augmented `head` sample (default window 0..2327 -> 0..255): air 0-1 with its noise
# tail 2-111, CSF/eyes/brain/lesion 112-118, soft tissue 119-123 (1100 -> 120.5; the sample does not
# separate skin from muscle), partial-volume ramp soft/brain-to-bone 124-239, bone 240-242 (2200 -> 241),
# teeth 255 (2600, clipped)
MATERIALS = ("CSF", "EYE", "BRAIN", "SOFT", "BONE", "TOOTH")


def _material_densities(window) -> dict[str, int]:
    """Density code of each material of the head sample under ``window`` (formats/augmented.md §4)."""
    from isplat import samples

    lo, hi = window
    return {m: int(min(255, round((getattr(samples, m) - lo) * 255.0 / (hi - lo)))) for m in MATERIALS}

PAPER = ("Paper (H1, 256x256x225, \"about 14.1 million\" voxels): 6.4 MB of index with only bones and muscles "
         "loaded, about 20 MB with skin; 56.3 MB for the augmented volume itself (4 bytes per voxel).")


def _median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def _augment_to(path, shape=None):
    from isplat.augfile import write_augmented
    from isplat.augment import augment_array
    from isplat.samples import make_sample

    arr, spacing = make_sample("head", shape=shape)
    aug = augment_array(arr, spacing)
    del arr
    write_augmented(path, aug["density"], aug["gradient_magnitude"], aug["normal"], aug["spacing_ijk"],
                    aug["density_window"], aug["gradient_magnitude_scale"])
    return aug["density"], aug["density_window"]


def _values_storage(idx_path) -> int:
    """Bytes on disk of channel values inside the index (``/values`` of index format 4; format 6 keeps them in
    the values file beside it): not part of the paper's index."""
    with h5py.File(idx_path, "r") as f:
        if "values" not in f:
            return 0
        return sum(int(ds.id.get_storage_size()) for ds in f["values"].values())


def _values_file(idx_path) -> int:
    """Bytes on disk of the values file beside the index (index format 6), 0 without one."""
    p = Path(str(idx_path).replace(".idx.h5", ".values.idx.h5"))
    return os.path.getsize(p) if p.exists() else 0


def _sizes(idx_path, n_axes_expected=3):
    from isplat.index import open_index

    idx = open_index(idx_path)
    total = os.path.getsize(idx_path) - _values_storage(idx_path)
    n = int(idx.voxel_counts(idx.axes[0]).sum())
    per_axis = {a: idx.nbytes(a) / max(1, n) for a in idx.axes}
    return idx, total, n, total / max(1, n * len(idx.axes)), per_axis


def _peak_rss_child(aug_path, out_path) -> tuple[float, float]:
    """Peak RSS (MB) and wall time of ``isplat index`` run in a fresh process.

    A small wrapper process runs it and reports its own ``RUSAGE_CHILDREN.ru_maxrss``: Linux carries a
    process's high-water RSS across fork/exec, so the child must not be started from a big parent.
    """
    cmd = [sys.executable, "-m", "isplat", "index", str(aug_path), "-o", str(out_path), "-q", "--force"]
    wrapper = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
               f"subprocess.run({cmd!r}, check=True); dt = time.perf_counter() - t; "
               "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, dt)")
    out = subprocess.run([sys.executable, "-c", wrapper], check=True, capture_output=True, text=True).stdout
    kib, dt = out.split()
    return int(kib) / 1024.0, float(dt)     # ru_maxrss is in KiB on Linux


def run(out_dir: Path, quick: bool) -> Path:
    from isplat.index import build_index, build_index_file, open_index

    out_dir = Path(out_dir)
    repeats = 1 if quick else 3
    big = (192, 192, 192) if quick else (512, 512, 512)
    lines = ["```", "python -m benchmarks index" + (" --quick" if quick else ""), "```", ""]
    with tempfile.TemporaryDirectory(prefix="isplat-bench-index-") as tmp:
        tmp = Path(tmp)
        # peak memory first: RUSAGE_CHILDREN keeps the maximum over all children waited for
        big_aug = tmp / "big.aug.h5"
        print(f"[bench index] augmenting head at {big}", file=sys.stderr)
        subprocess.run([sys.executable, "-c", "import sys; from benchmarks.index import _augment_to; "
                        f"_augment_to({str(big_aug)!r}, shape={big!r})"], check=True,
                       cwd=Path(__file__).resolve().parents[1])
        big_rss, big_time = _peak_rss_child(big_aug, tmp / "big.idx.h5")
        big_file = os.path.getsize(tmp / "big.idx.h5")
        big_aug.unlink()

        print("[bench index] head 256x256x225", file=sys.stderr)
        aug = tmp / "head.aug.h5"
        density, window = _augment_to(aug)
        mat = _material_densities(window)
        # bone and soft tissue ("muscle"; the sample does not separate skin): from just below soft tissue up
        bone_and_soft = [(mat["SOFT"] - 2, 255)]
        # bone with its partial-volume ramp and teeth: just above soft tissue up (about 7% of the voxels)
        load_interval = (mat["SOFT"] + 3, 255)
        n_vox = density.size
        hist = np.bincount(density.ravel(), minlength=256)

        out_all = tmp / "head.idx.h5"
        build_index_file(aug, out_all, force=True)                  # warm-up (numba compile/cache)
        t_file = _median_time(lambda: build_index_file(aug, out_all, force=True), repeats)
        t_mem = _median_time(lambda: build_index(density), repeats)
        idx_all, total_all, n_all, bpv_all, axis_all = _sizes(out_all)
        _values_file_mb = _values_file(out_all) / 1e6

        out_bs = tmp / "head-bone-soft.idx.h5"
        t_bs = _median_time(lambda: build_index_file(aug, out_bs, ranges=bone_and_soft, force=True), repeats)
        idx_bs, total_bs, n_bs, bpv_bs, axis_bs = _sizes(out_bs)

        # load one axis for an interval of ~7% of the voxels
        lo, hi = load_interval
        frac = hist[lo:hi + 1].sum() / n_vox
        load_rows = []
        for a in "ijk":
            with h5py.File(out_all, "r") as f:
                g = f["axes"][a]
                ptr = g["density_entry_ptr"][()]
                off = g["entry_byte_offset"]
                block_bytes = int(off[ptr[hi + 1]] - off[ptr[lo]])
            idx = open_index(out_all)
            loaded = idx.load_axis(a, [load_interval])
            t_load = _median_time(lambda: idx.load_axis(a, [load_interval]), repeats)
            strict = idx.load_axis(a, [load_interval], verify_offsets=True).bytes_read
            load_rows.append((a, loaded.n_voxels, loaded.n_blocks, block_bytes, loaded.bytes_read,
                              loaded.bytes_read / max(1, block_bytes), t_load, strict / max(1, block_bytes)))

    mb = 1e6
    lines += [
        "# Index performance",
        "",
        f"Sample `head` (256x256x225 = {n_vox:,} voxels), augmented with default settings "
        f"(`isplat.augment.augment_array`). Times are medians of {repeats} after a warm-up run "
        f"(numba compile); machine: {_doc.machine_line()}; isplat {_doc.git_rev()}.",
        "",
        "## Build time",
        "",
        "| what | time (s) | target |",
        "|---|---:|---|",
        f"| `build_index_file`, all densities, axes ijk (read + index + channel values + write) | {t_file:.3f} "
        "| < 10 s |",
        f"| `build_index` in memory, all densities, axes ijk | {t_mem:.3f} | |",
        f"| `build_index_file`, `--densities {_r(bone_and_soft)}` | {t_bs:.3f} | |",
        "",
        "## Size per indexed voxel (file bytes, tables included)",
        "",
        "File bytes are the index file's: since index format 6 the channel values (3 B per indexed voxel, read by "
        "the pre technique only) are in the values file beside it, given apart (values file: "
        f"{_values_file_mb:.1f} MB for all densities; docs/selective-read.md). "
        "Bytes per indexed voxel = total file bytes / (indexed voxels x axes); per axis = the axis's blocks and "
        "tables (`IndexFile.nbytes(axis)`) / indexed voxels. Ranges from the sample's materials under the "
        f"default window {window[0]:.0f}..{window[1]:.0f}: "
        + ", ".join(f"{m.lower()} {d}" for m, d in mat.items()) + " (air 0, with a noise tail); "
        f"the bone-and-muscle index is {_r(bone_and_soft)} (soft tissue, partial-volume ramps, bone, teeth; "
        "skin and muscle are one material in this sample). Voxels with density > 0.2% of the volume: "
        + ", ".join(f"{d}: {int(hist[d]):,}" for d in np.flatnonzero(hist > 0.002 * n_vox)) + ".",
        "",
        "| densities | indexed voxels | file bytes | bytes / indexed voxel | i | j | k | target |",
        "|---|---:|---:|---:|---:|---:|---:|---|",
        f"| all (0:255) | {n_all:,} | {total_all:,} ({total_all / mb:.1f} MB) | {bpv_all:.3f} | "
        f"{axis_all['i']:.3f} | {axis_all['j']:.3f} | {axis_all['k']:.3f} | <= 1.3 |",
        f"| bone + soft tissue ({_r(bone_and_soft)}) | {n_bs:,} | {total_bs:,} ({total_bs / mb:.1f} MB) | "
        f"{bpv_bs:.3f} | {axis_bs['i']:.3f} | {axis_bs['j']:.3f} | {axis_bs['k']:.3f} | |",
        "",
        PAPER + f" For comparison the paper's 6.4 MB over 3 x 14.1 M voxel slots is "
        f"{6.4e6 / (3 * 14.1e6):.3f} bytes per voxel per axis of the whole volume; ours for bone + soft "
        f"tissue is {total_bs / (3 * n_vox):.3f} per voxel of the whole volume ({total_bs / mb:.1f} MB), "
        f"and {total_all / mb:.1f} MB for everything.",
        "",
        "## Loading one axis for an interval",
        "",
        f"Interval {lo}:{hi} (bone with its partial-volume ramp and teeth) holds {frac:.1%} of the voxels. "
        "Block bytes = the interval's byte range; bytes read = every dataset slice requested through h5py "
        "(`density_entry_ptr`; the interval's rows of `entry_slice` and `entry_voxel_count`; its two end rows "
        "of `entry_byte_offset`; its byte range; block boundaries inside follow from the counts). The last "
        "column is `load_axis(..., verify_offsets=True)`, which also reads every row of `entry_byte_offset` "
        "(8 more bytes per block) to check each block against it.",
        "",
        "| axis | voxels | blocks | block bytes | bytes read | read / block bytes | load time (s) | target "
        "| read / block bytes, verify_offsets |",
        "|---|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for a, nv, nb, bb, br, ratio, tl, strict in load_rows:
        lines.append(f"| {a} | {nv:,} | {nb:,} | {bb:,} | {br:,} | {ratio:.3f} | {tl:.3f} | <= 1.2 | {strict:.3f} |")
    lines += [
        "",
        "## Peak memory",
        "",
        f"`isplat index` (all densities, axes ijk) on the `head` sample at {big[0]}x{big[1]}x{big[2]}, run as a "
        "subprocess; peak RSS from `resource.getrusage(RUSAGE_CHILDREN).ru_maxrss`.",
        "",
        "| volume | peak RSS (MB) | wall time (s, incl. start-up) | index file (MB) | target |",
        "|---|---:|---:|---:|---|",
        f"| {big[0]}^3 | {big_rss:.0f} | {big_time:.1f} | {big_file / mb:.1f} | < 3000 MB |",
        "",
    ]
    path = out_dir / "index-performance.md"
    path.write_text("\n".join(lines))
    return path


def _r(ranges):
    return ",".join(f"{lo}:{hi}" for lo, hi in ranges)
