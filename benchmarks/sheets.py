"""Image-aligned against axis-aligned sheets: popping at the principal-axis switch, and frame time.

``python -m benchmarks sheets [--out docs] [--quick]`` writes ``sheets.md``. For the head (examples/head.toml,
orthographic) and the engine (examples/engine.toml, perspective as written), both at the scene's other
settings and 256 x 256 (quick: 64 x 64 on small samples):

* popping (the measure of docs/accuracy.md): views 0.2 degrees apart straddling the azimuth where the
  principal axis switches; RMSE of the image change across the switch over the median change between
  neighbouring views on the same side, for ``render.sheets = "axis"`` and ``"image"``;
* frame time: median of interleaved frames (axis, image, axis, image, ...) of the scene's own view, all
  cores, after warm-up frames, and the counters of the last frame.
"""

from __future__ import annotations

import dataclasses
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from . import _doc

REPO = Path(__file__).resolve().parents[1]
CACHE = REPO / "bench-out"
CASES = {"head": ("examples/head.toml", "orthographic", "bone, opaque, lit"),
         "engine": ("examples/engine.toml", "perspective", "semi-transparent aluminium, steel, opaque bolts")}
QUICK_SHAPE = (48, 48, 48)
OFFSETS = [-0.9, -0.7, -0.5, -0.3, -0.1, 0.1, 0.3, 0.5, 0.7, 0.9]   # degrees from the switch
TARGET = 1.3          # issue 12: the switch at most 1.3x the change between neighbouring views


def _log(msg):
    print(f"[sheets] {msg}", file=sys.stderr, flush=True)


def sample(name: str, quick: bool) -> tuple[Path, Path]:
    """The sample ``name`` augmented and indexed in bench-out/ (built once, reused)."""
    from isplat.augfile import write_augmented
    from isplat.augment import augment_array
    from isplat.index import build_index_file
    from isplat.samples import make_sample

    tag = f"sheets-{name}" + ("-quick" if quick else "")
    aug, idx = CACHE / f"{tag}.aug.h5", CACHE / f"{tag}.idx.h5"
    if aug.exists() and idx.exists():
        return aug, idx
    _log(f"making {tag}")
    CACHE.mkdir(parents=True, exist_ok=True)
    arr, sp = make_sample(name, shape=QUICK_SHAPE if quick else None)
    o = augment_array(arr, sp)
    tmp_aug, tmp_idx = (CACHE / f".{tag}{e}.{os.getpid()}" for e in (".aug.h5", ".idx.h5"))
    try:
        write_augmented(tmp_aug, o["density"], o["gradient_magnitude"], o["normal"], o["spacing_ijk"],
                        o["density_window"], o["gradient_magnitude_scale"], {"source": f"isplat sample {name}"})
        build_index_file(tmp_aug, tmp_idx)
        os.replace(tmp_aug, aug)
        os.replace(tmp_idx, idx)
    finally:
        for p in (tmp_aug, tmp_idx):
            p.unlink(missing_ok=True)
    return aug, idx


def scene(case: str, sheets: str, size: int, quick: bool):
    from isplat.scene import load_scene

    aug, idx = sample(case, quick)
    ov = ["version=3", f'data.augmented="{aug}"', f'data.index="{idx}"', f"image.width={size}",
          f"image.height={size}", f'render.sheets="{sheets}"']
    return load_scene(REPO / CASES[case][0], ov)


def switch_azimuth(sc, lo=0.0, hi=90.0) -> tuple[float, str, str]:
    """The azimuth in (lo, hi) where the principal axis of the scene's camera changes (bisection)."""
    from isplat import camera as C
    from isplat.augfile import open_augmented

    aug = open_augmented(sc.data.augmented)
    geom = C.volume_geometry(aug.shape, sc.volume.spacing or aug.spacing_ijk, sc.volume.origin, sc.volume.axes)

    def axis(az):
        f = C.view_frame(dataclasses.replace(sc.views[0], azimuth=az), geom, sc.image.width, sc.image.height)
        return C.principal_axis(f, geom)[0]

    a_lo = axis(lo)
    if a_lo == axis(hi):
        raise RuntimeError(f"no principal-axis switch between azimuth {lo} and {hi}")
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if axis(mid) == a_lo else (lo, mid)
    return 0.5 * (lo + hi), a_lo, axis(hi)


def rmse(a, b) -> float:
    d = a[..., :3].astype(np.float64) - b[..., :3].astype(np.float64)
    return float(np.sqrt(np.mean(d * d)))


def popping(case: str, sheets: str, size: int, quick: bool) -> dict:
    from isplat.renderer import Renderer

    sc = scene(case, sheets, size, quick)
    s, ax_lo, ax_hi = switch_azimuth(sc)
    cams = [dataclasses.replace(sc.views[0], azimuth=s + o) for o in OFFSETS]
    r = Renderer(sc, views=cams)
    out = [r.render_view(n) for n in range(len(cams))]
    steps = [dict(a0=s + OFFSETS[n], a1=s + OFFSETS[n + 1], ax0=out[n][1].axis, ax1=out[n + 1][1].axis,
                  rmse=rmse(out[n + 1][0], out[n][0])) for n in range(len(cams) - 1)]
    cross = [x["rmse"] for x in steps if x["ax0"] != x["ax1"]]
    same = statistics.median(x["rmse"] for x in steps if x["ax0"] == x["ax1"])
    return dict(switch=s, axes=(ax_lo, ax_hi), steps=steps, cross=cross[0], same=same, ratio=cross[0] / same)


def frame_times(case: str, size: int, frames: int, quick: bool) -> dict:
    """Interleaved frames of the scene's view, axis and image sheets in turn; median seconds and counters."""
    from isplat.renderer import Renderer

    rs = {s: Renderer(scene(case, s, size, quick)) for s in ("axis", "image")}
    times = {s: [] for s in rs}
    last = {}
    for _ in range(2):                                  # warm-up (compilation, caches)
        for s, r in rs.items():
            last[s] = r.render_view(0)
    for _ in range(frames):
        for s, r in rs.items():
            t0 = time.perf_counter()
            last[s] = r.render_view(0)
            times[s].append(time.perf_counter() - t0)
    out = {s: dict(ms=1000 * statistics.median(times[s]), stats=last[s][1]) for s in rs}
    out["ratio"] = out["image"]["ms"] / out["axis"]["ms"]
    out["diff"] = rmse(last["image"][0], last["axis"][0])
    return out


def render_doc(pops, times, size, frames, quick, seconds, load0) -> str:
    L = ["```", "python -m benchmarks sheets" + (" --quick" if quick else ""), "```", "",
         "# Image-aligned sheets: popping and cost", "",
         f"Machine: {_doc.machine_line()}; git {_doc.git_rev()}; load average {load0:.2f} at the start; the bench "
         f"took {seconds:.0f} s." + (" **Quick run: small samples, numbers not representative.**" if quick else ""),
         "",
         '`render.sheets = "axis"` (the default) sums each slice of the principal axis into a sheet (Westover); '
         '`"image"` cuts the kernel into slabs parallel to the image plane, one smallest-spacing thick, and adds '
         "each voxel's kernel integral over every slab it reaches (Mueller and Crawfis 1998; "
         "isplat/splat/sheets.py). Images are "
         f"{size} x {size}; the cases are the example scenes with their own settings:", ""]
    for case, (path, proj, what) in CASES.items():
        L.append(f"- **{case}** (`isplat sample {case}`{', 48^3' if quick else ''}): {what}: {path} ({proj})")
    L += ["", "## Popping at the principal-axis switch", "",
          "Views 0.2 degrees of azimuth apart straddling the switch (found by bisection on "
          "`isplat.camera.principal_axis`); the change between neighbouring views is the RMSE over RGB in [0, 1]. "
          "*Ratio*: the change across the switch over the median change between neighbouring views on the same "
          f"side (the measure of docs/accuracy.md; issue 12's target: at most {TARGET}).", "",
          "| case | sheets | switch at azimuth | axes | RMSE across the switch | median RMSE same side | ratio |",
          "|---|---|---:|---|---:|---:|---:|"]
    for (case, sheets), p in pops.items():
        L.append(f"| {case} | `{sheets}` | {p['switch']:.4f} | {p['axes'][0]} -> {p['axes'][1]} | {p['cross']:.2e} | "
                 f"{p['same']:.2e} | **{p['ratio']:.2f}** |")
    L += ["", "Every step, RMSE of the change:", "",
          "| case | from azimuth | to | " + " | ".join(f"`{s}`" for s in ("axis", "image")) + " |",
          "|---|---:|---:|---:|---:|"]
    for case in CASES:
        pa, pi = pops[(case, "axis")], pops[(case, "image")]
        for sa, si in zip(pa["steps"], pi["steps"]):
            mark = " (switch)" if sa["ax0"] != sa["ax1"] else ""
            L.append(f"| {case} | {sa['a0']:.3f} | {sa['a1']:.3f}{mark} | {sa['rmse']:.2e} | {si['rmse']:.2e} |")
    L += ["", "## Frame time", "",
          f"Median of {frames} frames each, axis and image rendered in turn (interleaved) after 2 warm-up frames, "
          "all cores; counters of the last frame (image sheets: a voxel is counted once however many slabs it "
          "reaches; *sheets* is slices or slabs composited).", "",
          "| case | sheets | ms/frame (median) | x axis | voxels examined | voxels splatted | sheets | RMSE image vs axis |",
          "|---|---|---:|---:|---:|---:|---:|---:|"]
    for case, t in times.items():
        for s in ("axis", "image"):
            st = t[s]["stats"]
            L.append(f"| {case} | `{s}` | {t[s]['ms']:.1f} | {t[s]['ms'] / t['axis']['ms']:.2f} | "
                     f"{st.voxels_examined:,} | {st.voxels_splatted:,} | {st.slices:,} | "
                     f"{'' if s == 'axis' else format(t['diff'], '.2e')} |")
    L += ["", "## Reading", "", reading(pops, times)]
    return "\n".join(L) + "\n"


def reading(pops, times) -> str:
    ra = {c: pops[(c, "axis")]["ratio"] for c in CASES}
    ri = {c: pops[(c, "image")]["ratio"] for c in CASES}
    cost = {c: times[c]["ratio"] for c in CASES}
    met = all(r <= TARGET for r in ri.values())
    txt = ("Across the switch axis-aligned sheets change the image " +
           ", ".join(f"{ra[c]:.1f}x ({c})" for c in CASES) +
           " as much as a 0.2 degree turn does; image-aligned sheets " +
           ", ".join(f"{ri[c]:.2f}x ({c})" for c in CASES) +
           (f": within the target of {TARGET}x, the switch is no longer visible. " if met else
            f": the target of {TARGET}x is not met everywhere. ") +
           "The cost: image-aligned frames take " + ", ".join(f"{cost[c]:.1f}x ({c})" for c in CASES) +
           " the time of axis-aligned ones: every voxel is splatted into each slab its kernel reaches (about "
           "2 x 2.5 sigma / slab thickness + 1, 4-5 slabs at the default sigma 0.7 and radius 2.5), and voxels "
           "behind saturated pixels are tested once per slab instead of once per 4 x 4 cell.\n\n")
    txt += ("Default: `render.sheets` stays `\"axis\"`. For still images the popping does not exist (it is a "
            "change between frames) and image-aligned sheets cost " +
            f"{min(cost.values()):.1f}-{max(cost.values()):.1f}x the time; the existing images and their tests "
            "stay as they are. For orbits and camera paths (`[views]` with `orbit_steps` or `path`, GIF/MP4) "
            "whose azimuth crosses a diagonal the switch is visible in every such animation, so set "
            '`render.sheets = "image"` there' + (" (it removes the jump)." if met else "."))
    return txt


def run(out_dir: Path, quick: bool) -> Path:
    t0 = time.time()
    load0 = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    size = 64 if quick else 256
    frames = 2 if quick else 9
    pops = {}
    for case in CASES:
        for sheets in ("axis", "image"):
            _log(f"popping {case} {sheets}")
            pops[(case, sheets)] = popping(case, sheets, size, quick)
    times = {}
    for case in CASES:
        _log(f"frame time {case}")
        times[case] = frame_times(case, size, frames, quick)
    p = Path(out_dir) / "sheets.md"
    p.write_text(render_doc(pops, times, size, frames, quick, time.time() - t0, load0))
    return p
