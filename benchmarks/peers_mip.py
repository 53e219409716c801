"""Maximum-intensity projection side by side with VTK's, both against the brute-force reference.

``python -m benchmarks.peers --mip-only [--quick] [--cases head,head-512]`` (``make bench-peers`` runs it after the
compositing peers) writes ``docs/mip.md``:

* frame time: isplat's MIP (``render.mode = "mip"``, :mod:`isplat.splat.mip`, indexed method) against
  ``vtkFixedPointVolumeRayCastMapper`` with ``SetBlendModeToMaximumIntensity`` at a ray step of 1 voxel and at
  VTK's default sample distance (1.0 world unit), the same thread count, offscreen; all rendered in turn, round
  after round, in one process (interleaved), each timed frame right after an untimed one of the same renderer;
  medians, and the median of the per-round ratios isplat / VTK;
* image difference of each against the brute-force reference (tests/mip_reference.py,
  ``mip_reference_vectorized``: every pixel's ray, every slice plane of the principal axis, the bilinear density
  at the crossing, the maximum; no index, no skipping), and between the two;
* the leave-out figure: the voxels of interest of the frame and those in the cells the frame visited.

The same picture on both sides: the augmented file's 8-bit densities, spacing and placement (benchmarks.peers'
``VTKView``); densities below ``THRESHOLD`` are of no interest to isplat (opacity 0) and map to black in VTK
(opacity 0 below it: VTK's MIP takes the largest sample and then classifies it), so both show
``clip((max - T) / (255 - T))`` as grey over black. Black background, orthographic, anterior view, no shading.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import numpy as np

from . import _doc

REPO = Path(__file__).resolve().parents[1]
SECTION = "mip"
THRESHOLD = 40           # code: the head sample's air and its noise lie below, skin and everything inside above
TECHNIQUES = ["mip"]
SOURCES = _doc.sources(_doc.RENDER, _doc.READ, _doc.SAMPLES, ("isplat/scene_parse.py", "isplat/scene_schema.py",
                       "tests/mip_reference.py", "benchmarks/reference.py", "benchmarks/peers.py",
                       "benchmarks/peers_mip.py"))
# name -> (sample, shape or None (the sample's default), quick shape, sizes, quick sizes, rounds, note)
CASES = {
    "head": ("head", None, (64, 64, 56), [256, 512], [48], 7, "head sample 256x256x225"),
    "head-512": ("head", (512, 512, 512), (96, 96, 96), [512], [64], 3, "head sample at 512^3"),
}


def mip_scene(aug, idx, size: int):
    from isplat.scene import parse_scene

    t = THRESHOLD
    text = (f'version = 6\n[data]\naugmented = "{aug}"\nindex = "{idx}"\n[image]\nwidth = {size}\nheight = {size}\n'
            f'background = [0.0, 0.0, 0.0]\n[transfer]\nopacity = [[{t - 1}, 0.0], [{t}, 1.0], [255, 1.0]]\n'
            f'color = [[{t}, 0.0, 0.0, 0.0], [255, 1.0, 1.0, 1.0]]\n[render]\nmode = "mip"\nwindow = [{t}, 255]\n')
    return parse_scene(text, REPO, "peers_mip scene")


def reference_grey(density, view, t=THRESHOLD) -> tuple[np.ndarray, float]:
    """The brute-force MIP as grey (H, W) over black, and the seconds it took."""
    sys.path.insert(0, str(REPO / "tests"))
    from mip_reference import mip_reference_vectorized

    t0 = time.perf_counter()
    interest = np.arange(256) >= t
    held = mip_reference_vectorized(density, view, interest, "mip")
    g = np.where(np.isnan(held), 0.0, np.clip((held - t) / (255.0 - t), 0.0, 1.0))
    return g, time.perf_counter() - t0


def errors(img: np.ndarray, ref: np.ndarray) -> dict:
    """max, mean and RMS of |img - ref| (grey in [0, 1]) and the share of pixels off by more than 2/255."""
    d = np.abs(np.asarray(img, np.float64) - ref)
    return dict(max=float(d.max()), mean=float(d.mean()), rmse=float(np.sqrt((d * d).mean())),
                over2=float((d > 2.0 / 255.0).mean()))


def measure(name: str, size: int, quick: bool) -> dict:
    from isplat.augfile import open_augmented
    from isplat.frame import BandLearning, render_frame
    from isplat.renderer import Renderer

    from . import reference as REF
    from .peers import VTKView

    sample, shape, qshape, _, _, rounds, _ = CASES[name]
    aug, idx = REF.sample_data(sample, qshape if quick else shape)
    scene = mip_scene(aug, idx, size)
    r = Renderer(scene)
    view = r.views[0]
    density = open_augmented(aug).read("density")
    vtkv = VTKView(r, 0, 1.0, density=density)
    vtkv.mapper.SetBlendModeToMaximumIntensity()
    default_step = 1.0 / vtkv.voxel             # VTK's default SampleDistance, 1.0 world unit, in voxels
    labels = ["isplat mip", "VTK MIP 1", "VTK MIP default"]
    steps = {"VTK MIP 1": 1.0, "VTK MIP default": default_step}
    bands = BandLearning()
    imgs, stats = {}, {}

    def job(lab, keep):
        if lab.startswith("VTK"):
            vtkv.set_step(steps[lab])
            dt = vtkv.render()
            if keep:
                imgs[lab] = vtkv.image_float()[..., 0]
            return dt
        t0 = time.perf_counter()
        img, st = render_frame(r.selection, view, None, bands)
        dt = time.perf_counter() - t0
        imgs[lab], stats[lab] = img[..., 0], st
        return dt

    for lab in labels:                          # warm up: compiled code, the units of the selection, caches
        job(lab, False)
    times = {lab: [] for lab in labels}
    n = 2 if quick else rounds
    for rnd in range(n):
        for lab in labels[rnd % len(labels):] + labels[:rnd % len(labels)]:
            job(lab, False)                     # the untimed frame: right after another renderer's
            times[lab].append(job(lab, rnd == n - 1))
    ref, ref_s = reference_grey(density, view)
    st = stats["isplat mip"]
    return dict(case=name, size=size, shape=list(density.shape[::-1]), threads=(r.threads, vtkv.threads),
                ms={lab: _doc.median_ms(times[lab]) for lab in labels},
                ratio={lab: statistics.median(a / b for a, b in zip(times["isplat mip"], times[lab]))
                       for lab in labels[1:]},
                err={lab: errors(imgs[lab], ref) for lab in labels},
                between=errors(imgs["isplat mip"], imgs["VTK MIP 1"]), default_step=default_step,
                interest=st.voxels_examined, visited=st.voxels_tested, samples=st.samples, ref_seconds=ref_s,
                rounds=n, images={lab: imgs[lab] for lab in labels}, ref=ref)


def save_strip(r: dict, path: Path) -> None:
    """isplat | VTK at step 1 | reference, and |isplat - ref| and |VTK - ref| times 16, as one PNG."""
    import imageio.v3 as iio

    ref = r["ref"]
    parts = [r["images"]["isplat mip"], r["images"]["VTK MIP 1"], ref,
             np.clip(16 * np.abs(r["images"]["isplat mip"] - ref), 0, 1),
             np.clip(16 * np.abs(r["images"]["VTK MIP 1"] - ref), 0, 1)]
    gap = np.ones((ref.shape[0], 4))
    strip = np.concatenate([x for p in parts for x in (p, gap)][:-1], axis=1)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, (np.clip(strip, 0, 1) * 255 + 0.5).astype(np.uint8))


def _e(e) -> str:
    return f"{e['max']:.4f} / {e['rmse']:.5f} / {100 * e['over2']:.2f}%"


def body(results, command, vtk_ver, window_cls, not_run) -> str:
    L = [f"Command: `{command}`. Technique: **mip** (`render.mode = \"mip\"`, isplat/splat/mip.py, indexed method, "
         f"scene version 6) against VTK {vtk_ver}'s `vtkFixedPointVolumeRayCastMapper` with "
         f"`SetBlendModeToMaximumIntensity` ({window_cls}, offscreen). {_doc.machine_line()}", "",
         "Both draw the same data (the augmented file's 8-bit densities, spacing and placement), anterior view, "
         f"orthographic, no shading, black background; densities below {THRESHOLD} are of no interest (isplat: "
         "opacity 0, so they are not indexed for the frame; VTK: opacity 0 after its maximum), and the maximum "
         f"maps to grey through the window {THRESHOLD}..255 (`render.window`). VTK MIP 1: ray step 1 voxel; VTK MIP "
         "default: VTK's default sample distance, 1.0 world unit (the same as step 1 where the smallest spacing is "
         "1). Frame times are medians over interleaved rounds, each timed frame right after an untimed one of the "
         "same renderer; the ratio is the median of the per-round ratios isplat / VTK (below 1: isplat faster).", "",
         "Image difference against the brute-force reference (tests/mip_reference.py `mip_reference_vectorized`: "
         "every pixel's ray crossed with every slice plane of the principal axis, the bilinear density there, the "
         "maximum; no index and no skipping), as grey in [0, 1]: max / RMS / share of pixels off by more than "
         "2/255. VTK's images are 8-bit (up to 0.5/255 from rounding alone); isplat's are compared as rendered "
         "(float).", "",
         "| case | px | threads | isplat mip ms | VTK MIP 1 ms | VTK default ms | isplat / VTK 1 | isplat / VTK "
         "default | isplat vs ref | VTK 1 vs ref | VTK default vs ref | isplat vs VTK 1 |",
         "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        ms, ra, er = r["ms"], r["ratio"], r["err"]
        L.append(f"| {CASES[r['case']][6]} | {r['size']} | {r['threads'][0]} / {r['threads'][1]} | "
                 f"{ms['isplat mip']:.1f} | {ms['VTK MIP 1']:.1f} | {ms['VTK MIP default']:.1f} "
                 f"(step {r['default_step']:g}) | {ra['VTK MIP 1']:.2f} | {ra['VTK MIP default']:.2f} | "
                 f"{_e(er['isplat mip'])} | {_e(er['VTK MIP 1'])} | {_e(er['VTK MIP default'])} | "
                 f"{_e(r['between'])} |")
    L += ["", "The leave-out figure (`isplat render -v` prints it per view): the voxels of interest of the frame, "
          "and those in the cells a MIP frame visited (a cell is skipped when every pixel it reaches already holds "
          "at least the highest density of its quads; summed over the image bands, so a cell reaching two bands "
          "counts twice), and the samples taken.", "",
          "| case | px | voxels of interest | voxels in cells visited | share | samples taken | reference s |",
          "|---|---|---|---|---|---|---|"]
    for r in results:
        L.append(f"| {CASES[r['case']][6]} | {r['size']} | {r['interest']:,} | {r['visited']:,} | "
                 f"{100 * r['visited'] / max(1, r['interest']):.1f}% | {r['samples']:,} | {r['ref_seconds']:.1f} |")
    slower = [r for r in results if r["ratio"]["VTK MIP 1"] > 1.0]
    L += [""]
    for r in results:
        if r["size"] == 512:
            verdict = "slower than" if r["ratio"]["VTK MIP 1"] > 1.0 else "faster than"
            L.append(f"At 512 px on the {CASES[r['case']][6]} isplat's MIP is {verdict} VTK's MIP at step 1 "
                     f"(x{r['ratio']['VTK MIP 1']:.2f} of its frame time; the bar is 1, the aim 0.5).")
    if slower:
        L.append("Slower where the ratio is above 1: " + ", ".join(f"{r['case']} {r['size']} px" for r in slower)
                 + ".")
    for name in not_run:
        sample, shape, *_ = CASES[name]
        L.append(f"Not run in this page's run: {CASES[name][6]} (`python -m benchmarks.peers --mip-only --cases {name}`"
                 " measures it; it was left out for the time it takes on this machine).")
    for r in results:
        L += ["", f"![{r['case']} {r['size']} px: isplat mip | VTK MIP step 1 | reference | 16 x |isplat - "
                  f"reference| | 16 x |VTK - reference|](img/mip-{r['case']}-{r['size']}.png)",
              f"*{CASES[r['case']][6]}, {r['size']} px, technique mip: isplat | VTK MIP step 1 | brute-force "
              "reference | 16 x |isplat - reference| | 16 x |VTK - reference|.*"]
    return "\n".join(L)


def run(out_dir: Path, quick: bool, cases=None, command: str | None = None) -> Path:
    from .peers import PeerUnavailable, offscreen_window_class, vtk_version  # noqa: F401 (PeerUnavailable: callers)
    import os

    out_dir = Path(out_dir)
    ver = vtk_version()
    cls = offscreen_window_class()
    os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = cls
    cases = list(cases or CASES)
    command = command or ("python -m benchmarks.peers --mip-only" + (" --quick" if quick else "")
                          + (f" --cases {','.join(cases)}" if set(cases) != set(CASES) else ""))
    results = []
    for name in cases:
        for size in CASES[name][4 if quick else 3]:
            print(f"[peers mip] {name} at {size} px", file=sys.stderr, flush=True)
            r = measure(name, size, quick)
            print(f"[peers mip]   isplat {r['ms']['isplat mip']:.1f} ms, VTK MIP 1 {r['ms']['VTK MIP 1']:.1f} ms "
                  f"(x{r['ratio']['VTK MIP 1']:.2f}); max |isplat - ref| {r['err']['isplat mip']['max']:.2e}, "
                  f"|VTK - ref| {r['err']['VTK MIP 1']['max']:.3f}", file=sys.stderr, flush=True)
            save_strip(r, out_dir / "img" / f"mip-{name}-{size}.png")
            results.append(r)
    doc = out_dir / "mip.md"
    not_run = [c for c in CASES if c not in cases]
    text = body(results, command, ver, cls, not_run)
    _doc.update_section(doc, SECTION, text, title="Maximum-intensity projection: isplat against VTK")
    return _doc.put_stamp(doc, _doc.stamp(SECTION, command, TECHNIQUES, SOURCES), SECTION)
