"""Thick slices: what makes the terraces and streaks on shaded renders of 2.5-7 mm slices, and their fix.

``python -m benchmarks thick [--quick]`` writes docs/thick-slices.md and the pictures docs/img/thick-*.png.

Each case is a sample made with few, thick slices (``isplat sample NAME --shape NI,NJ,NK`` and ``--spacing``), and
the same sample made with slices as thin as its pixels (the *object*, the reference the pictures are compared
against: the samples are painted in normalised coordinates, so both are the same object). Rendered with isplat's
default technique (scene version 4, post-classified), shaded, orthographic, from the side (the thick axis vertical
in the image, the view along i) and obliquely, with:

* *before*: the normals as isplat made them before this page: central differences of the windowed density
  (``augment_array(..., smooth_normals=False)``);
* *after*: the default now (:func:`isplat.augment.normal_sigmas`: on slices more than ``NORMAL_RATIO`` times
  thicker than the pixels the density is smoothed along the thinner axes before the normals' differences);
* *forced*: that smoothing at any ratio (for the cases below ``NORMAL_RATIO``: what it would do there);
* *thin*: ``isplat augment --thin-slices`` (linear interpolation along the thick axis first);
* the *object*, made with thin slices.

Measures: RMSE over RGB against the object; the *band energy* of a side view (the RMS over image rows of the
row's mean luminance minus its running mean over one slice period: what repeats slice by slice); and, for the
side views, a converged ray caster (tests/ray_reference.py, step 0.25 of the smallest spacing, normals
interpolated as vectors) on the thick data with each set of normals, which separates the normals from isplat's
sampler; and the same renders unshaded, which separates shading from the reconstruction of the density.
``--thin-slices``'s cost is measured on the command line (``isplat augment``, /usr/bin/time).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import _doc

TECHNIQUES = ["post"]
SOURCES = _doc.sources(_doc.RENDER, _doc.AUGMENT, _doc.SAMPLES, ("isplat/resample.py", "benchmarks/thick.py",
                                                                  "tests/ray_reference.py", "examples/ct-preset.toml"))
REPO = Path(__file__).resolve().parents[1]
SIZE = 320
# name, sample, thick shape (NI, NJ, NK), spacing (i, j, k), preset, object's NK (slices of the in-plane spacing)
CASES = [
    ("ct-head-7mm", "ct-head", (256, 256, 32), (1.0, 1.0, 7.0), "ct-bone", 224),
    ("mr-head-7mm", "mr-head", (256, 256, 32), (1.0, 1.0, 7.0), "mri-t1-head", 224),
    ("ct-chest-2.5mm", "ct-chest", (256, 192, 72), (0.7, 0.7, 2.5), "ct-bone", 257),
    ("ct-chest-2.5mm-soft", "ct-chest", (256, 192, 72), (0.7, 0.7, 2.5), "ct-soft-tissue", 257),
]
VIEWS = {"side": (90.0, 0.0), "oblique": (45.0, 25.0)}
PROTOTYPE = ("ct-head-7mm", "mr-head-7mm", "ct-chest-2.5mm-soft")     # cases that also get the sampler's shading prototyped (phong_factor_render)
WINDOWS = {"ct-head": (-1024.0, 3071.0), "ct-chest": (-1024.0, 3071.0)}


def _log(msg):
    print(f"[thick] {msg}", file=sys.stderr, flush=True)


def _rr():
    if str(REPO / "tests") not in sys.path:
        sys.path.insert(0, str(REPO / "tests"))
    import ray_reference

    return ray_reference


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


def ray_reference(sc, c, smooth_normals: bool, step=0.25) -> np.ndarray:
    """The converged ray caster on the thick data, its normals central differences of the density codes, or of
    the codes smoothed as :func:`isplat.augment.normal_sigmas` says (``smooth_normals``)."""
    from isplat.augment import _smooth_axis, normal_sigmas
    from isplat.frame import views_for

    rr = _rr()
    sel = _selection(sc, c)
    view = views_for(sc, sel)[0]
    orig = rr.central_gradient
    sig = normal_sigmas(c["spacing"], ratio=1.0) if smooth_normals else None

    def grad(vol, spacing):
        v = np.asarray(vol, np.float32)
        if sig is not None:
            for axis, s in enumerate((sig[2] / spacing[2], sig[1] / spacing[1], sig[0] / spacing[0])):
                v = _smooth_axis(v, s, axis)
        return orig(v, spacing)

    rr.central_gradient = grad
    try:
        unit = sc.transfer.unit_distance or float(view.geom.spacing.min())
        return rr.render(view, sc.transfer, sc.shading, density=c["density"], unit=unit, step=step)
    finally:
        rr.central_gradient = orig


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


def run_case(case, views, size, img_dir: Path, refs: bool):
    from isplat.resample import thin_slices
    from isplat.samples import make_sample

    tag, name, shape, sp, preset, nk_obj = case
    _log(f"{tag}: samples")
    thick, _ = make_sample(name, shape)
    window = WINDOWS.get(name)
    before = channels(thick, sp, window, smooth_normals=False)
    window = before["window"]
    after = channels(thick, sp, window)
    forced = channels(thick, sp, window, forced=True)
    tv, tsp = thin_slices(thick.astype(np.float32), sp)
    thin = channels(tv, tsp, window)
    s0 = min(sp)
    obj_vol, _ = make_sample(name, (shape[0], shape[1], nk_obj))
    obj = channels(obj_vol, (s0, s0, s0), window)
    rows, pics, proto_pics = [], [], []
    tmp = tempfile.TemporaryDirectory()
    aug = Path(tmp.name) / "scene.aug.h5"       # the scene's presets read their data units through its window
    _write_aug(aug, before["raw"], name)
    for view in views:
        _log(f"{tag}: {view}")
        sc = scene(aug, preset, view, size)
        imgs = {k: render(sc, c) for k, c in (("before", before), ("after", after), ("forced", forced), ("thin", thin),
                                              ("object", obj))}
        period = max(sp) / pixel_size(sc, before)
        row = dict(case=tag, view=view, preset=preset, spacing=sp, thin_spacing=tsp,
                   rmse={k: rmse(v, imgs["object"]) for k, v in imgs.items() if k != "object"},
                   band={k: band_energy(v, period) for k, v in imgs.items()})
        if view == "side":
            scu = scene(aug, preset, view, size, shaded=False)
            un = {k: render(scu, c) for k, c in (("before", before), ("after", after), ("object", obj))}
            row["band_unshaded"] = {k: band_energy(v, period) for k, v in un.items()}
            if refs:
                t0 = time.perf_counter()
                for key, smooth in (("ray_before", False), ("ray_after", True)):
                    ref = ray_reference(sc, before, smooth)
                    row["band"][key] = band_energy(ref, period)
                    row["rmse"][key] = rmse(ref, imgs["object"])
                    row.setdefault("ray_vs_isplat", {})[key] = rmse(ref, imgs["before" if not smooth else "forced"])
                _log(f"{tag}: ray references {time.perf_counter() - t0:.0f} s")
        if tag in PROTOTYPE and refs:
            t0 = time.perf_counter()
            proto = {k: phong_factor_render(sc, after, k == "weighted") for k in ("unweighted", "weighted")}
            row["proto"] = {k: dict(rmse=rmse(v, imgs["object"]), band=band_energy(v, period),
                                    vs_isplat=rmse(v, imgs["after"])) for k, v in proto.items()}
            proto_pics.append([imgs["after"], proto["unweighted"], proto["weighted"], imgs["object"]])
            _log(f"{tag}: sampler prototypes {time.perf_counter() - t0:.0f} s")
        rows.append(row)
        pics.append([imgs["before"], imgs["after"], imgs["thin"], imgs["object"]])
    _write_png(img_dir / f"thick-{tag}.png", pics)
    if proto_pics:
        _write_png(img_dir / f"thick-{tag}-sampler.png", proto_pics)
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
    views = ["side"] if quick else list(VIEWS)
    rows, costs = [], {}
    for case in cases:
        rows += run_case(case, views, size, Path(out_dir) / "img", refs=not quick)
        tag, name, shape, sp = case[:4]
        if tag.endswith("soft") or quick:
            continue
        costs[tag] = thin_cost(name, shape, sp, WINDOWS.get(name))
    path = Path(out_dir) / "thick-slices.md"
    path.write_text(render_doc(rows, costs, size, quick, time.perf_counter() - t0))
    return path


def _f(x, n=4):
    return "" if x is None else f"{x:.{n}f}"


def render_doc(rows, costs, size, quick, seconds) -> str:
    L = ["```", "python -m benchmarks thick" + (" --quick" if quick else ""), "```", "",
         "# Thick slices: terraces and streaks, their cause and their fix", "",
         f"Measured on {_doc.machine_line()}; {seconds:.0f} s. Pictures {size} x {size}, orthographic, shaded "
         "(examples/ct-preset.toml's lights and Phong terms), the default technique (scene version 4, "
         "post-classified), early termination at its default. Each case is an isplat sample made with thick slices "
         "(`isplat sample NAME --shape ...`, augmented with `--spacing`) and the same sample made with slices as "
         "thin as its pixels, the *object* (the samples are painted in normalised coordinates: the same object). "
         "Columns of each picture: *before* (normals of plain central differences, as isplat made them before), "
         "*after* (the default now: `isplat.augment.normal_sigmas`), *thin* (`isplat augment --thin-slices`), "
         "the *object*. Rows: the side view (azimuth 90, elevation 0: the slices are horizontal), then the "
         "oblique view (azimuth 45, elevation 25).", ""]
    for tag in dict.fromkeys(r["case"] for r in rows):
        L += [f"![{tag}](img/thick-{tag}.png)", "", f"`img/thick-{tag}.png`", ""]
    L += ["## Error against the object", "",
          "RMSE over RGB against the object; *band*: the band energy of the side view (RMS over the image's rows "
          "of the row's mean luminance minus its running mean over one slice period; the object's own is the floor "
          "what the object's shading and the rings of its in-plane sampling give). *ray*: a converged ray caster "
          "(tests/ray_reference.py, step 0.25 of the smallest spacing) on the same thick densities, its normals "
          "central differences (*before*) or smoothed as *forced*, interpolated as vectors, not as Phong factors.", "",
          "*forced*: the smoothing of *after* applied below its ratio too.", "",
          "| case | preset | spacing (mm) | view | RMSE before | after | forced | thin | ray before | ray after | "
          "band before | after | forced | thin | ray before | ray after | object |",
          "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        e, b = r["rmse"], r["band"]
        side = r["view"] == "side"
        L.append(f"| {r['case']} | {r['preset']} | {' x '.join(f'{s:g}' for s in r['spacing'])} | {r['view']} | "
                 f"{_f(e['before'])} | **{_f(e['after'])}** | {_f(e['forced'])} | {_f(e['thin'])} | "
                 f"{_f(e.get('ray_before'))} | {_f(e.get('ray_after'))} | " + (
                     f"{_f(b['before'])} | **{_f(b['after'])}** | {_f(b['forced'])} | {_f(b['thin'])} | "
                     f"{_f(b.get('ray_before'))} | {_f(b.get('ray_after'))} | {_f(b['object'])} |" if side
                     else "| | | | | | |"))
    L += ["", "Unshaded (the same side views with `shading.enabled = false`): band energy, which shading cannot "
          "cause. *ray vs isplat*: RMSE between the ray caster and isplat with the same normals (*before*, *forced*).", "",
          "| case | band unshaded: before | after | object | ray vs isplat: before | forced |",
          "|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        if "band_unshaded" not in r:
            continue
        u, rv = r["band_unshaded"], r.get("ray_vs_isplat", {})
        L.append(f"| {r['case']} | {_f(u['before'])} | {_f(u['after'])} | {_f(u['object'])} | "
                 f"{_f(rv.get('ray_before'))} | {_f(rv.get('ray_after'))} |")
    proto = [r for r in rows if "proto" in r]
    if proto:
        L += ["", "## The sampler's shading, prototyped", "",
              "isplat's post-classified sampler shades a sample with the bilinear mean of its four voxels' Phong "
              "factors (isplat/splat/post.py, `_sample`). A copy of the ray caster that does the same in 3-D "
              "(trilinear mean of the eight voxels' Phong factors from their oct16 normals, step 1 smallest "
              "spacing: `phong_factor_render`) against one whose means weight each voxel by its gradient magnitude "
              "code (the proposed change), both on the *after* normals:", "",
              "| case | view | RMSE isplat | unweighted | weighted | band isplat | unweighted | weighted | object | "
              "unweighted vs isplat |", "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for r in proto:
            p, e, b = r["proto"], r["rmse"], r["band"]
            L.append(f"| {r['case']} | {r['view']} | {_f(e['after'])} | {_f(p['unweighted']['rmse'])} | "
                     f"**{_f(p['weighted']['rmse'])}** | {_f(b['after'])} | {_f(p['unweighted']['band'])} | "
                     f"**{_f(p['weighted']['band'])}** | {_f(b['object'])} | {_f(p['unweighted']['vs_isplat'])} |")
        for tag in dict.fromkeys(r["case"] for r in proto):
            L += ["", f"![{tag} sampler](img/thick-{tag}-sampler.png)", "",
                  f"`img/thick-{tag}-sampler.png`: isplat *after*, the prototype unweighted (isplat's shading), "
                  "weighted by the gradient magnitude (the proposal), the object; side view, then oblique."]
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
            L.append(f"| {r['case']} | {' x '.join(f'{s:g}' for s in r['spacing'])} -> "
                     f"{' x '.join(f'{s:g}' for s in r['thin_spacing'])} | {c['as_is']['seconds']:.2f} | "
                     f"{c['thin']['seconds']:.2f} | {c['as_is']['rss_mb']:.0f} | {c['thin']['rss_mb']:.0f} | "
                     f"{c['as_is']['file_mb']:.1f} | {c['thin']['file_mb']:.1f} |")
        ratios = [(c["thin"]["seconds"] / c["as_is"]["seconds"], c["thin"]["rss_mb"] - c["as_is"]["rss_mb"],
                   c["thin"]["file_mb"] / c["as_is"]["file_mb"]) for c in costs.values()]
        L += ["", f"With `--thin-slices`: {min(r[0] for r in ratios):.2f}-{max(r[0] for r in ratios):.2f} times the "
              f"seconds, {min(r[1] for r in ratios):.0f}-{max(r[1] for r in ratios):.0f} MB more peak memory, "
              f"{min(r[2] for r in ratios):.1f}-{max(r[2] for r in ratios):.1f} times the file."]
    L += ["", READING, ""]
    return "\n".join(L)


READING = """## Reading

(Written from the run this page was made with; the tables above are regenerated, this text is not.)

**What makes the terraces**, one factor at a time on the side views, where the slices are horizontal lines:

- *Not the sampler's step or its reconstruction of the density, on an opaque surface.* A converged ray caster
  (0.25 mm steps, normals interpolated as vectors) on the same thick densities and normals shows the bands too
  (7 mm CT head, bone: band energy 0.0033, isplat 0.0043, the object 0.0027). The same views unshaded have the
  object's band energy (0.0030 against 0.0036), so neither the density's linear interpolation between slices nor
  the opacity correction makes them there (in a side view isplat samples the thin slices, 1 mm apart).
- *The normals.* Central differences span two in-slice voxels (2 mm) but two slices (14 mm): where a surface
  crosses a slice the in-slice part of the gradient is large, half-way between slices (where the voxels of both
  slices lie off the surface) small, so the normal's direction swings slice by slice. Smoothing the density
  along the thinner axes before the differences (*after*: a Gaussian of 0.5 sqrt(s_max^2 - s_a^2), 3.5 mm for
  1 x 1 x 7; `isplat.augment.normal_sigmas`) brings the band energy to the object's: 0.0043 -> 0.0027 (object
  0.0027); RMSE 0.0360 -> 0.0359 (side), 0.0437 -> 0.0422 (oblique). On a smooth ball sampled 1 x 1 x 7 the
  normals come closer to the analytic ones (tests/test_augment.py).
- *What remains on the CT head* (rings on the top of the skull in the oblique view, where the surface is nearly
  parallel to the slices): the sampler's shading. It averages the four voxels' Phong factors with the bilinear
  weights only, so a voxel just outside the surface (air: a short gradient, and a direction that is mostly the
  surface's along k only) counts as much as the voxel on the surface. The prototype that weights each voxel's
  Phong factors by its gradient magnitude as well removes the rings (picture above; RMSE 0.0421 -> 0.0410
  oblique, side band 0.0028 -> 0.0023). On the MRI head it changes little (RMSE 0.0593 -> 0.0581 side, 0.0737 ->
  0.0738 oblique), and on the chest's soft tissue, whose object is shaded by isplat's unweighted mean too, the
  error grows a little (0.0145 -> 0.0152 side, 0.0189 -> 0.0198 oblique). The change belongs in
  isplat/splat/post.py's `_sample` and is described in docs/design.md; not made here (isplat/splat is being
  restructured), and to be measured on docs/accuracy.md's cases when made.
- *The MRI head* (semi-transparent, a colour ramp, a bright scalp thinner than a slice): mostly the density's
  reconstruction. Unshaded its band energy is 0.0195 against the object's 0.0112, and the converged ray caster
  has the bands too. The smoothed normals lower the band energy 0.0151 -> 0.0138 and the RMSE 0.0625 -> 0.0602
  (side), 0.0798 -> 0.0739 (oblique), but the terraces stay visible: linear interpolation between 7 mm slices
  cross-fades a shell thinner than a slice and edges that move further from one slice to the next than they are
  wide. Removing them needs a reconstruction across slices that follows the edges (shape-based interpolation), in
  the sampler; not built.
- *The chest at 0.7 x 0.7 x 2.5 mm* has no terraces to remove: its band energies are the object's in every column
  (0.0023 bone, 0.0039 soft tissue), and its vertical texture is the sample's noise interpolated along the slices,
  at every column alike. Smoothing there (*forced*) would double the error (0.0080 -> 0.0181 bone, 0.0139 -> 0.0264
  soft tissue): in noisy tissue it takes away the in-slice noise of the gradient but not the noise between slices,
  and the normals turn along the slices (speckle on the soft tissue). So the smoothing starts above 4:1
  (`NORMAL_RATIO`); at 3.6:1 the chest's normals, and its pictures before and after, are the same. A sweep on the
  CT head, not kept as a benchmark: 2.5 mm slices (2.5:1) no band to remove; 4 mm slices (4:1) band 0.0029 ->
  0.0021 (object 0.0022) but RMSE 0.0266 -> 0.0274 (bone) and 0.0183 -> 0.0220 (the ct-skin preset), so 4:1 is
  left out.

**Cost of the fix**: augmenting the 7 mm samples smooths one extra float slab per slab (two more passes of a
Gaussian along i and j): `augment_array` of the 7 mm MRI head took 0.78 s against 0.39 s without it (one run, in
process). The file, the index and the frames are unchanged in size and time; isotropic scans and slices up to 4
times thicker than the pixels get bit-identical files.

**`--thin-slices`** (linear interpolation along the thick axis before augmenting) lowered the error in one of the
eight views above (the chest's soft tissue, oblique: 0.0159 against 0.0193) and raised it in the others (7 mm CT
head 0.0402 against 0.0360, MRI head 0.0688 against 0.0625, chest bone 0.0088 against 0.0080, side views); it
removed no band. The default, post-classified sampler already interpolates linearly between slices, which is what
`--thin-slices` stores, and the normals of the interpolated slices, differenced over 1.75 mm of a linear ramp, are
noisier. Its cost (table above): 4 times the file at 7 mm (8.4 -> 33.3 MB), 2 times at 2.5 mm, more augment time
and peak memory (the ratios under the table; the times are whole processes, start-up included, and vary with the
machine's load between runs), growing with the scan, since the volume is held in memory (1.5 GiB on the issue's
chest). It stays for pre-classified splatting (`render.classification = "pre"`),
where docs/sheets.md measures it 5-12 times closer to the trilinear field; `isplat augment`'s line about thick
slices and its `--help` now say so.
"""


# ---- the sampler's shading, prototyped in a ray caster (issue 28: a proposal for isplat/splat/post.py) -------------
def _factor_integrator():
    """A copy of tests/ray_reference.py's integrator (GRID, orthographic) that shades each sample with the
    trilinear interpolation of the eight voxels' Phong factors, each weighted by ``wgt`` (all ones: what
    isplat's post-classified sampler does, per slice; the gradient magnitudes: the proposal)."""
    import math

    import numba

    rr = _rr()
    trilinear, pwl, box_range = rr._trilinear, rr._pwl, rr._box_range

    @numba.njit(parallel=True, nogil=True)
    def integrate(vol, fac, wgt, orig, dirs, t_lo, n, step, ox, oy, cx, cy, unit, out):
        for r in numba.prange(orig.shape[0]):
            o = orig[r]
            d = dirs[r]
            t0, t1 = box_range(o, d, n, t_lo[r])
            acc = np.zeros(3)
            T = 1.0
            if t1 > t0:
                nseg = max(1, int(math.ceil((t1 - t0) / step)))
                dt = (t1 - t0) / nseg
                for m in range(nseg):
                    t = t0 + (m + 0.5) * dt
                    gi, gj, gk = o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]
                    dens = trilinear(vol, gi, gj, gk)
                    a = pwl(ox, oy, dens, True)
                    if a <= 0.0:
                        continue
                    alpha = -math.expm1(math.log1p(-min(a, 1.0 - 2.0 ** -40)) / unit * dt)
                    w = trilinear(wgt, gi, gj, gk)
                    for ch in range(3):
                        c = pwl(cx, cy[:, ch], dens, False)
                        if w > 0.0:
                            c = c * trilinear(fac[ch], gi, gj, gk) / w + trilinear(fac[3 + ch], gi, gj, gk) / w
                        acc[ch] += T * alpha * c
                    T *= 1.0 - alpha
                    if T < 1e-9:
                        break
            out[r, 0], out[r, 1], out[r, 2], out[r, 3] = acc[0], acc[1], acc[2], 1.0 - T
    return integrate


def phong_factor_render(sc, c, weighted: bool, step: float = 1.0) -> np.ndarray:
    """The thick data ``c`` rendered by :func:`_factor_integrator` with ``c``'s own (oct16) normals: per voxel
    the Phong factors of its decoded normal, interpolated unweighted (isplat's sampler) or weighted by the
    gradient magnitude codes (the proposal)."""
    from isplat.frame import views_for
    from isplat.normals import decode
    from isplat.splat.composite import finish

    rr = _rr()
    sel = _selection(sc, c)
    view = views_for(sc, sel)[0]
    f, g = view.frame, view.geom
    sh = sc.shading
    lights = rr.light_rows(sh, f, g)
    shv = np.array([sh.ambient, sh.diffuse, sh.specular, sh.shininess, 1.0 if sh.two_sided else 0.0])
    nrm = decode(c["normal"]).astype(np.float64)
    fac = np.empty((6,) + c["normal"].shape)
    flat = nrm.reshape(-1, 3)
    table = {}
    out6 = fac.reshape(6, -1)
    codes = c["normal"].ravel()
    for code in np.unique(codes):                  # one Phong evaluation per distinct code
        table[int(code)] = rr._phong(*map(float, decode(np.array([code]))[0]), lights, shv)
    lut = np.zeros((65536, 6))
    for code, v in table.items():
        lut[code] = v
    out6[:] = lut[codes].T
    wgt = c["gm"].astype(np.float64) if weighted else np.ones(c["gm"].shape)
    fac *= wgt[None]
    op, col = np.asarray(sc.transfer.opacity, float), np.asarray(sc.transfer.color, float)
    o, d, t_lo = rr.rays(view)
    out = np.empty((len(o), 4))
    vol = np.ascontiguousarray(c["density"], np.float32)
    _factor_integrator()(vol, np.ascontiguousarray(fac), np.ascontiguousarray(wgt), o, d, t_lo,
                         np.asarray(g.n_ijk, float), float(step) * float(g.spacing.min()),
                         np.ascontiguousarray(op[:, 0]), np.ascontiguousarray(op[:, 1]),
                         np.ascontiguousarray(col[:, 0]), np.ascontiguousarray(col[:, 1:4]),
                         float(sc.transfer.unit_distance or g.spacing.min()), out)
    img = out.reshape(f.height, f.width, 4)
    rgba = np.empty_like(img)
    finish(img, np.asarray(view.background, dtype=np.float64), rgba)
    return rgba
