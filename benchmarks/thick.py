"""Thick slices: what makes the rings, terraces and streaks on shaded renders of 2.5-7 mm slices, and their fix.

``python -m benchmarks thick [--quick]`` writes docs/thick-slices.md and the pictures docs/img/thick-*.png.

Each case is a sample made with few, thick slices (``isplat sample NAME --shape NI,NJ,NK`` and ``--spacing``), and
the same sample made with slices as thin as its pixels (the *object*, the reference the pictures are compared
against: the samples are painted in normalised coordinates, so both are the same object). Rendered with isplat's
default technique (post-classified), shaded, orthographic, from the side (the thick axis vertical in the image,
the view along i) and obliquely, with the post-classified sampler's shading *before* (each quad corner's Phong
factors weighted bilinearly) and *after* (weighted by the bilinear weight times the corner's gradient magnitude:
``isplat.splat.post.WEIGHTED_SHADING``), and *thin* (``isplat augment --thin-slices``).

Measures: the *streak* strength (:func:`streak`: the high-frequency luminance's difference from the object's),
RMSE over RGB against the object, the *band energy* of a side view (:func:`band_energy`), the sampler's cost in ns
per sample (interleaved rounds, :func:`ns_per_sample`), and ``--thin-slices``'s cost on the command line
(``isplat augment``, /usr/bin/time).
"""

from __future__ import annotations

import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import _doc

TECHNIQUES = ["post"]
SOURCES = _doc.sources(_doc.RENDER, _doc.AUGMENT, _doc.SAMPLES, ("isplat/resample.py", "benchmarks/thick.py",
                                                                  "isplat/presets.py", "isplat/scene_parse.py",
                                                                  "examples/ct-preset.toml"))
REPO = Path(__file__).resolve().parents[1]
SIZE = 320
# name, sample, thick shape (NI, NJ, NK), spacing (i, j, k), preset, object's NK (slices of the in-plane spacing)
CASES = [
    ("ct-head-2.5mm", "ct-head", (256, 256, 72), (0.7, 0.7, 2.5), "ct-bone", 257),
    ("ct-chest-2.5mm", "ct-chest", (256, 192, 72), (0.7, 0.7, 2.5), "ct-bone", 257),
    ("ct-head-7mm", "ct-head", (256, 256, 32), (1.0, 1.0, 7.0), "ct-bone", 224),
    ("mr-head-7mm", "mr-head", (256, 256, 32), (1.0, 1.0, 7.0), "mri-t1-head", 224),
]
VIEWS = {"side": (90.0, 0.0), "oblique": (45.0, 25.0)}
ROUNDS = 41               # interleaved rounds of the timing (ns_per_sample; frames of 10-50 ms on a shared machine)
WINDOWS = {"ct-head": (-1024.0, 3071.0), "ct-chest": (-1024.0, 3071.0)}


def _log(msg):
    print(f"[thick] {msg}", file=sys.stderr, flush=True)


def scene(aug: Path, preset: str, view: str, size: int, shaded: bool = True):
    """The scene of examples/ct-preset.toml with ``preset`` (in data units: read through ``aug``'s window)."""
    from isplat.scene import load_scene

    az, el = VIEWS[view]
    ov = [f'data.augmented="{aug}"', f"image.width={size}", f"image.height={size}", f'transfer.preset="{preset}"',
          f"camera.azimuth={az}", f"camera.elevation={el}", 'camera.projection="orthographic"']
    if not shaded:
        ov.append("shading.enabled=false")
    return load_scene(REPO / "examples" / "ct-preset.toml", ov)


def channels(vol, spacing, window, smooth_normals=True, forced=False) -> dict:
    from isplat import augment as A

    ratio = A.NORMAL_RATIO
    A.NORMAL_RATIO = 1.0 if forced else ratio
    try:
        o = A.augment_array(vol, spacing, window, smooth_normals=smooth_normals)
    finally:
        A.NORMAL_RATIO = ratio
    o["window"] = o["density_window"]
    return dict(raw=o, density=o["density"], normal=o["normal"], gm=o["gradient_magnitude"],
                gscale=o["gradient_magnitude_scale"], spacing=o["spacing_ijk"], window=o["density_window"])


def _selection(sc, c):
    from isplat.selection import Selection

    return Selection.from_arrays(c["density"], sc, normal=c["normal"], gradient_magnitude=c["gm"],
                                 gradient_magnitude_scale=c["gscale"], spacing=c["spacing"])


def render(sc, c) -> np.ndarray:
    from isplat.frame import render_frame, views_for

    sel = _selection(sc, c)
    return render_frame(sel, views_for(sc, sel)[0])[0].astype(np.float64)


def pixel_size(sc, c) -> float:
    from isplat.frame import views_for

    return float(views_for(sc, _selection(sc, c))[0].frame.pixel_size)


def rmse(a, b) -> float:
    d = a[..., :3] - b[..., :3]
    return float(np.sqrt(np.mean(d * d)))


def band_energy(img, period_px: float) -> float:
    """RMS over the image's rows (those crossing the object) of the row's mean luminance minus its running
    mean over one slice period (``period_px`` pixels, odd, at least 3): the part of the picture that repeats
    slice by slice in a side view. The object's own shading changes slowly over a period and mostly cancels."""
    L = img[..., :3].mean(-1)
    mask = img[..., 3] > 0.5 if img.shape[-1] == 4 else L > 0.02
    P = max(3, int(round(period_px)) | 1)
    k = np.ones(P) / P
    pad = np.pad(L, ((P // 2, P // 2), (0, 0)), mode="edge")
    sm = sum(k[m] * pad[m:m + L.shape[0]] for m in range(P))
    R = (L - sm) * mask
    n = mask.sum(1)
    rows = n > 10
    m = R.sum(1)[rows] / n[rows]
    return float(np.sqrt(np.mean(m * m))) if m.size else 0.0


def thin_cost(name, shape, spacing, window) -> dict:
    """``isplat augment`` of the thick sample as it is and with ``--thin-slices``: seconds, peak RSS, file size."""
    from isplat.samples import make_sample

    out = {}
    isplat = Path(sys.executable).with_name("isplat")
    with tempfile.TemporaryDirectory() as tmp:
        arr, _ = make_sample(name, shape)
        np.save(Path(tmp) / "v.npy", arr)
        win = [] if window is None else [f"--window={window[0]:g},{window[1]:g}"]
        for key, extra in (("as_is", []), ("thin", ["--thin-slices"])):
            dst = Path(tmp) / f"{key}.aug.h5"
            cmd = ["/usr/bin/time", "-f", "%e %M", str(isplat), "-q", "augment", str(Path(tmp) / "v.npy"), "-o",
                   str(dst), "--spacing", ",".join(map(str, spacing)), *win, *extra]
            r = subprocess.run(cmd, capture_output=True, text=True, check=True)
            secs, kb = r.stderr.strip().splitlines()[-1].split()
            out[key] = dict(seconds=float(secs), rss_mb=int(kb) / 1024, file_mb=dst.stat().st_size / 1e6)
    return out


def _sampler(weighted: bool):
    """Set the post-classified sampler's shading: corners weighted by their gradient magnitudes too (the default
    now) or bilinearly only (before); returns the previous setting."""
    from isplat.splat import post

    old = post.WEIGHTED_SHADING
    post.WEIGHTED_SHADING = weighted
    return old


def render_with(sc, c, weighted: bool) -> np.ndarray:
    old = _sampler(weighted)
    try:
        return render(sc, c)
    finally:
        _sampler(old)


def _measure():
    """tests/streak_measure.py (the streak measure, shared with the tests)."""
    tests = str(REPO / "tests")
    if tests not in sys.path:
        sys.path.insert(0, tests)
    import streak_measure

    return streak_measure


def _view(sc, c):
    from isplat.frame import views_for

    return views_for(sc, _selection(sc, c))[0]


def surface_phase(sc, obj, thick_c, level: float) -> np.ndarray:
    """:func:`streak_measure.surface_phase` of the scene's view of the object and of the thick data."""
    return _measure().surface_phase(_view(sc, obj), _view(sc, thick_c), obj["density"], level)


def streak(img, phase, period_px: float) -> float:
    return _measure().streak(img, phase, period_px)


def ns_per_sample(sc, c, rounds: int) -> dict:
    """Interleaved rounds of the frame with the sampler's shading unweighted (before) and weighted (after): the
    median frame seconds over the samples composited, in ns per sample, and the samples."""
    from isplat.frame import render_frame, views_for

    sel = _selection(sc, c)
    view = views_for(sc, sel)[0]
    t = {False: [], True: []}
    n = {}
    for w in (False, True):          # compile and warm both
        old = _sampler(w)
        render_frame(sel, view)
        _sampler(old)
    for r in range(rounds):
        for w in ((False, True) if r % 2 == 0 else (True, False)):     # ABBA: neither always goes first
            old = _sampler(w)
            try:
                _, st = render_frame(sel, view)
            finally:
                _sampler(old)
            t[w].append(st.seconds)
            n[w] = st.samples
    med = {w: statistics.median(v) for w, v in t.items()}
    return dict(before=med[False] * 1e9 / max(1, n[False]), after=med[True] * 1e9 / max(1, n[True]),
                samples=n[True], seconds_before=med[False], seconds_after=med[True], rounds=rounds)


def level(sc) -> float:
    """The density code where the scene's opacity first reaches half its largest value: the surface
    :func:`surface_phase` looks for."""
    op = np.asarray(sc.transfer.opacity, float)
    codes = np.arange(256.0)
    a = np.interp(codes, op[:, 0], op[:, 1], left=0.0, right=0.0)
    return float(codes[np.argmax(a >= 0.5 * a.max())])


def run_case(case, views, size, img_dir: Path, rounds: int):
    from isplat.resample import thin_slices
    from isplat.samples import make_sample

    tag, name, shape, sp, preset, nk_obj = case
    _log(f"{tag}: samples")
    thick, _ = make_sample(name, shape)
    window = WINDOWS.get(name)
    c = channels(thick, sp, window)
    window = c["window"]
    tv, tsp = thin_slices(thick.astype(np.float32), sp)
    thin = channels(tv, tsp, window)
    s0 = min(sp)
    obj_vol, _ = make_sample(name, (shape[0], shape[1], nk_obj))
    obj = channels(obj_vol, (s0, s0, s0), window)
    rows, pics = [], []
    tmp = tempfile.TemporaryDirectory()
    aug = Path(tmp.name) / "scene.aug.h5"       # the scene's presets read their data units (or, MRI, the
    _write_aug(aug, c["raw"], name)             # histogram they are placed on) through this file
    for view in views:
        _log(f"{tag}: {view}")
        sc = scene(aug, preset, view, size)
        imgs = {"before": render_with(sc, c, False), "after": render_with(sc, c, True),
                "thin_before": render_with(sc, thin, False), "thin": render_with(sc, thin, True),
                "object_before": render_with(sc, obj, False), "object": render_with(sc, obj, True)}
        period = max(sp) / pixel_size(sc, c)
        ref = {"before": "object_before", "thin_before": "object_before"}
        keys = ("before", "after", "thin_before", "thin")
        phase = surface_phase(sc, obj, c, level(sc))
        row = dict(case=tag, view=view, preset=preset, spacing=sp, thin_spacing=tsp, period_px=period,
                   rmse={k: rmse(imgs[k], imgs[ref.get(k, "object")]) for k in keys},
                   streak={k: streak(imgs[k], phase, period) for k in keys + ("object_before", "object")},
                   objects=rmse(imgs["object_before"], imgs["object"]))
        if view == "side":
            row["band"] = {k: band_energy(imgs[k], period) for k in keys + ("object_before", "object")}
        if view == "oblique" and rounds:
            row["timing"] = ns_per_sample(sc, c, rounds)
            _log(f"{tag}: {row['timing']['before']:.1f} -> {row['timing']['after']:.1f} ns per sample")
        rows.append(row)
        pics.append([imgs["before"], imgs["after"], imgs["thin"], imgs["object"]])
    _write_png(img_dir / f"thick-{tag}.png", pics)
    tmp.cleanup()
    return rows


def _write_aug(path: Path, o: dict, name: str):
    from isplat.augfile import write_augmented

    attrs = {"source": f"isplat sample {name}"}
    if name.startswith("ct-"):
        attrs["density_units"] = "HU"
    write_augmented(path, o["density"], o["gradient_magnitude"], o["normal"], o["spacing_ijk"], o["density_window"],
                    o["gradient_magnitude_scale"], attrs)


def _write_png(path: Path, pics):
    import imageio.v3 as iio

    grid = np.concatenate([np.concatenate([np.clip(p[..., :3], 0, 1) for p in row], 1) for row in pics], 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, (grid * 255 + 0.5).astype(np.uint8))


def run(out_dir: Path, quick: bool) -> Path:
    t0 = time.perf_counter()
    size = 160 if quick else SIZE
    cases = CASES[:1] if quick else CASES
    rows, costs = [], {}
    for case in cases:
        rows += run_case(case, list(VIEWS), size, Path(out_dir) / "img", 2 if quick else ROUNDS)
        tag, name, shape, sp = case[:4]
        if not quick:
            costs[tag] = thin_cost(name, shape, sp, WINDOWS.get(name))
    path = Path(out_dir) / "thick-slices.md"
    path.write_text(render_doc(rows, costs, size, quick, time.perf_counter() - t0))
    return path


def _f(x, n=4):
    return "" if x is None else f"{x:.{n}f}"



def _sp(sp) -> str:
    return " x ".join(f"{s:g}" for s in sp)


def _get(rows, case, view):
    return next((r for r in rows if r["case"] == case and r["view"] == view), None)


def render_doc(rows, costs, size, quick, seconds) -> str:
    L = ["```", "python -m benchmarks thick" + (" --quick" if quick else ""), "```", "",
         "# Thick slices: rings, terraces and streaks, their cause and their fix", "",
         f"Measured on {_doc.machine_line()}; {seconds:.0f} s. Every picture and number: isplat's default technique, "
         f"**post-classified** splatting (`render.classification = \"post\"`), {size} x {size}, orthographic, "
         "shaded (examples/ct-preset.toml's lights and Phong terms), early termination at its default. Each case is "
         "an isplat sample made with thick slices (`isplat sample NAME --shape ...`, augmented with `--spacing`) and "
         "the same sample made with slices as thin as its pixels, the *object* (the samples are painted in "
         "normalised coordinates: the same object). Columns of each picture: *before* (the sampler's shading as "
         "isplat had it: each quad corner's Phong factors weighted bilinearly), *after* (the default now: weighted "
         "by the bilinear weight times the corner's gradient magnitude, isplat/splat/post.py `_sample`), *thin* "
         "(`isplat augment --thin-slices`, rendered as *after*), the *object* (as *after*). Rows: the side view "
         "(azimuth 90, elevation 0: the slices are horizontal), then the oblique view (azimuth 45, elevation 25). "
         "Both columns use the same file (normals smoothed along the thin axes above 4:1, "
         "`isplat.augment.normal_sigmas`); only the sampler differs.", ""]
    for tag in dict.fromkeys(r["case"] for r in rows):
        L += [f"![{tag}](img/thick-{tag}.png)", "",
              f"`img/thick-{tag}.png` (post-classified): before, after, thin, object; side, then oblique.", ""]
    L += ["## Streaks, measured", "",
          "*streak*: how much the picture's fine shading depends on where the surface lies between two thick "
          "slices (`streak` in benchmarks/thick.py): per pixel, the first point of the object's surface (the "
          "density where the preset's opacity reaches half its top) along the ray gives the phase 0..1 between "
          "two thick slices; the high-frequency luminance (luminance minus its Gaussian blur of sigma two slice "
          "periods in pixels) is averaged per eighth of that phase, and the streak is the RMS of those eight means. "
          "Rings, terraces and streaks are locked to the slices and make the eighths differ; the shapes' own "
          "shading and the object's fine detail are not, and average out: the object's own value (rendered with "
          "the same phases) is the floor. *RMSE*: over RGB against the object, each column against the object "
          "rendered by the same sampler (*before* and *thin before* against the object shaded as before); "
          "*objects*: RMSE between the object shaded before and after (what the change does on thin slices). "
          "*band* (side views): RMS over the image's rows of the row's mean luminance minus its running mean over "
          "one slice period (the object's own is the floor).", "",
          "| case | preset | spacing (mm) | view | streak before | after | thin before | thin | object | RMSE "
          "before | after | thin before | thin | objects | band before | after | thin | object |",
          "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        s, e, b = r["streak"], r["rmse"], r.get("band")
        L.append(f"| {r['case']} | {r['preset']} | {_sp(r['spacing'])} | {r['view']} | {_f(s['before'])} | "
                 f"**{_f(s['after'])}** | {_f(s['thin_before'])} | {_f(s['thin'])} | {_f(s['object'])} | {_f(e['before'])} | "
                 f"**{_f(e['after'])}** | {_f(e['thin_before'])} | {_f(e['thin'])} | {_f(r['objects'])} | " +
                 (f"{_f(b['before'])} | **{_f(b['after'])}** | {_f(b['thin'])} | {_f(b['object'])} |" if b
                  else "| | | |"))
    timed = [r for r in rows if "timing" in r]
    if timed:
        L += ["", "## What the weighting costs", "",
              f"The oblique view of each case rendered in {timed[0]['timing']['rounds']} interleaved rounds, before "
              "and after in turn, the order swapped every round (one process, the same selection; `isplat.splat.post.WEIGHTED_SHADING` switches "
              "the sampler), after a warm-up frame of each: the median frame time (the whole frame: traversal and set-up included) over the samples composited. "
              "After reads the gradient magnitude channel too (1 byte per voxel more in memory and read from the "
              "file when shaded).", "",
              "| case | samples | ms before | ms after | ns per sample before | after | after / before |",
              "|---|---:|---:|---:|---:|---:|---:|"]
        for r in timed:
            t = r["timing"]
            L.append(f"| {r['case']} | {t['samples']:,} | {t['seconds_before'] * 1e3:.1f} | "
                     f"{t['seconds_after'] * 1e3:.1f} | {t['before']:.1f} | {t['after']:.1f} | "
                     f"{t['after'] / t['before']:.2f} |")
    if costs:
        L += ["", "## What `--thin-slices` costs", "",
              "`isplat augment` of the thick sample (a .npy) as it is and with `--thin-slices` (`/usr/bin/time`: "
              "wall seconds, peak resident memory; the augmented file's size; the index comes on top, about in "
              "proportion).", "",
              "| case | spacing (mm) -> thin | seconds | thin | peak MB | thin | file MB | thin |",
              "|---|---|---:|---:|---:|---:|---:|---:|"]
        for r in rows:
            if r["case"] not in costs or r["view"] != "side":
                continue
            c = costs[r["case"]]
            L.append(f"| {r['case']} | {_sp(r['spacing'])} -> {_sp(r['thin_spacing'])} | "
                     f"{c['as_is']['seconds']:.2f} | {c['thin']['seconds']:.2f} | {c['as_is']['rss_mb']:.0f} | "
                     f"{c['thin']['rss_mb']:.0f} | {c['as_is']['file_mb']:.1f} | {c['thin']['file_mb']:.1f} |")
        ratios = [(c["thin"]["seconds"] / c["as_is"]["seconds"], c["thin"]["rss_mb"] - c["as_is"]["rss_mb"],
                   c["thin"]["file_mb"] / c["as_is"]["file_mb"]) for c in costs.values()]
        L += ["", f"With `--thin-slices`: {min(r[0] for r in ratios):.2f}-{max(r[0] for r in ratios):.2f} times the "
              f"seconds, {min(r[1] for r in ratios):.0f}-{max(r[1] for r in ratios):.0f} MB more peak memory, "
              f"{min(r[2] for r in ratios):.1f}-{max(r[2] for r in ratios):.1f} times the file."]
    L += ["", reading(rows, costs), ""]
    return "\n".join(L)


def reading(rows, costs) -> str:
    """The page's reading: the causes (from the earlier runs of this page, named by commit) and, with this run's
    numbers, what the fix does."""
    out = ["## Reading", "",
           "**What makes the rings and terraces.** The earlier runs of this page (git log docs/thick-slices.md; "
           "b27b5b8 measured them with a converged ray caster and unshaded renders) found two causes on shaded "
           "opaque surfaces, and neither the opacity correction nor the density's linear interpolation between "
           "slices: (1) the normals, central differences spanning two in-slice voxels but two thick slices, which "
           "swing slice by slice; fixed before this run by smoothing the density along the thin axes before the "
           "differences above 4:1 (`isplat.augment.normal_sigmas`); (2) the sampler's shading, here: it mixed the "
           "four corners' Phong factors with the bilinear weights only, so where a surface is nearly parallel to "
           "the slices (the top of the skull) a corner just off the surface (air or soft tissue, a short gradient "
           "whose direction is mostly along the slice axis) shades as much as the corner on it, and the shading "
           "jumps each time the surface crosses a slice: rings. Weighting each corner by its gradient magnitude "
           "too lets the corners on the surface give its shading.", ""]
    items = []
    for r in rows:
        s, e = r["streak"], r["rmse"]
        items.append(f"- *{r['case']}*, {r['view']}: streak {s['before']:.4f} -> {s['after']:.4f} "
                     f"({(s['after'] / s['before'] - 1) * 100 if s['before'] else 0:+.0f}%; object "
                     f"{s['object']:.4f}), RMSE {e['before']:.4f} -> "
                     f"{e['after']:.4f}" + (f"; band {r['band']['before']:.4f} -> {r['band']['after']:.4f} (object "
                                             f"{r['band']['object']:.4f})" if "band" in r else "") + ".")
    out += ["**This run, before -> after** (each against the object rendered by the same sampler):", ""] + items
    mr = [r for r in rows if r["case"].startswith("mr-")]
    if mr:
        out += ["", "The *MRI head* (semi-transparent, a colour ramp over a bright scalp thinner than a slice) keeps "
                "terraces after the weighting: the earlier runs found them in the unshaded renders too, so they come "
                "from the density's linear interpolation between 7 mm slices (a shell thinner than a slice "
                "cross-fades between slices), which shading cannot remove; a reconstruction across slices that "
                "follows the edges (shape-based interpolation) would be needed, in the sampler. Not built."]
    near = [r for r in rows if r["streak"]["before"] <= 1.2 * r["streak"]["object"]]
    if near:
        out += ["", "Already within 20% of the object's own streak before the change (nothing locked to the "
                "slices to remove): " + ", ".join(f"{r['case']} {r['view']}" for r in near) + "."]
    thin = [r for r in rows if r["streak"]["thin"] < 0.95 * r["streak"]["after"]]
    out += ["", f"**`--thin-slices`** lowers the streak measure more than 5% below *after* in {len(thin)} of the "
            f"{len(rows)} views above" + (" (" + ", ".join(f"{r['case']} {r['view']}" for r in thin) + ")" if thin else "") +
            "; it stores the linear interpolation between slices that the post-classified sampler already "
            "computes, so it cannot remove what that interpolation makes, and its normals, differenced over a "
            "linear ramp, are no better. Its cost is in the table above (file and memory grow with the factor of "
            "thinning, since the volume is held in memory). It stays for pre-classified splatting "
            "(`render.classification = \"pre\"`), where docs/sheets.md measures it closer to the trilinear field."]
    return "\n".join(out)
