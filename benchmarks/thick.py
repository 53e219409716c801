"""Thick slices: what makes the rings, terraces and streaks on shaded renders of 2.5-7 mm slices, and their fix.

``python -m benchmarks thick [--quick]`` writes docs/thick-slices.md and the pictures docs/img/thick-*.png.

Each case is a sample made with few, thick slices (``isplat sample NAME --shape NI,NJ,NK`` and ``--spacing``), and
the same sample made with slices as thin as its pixels (the *object*, the reference the pictures are compared
against: the samples are painted in normalised coordinates, so both are the same object). Rendered with isplat's
default technique (post-classified), shaded, orthographic, from the side (the thick axis vertical in the image,
the view along i) and obliquely, with the post-classified sampler's reconstruction between slices *before*
(linear: the quad's bilinear density and Phong factors, ``isplat.splat.post.BETWEEN_SLICES = "linear"``) and
*after* (the default: the interpolating cubic spline of the density along the thick axis, the Phong factors with
the cubic B-spline's weights along it), the *monotone* cubic and *corners* (the cubic density, the quad's corners' shading,
``SHADE_BETWEEN = False``), measured, not the default, and *thin* (``isplat augment --thin-slices``). The shading's corners are weighted by their gradient magnitudes in all
(``isplat.splat.post.WEIGHTED_SHADING``, an earlier run of this page).

Measures: the *streak* strength (:func:`streak`: the high-frequency luminance's difference from the object's),
RMSE over RGB against the object, the *band energy* of a side view (:func:`band_energy`), the sampler's cost in ns
per sample (interleaved rounds, :func:`ns_per_sample`), ``--thin-slices``'s cost on the command line
(``isplat augment``, /usr/bin/time), and the streak of linear and cubic against the grid's anisotropy
(:data:`RATIO_CASES`: where ``isplat.splat.post.THICK_RATIO`` is set). The maximum-intensity projection of
:data:`MIP_CASE` (``render.mode = "mip"``), linear and cubic between slices, against its object: streak, RMSE,
band and cost (:func:`mip_rows`). A sphere label on 7 mm slices (:func:`label_rows`): its terraces, and whether the
cubic would move its boundary (:func:`label_mismatch`). The 7 mm cases (:data:`BEST_CASES`) also resampled to
the object's grid by the best standard interpolators from the thick data alone (:func:`best_effort_images`,
benchmarks/_thick_resample.py: B-splines of degree 3 and 5, Lanczos-3, the Catmull-Rom cubic as a copy, and copies
with the default's own shading) and rendered by the default: whether any reconstruction from the same slices
comes nearer the object than the default (:func:`best_section`, its sentences computed from the numbers), with
a column of the pictures for the copy nearest the object.
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

TECHNIQUES = ["post", "mip"]
SOURCES = _doc.sources(_doc.RENDER, _doc.AUGMENT, _doc.SAMPLES, ("isplat/resample.py", "benchmarks/thick.py",
                                                                  "benchmarks/_thick_resample.py",
                                                                  "isplat/labels.py", "isplat/label_select.py",
                                                                  "tests/streak_measure.py",
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
# the sampler's settings compared (isplat.splat.post's module attributes): before, after (the defaults), monotone
SETTINGS = {"before": {"BETWEEN_SLICES": "linear"}, "after": {}, "monotone": {"BETWEEN_SLICES": "monotone"},
            "corners": {"SHADE_BETWEEN": False}}


def _kind_text() -> str:
    """The default's density between thick slices, in words (``isplat.splat.post.BETWEEN_SLICES``)."""
    from isplat.splat import post

    return {"b-spline": "the interpolating cubic spline (the cubic B-spline through prefiltered coefficients, its "
                        f"kernel cut to {post.SPLINE_REACH} slices each way, `BETWEEN_SLICES = \"b-spline\"`)",
            "catmull-rom": "a Catmull-Rom cubic through four slices (`BETWEEN_SLICES = \"catmull-rom\"`)",
            "monotone": "the monotone cubic (`BETWEEN_SLICES = \"monotone\"`)"}.get(post.BETWEEN_SLICES,
                                                                                  post.BETWEEN_SLICES)
# the mr-head sample at these slice spacings (1 x 1 x R mm, 224 / R slices), linear and cubic between slices, the
# cubic forced at every ratio: what the cubic gains against the anisotropy (isplat.splat.post.THICK_RATIO)
RATIO_CASES = (1.5, 2.0, 3.0, 5.0, 7.0)
# the case the maximum-intensity projection is measured on (mip_rows), as CASES
MIP_CASE = CASES[3]
# the label measured between thick slices (label_rows): a sphere's radius (mm), its centre's offset along the thick
# axis (mm), the grid's in-slice voxels (1 mm each; the thick grid has n / 7 slices of 7 mm)
LABEL_SPHERE = (45.0, 2.6, 126)
# the cases resampled to the object's grid by the best standard reconstructions from the thick data alone
# (best_effort_images, benchmarks/_thick_resample.py), and those reconstructions
BEST_CASES = ("ct-head-7mm", "mr-head-7mm")
BEST_METHODS = ("bspline3", "bspline5", "lanczos3", "catmull-rom", "bspline3+shading", "catmull-rom+shading")
ROUNDS = 41               # interleaved rounds of the timing (ns_per_sample; frames of 10-50 ms on a shared machine)
WINDOWS = {"ct-head": (-1024.0, 3071.0), "ct-chest": (-1024.0, 3071.0)}


def _log(msg):
    print(f"[thick] {msg}", file=sys.stderr, flush=True)


def scene(aug: Path, preset: str, view: str, size: int, shaded: bool = True, mode: str | None = None):
    """The scene of examples/ct-preset.toml with ``preset`` (in data units: read through ``aug``'s window);
    ``mode`` a ``render.mode`` ("mip": the maximum-intensity projection, scene version 6)."""
    from isplat.scene import load_scene

    az, el = VIEWS[view]
    ov = [f'data.augmented="{aug}"', f"image.width={size}", f"image.height={size}", f'transfer.preset="{preset}"',
          f"camera.azimuth={az}", f"camera.elevation={el}", 'camera.projection="orthographic"']
    if not shaded:
        ov.append("shading.enabled=false")
    if mode is not None:
        ov += ["version=6", f'render.mode="{mode}"']
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


def _sampler(setting: dict) -> dict:
    """Set the post-classified sampler's module attributes (a :data:`SETTINGS` entry); returns the previous ones."""
    from isplat.splat import post

    old = {k: getattr(post, k) for k in setting}
    for k, v in setting.items():
        setattr(post, k, v)
    return old


def render_with(sc, c, key: str) -> np.ndarray:
    old = _sampler(SETTINGS[key])
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


def interleaved(sc, c, keys, rounds: int) -> tuple[dict, dict]:
    """Interleaved rounds of the frame with each of the :data:`SETTINGS` ``keys`` in turn (the order reversed
    every other round: none always first), after a warm-up frame of each (one process, one selection): the
    median frame seconds of each, and its samples."""
    from isplat.frame import render_frame, views_for

    sel = _selection(sc, c)
    view = views_for(sc, sel)[0]
    t = {k: [] for k in keys}
    n = {}
    for w in t:                      # compile and warm each
        old = _sampler(SETTINGS[w])
        render_frame(sel, view)
        _sampler(old)
    for r in range(rounds):
        for w in (tuple(t) if r % 2 == 0 else tuple(t)[::-1]):      # ABC CBA: none always first
            old = _sampler(SETTINGS[w])
            try:
                _, st = render_frame(sel, view)
            finally:
                _sampler(old)
            t[w].append(st.seconds)
            n[w] = st.samples
    return {w: statistics.median(v) for w, v in t.items()}, n


def ns_per_sample(sc, c, rounds: int) -> dict:
    """Interleaved rounds of the frame with the sampler linear between slices (before) and cubic (after): the
    median frame seconds over the samples composited, in ns per sample, and the samples."""
    med, n = interleaved(sc, c, ("before", "after", "corners"), rounds)
    return dict(before=med["before"] * 1e9 / max(1, n["before"]), after=med["after"] * 1e9 / max(1, n["after"]),
                samples=n["after"], seconds_before=med["before"], seconds_after=med["after"], rounds=rounds,
                corners=med["corners"] * 1e9 / max(1, n["corners"]), seconds_corners=med["corners"])


def level(sc) -> float:
    """The density code where the scene's opacity first reaches half its largest value: the surface
    :func:`surface_phase` looks for."""
    op = np.asarray(sc.transfer.opacity, float)
    codes = np.arange(256.0)
    a = np.interp(codes, op[:, 0], op[:, 1], left=0.0, right=0.0)
    return float(codes[np.argmax(a >= 0.5 * a.max())])


def run_case(case, views, size, img_dir: Path, rounds: int, methods=()):
    """Renders, measures and pictures of one :data:`CASES` entry; ``methods``: the best-effort copies
    (:func:`best_effort_images`) to render and measure too."""
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
    rows, shown = [], {}
    tmp = tempfile.TemporaryDirectory()
    aug = Path(tmp.name) / "scene.aug.h5"       # the scene's presets read their data units (or, MRI, the
    _write_aug(aug, c["raw"], name)             # histogram they are placed on) through this file
    copies = best_effort_images(thick, c, sp, nk_obj, aug, preset, views, size, methods)
    for view in views:
        _log(f"{tag}: {view}")
        sc = scene(aug, preset, view, size)
        imgs = {k: render_with(sc, c, k) for k in SETTINGS}
        imgs.update(thin=render_with(sc, thin, "after"), object=render_with(sc, obj, "after"))
        period = max(sp) / pixel_size(sc, c)
        keys = ("before", "after", "monotone", "corners", "thin")
        phase = surface_phase(sc, obj, c, level(sc))
        row = dict(case=tag, view=view, preset=preset, spacing=sp, thin_spacing=tsp, period_px=period,
                   rmse={k: rmse(imgs[k], imgs["object"]) for k in keys},
                   streak={k: streak(imgs[k], phase, period) for k in keys + ("object",)})
        if view == "side":
            row["band"] = {k: band_energy(imgs[k], period) for k in keys + ("object",)}
        if view == "oblique" and rounds:
            row["timing"] = ns_per_sample(sc, c, rounds)
            _log(f"{tag}: {row['timing']['before']:.1f} -> {row['timing']['after']:.1f} ns per sample")
        if copies:
            row["best"] = {m: dict(streak=streak(im[view], phase, period), rmse=rmse(im[view], imgs["object"]),
                                   band=band_energy(im[view], period) if view == "side" else None)
                           for m, im in copies.items()}
            # unshaded (density and opacity alone): which part of a difference is the density's reconstruction
            flat = scene(aug, preset, view, size, shaded=False)
            ref = render_with(flat, obj, "after")
            un = {"default": render_with(flat, c, "after"), "object": ref,
                  **{m: im[(view, "flat")] for m, im in copies.items()}}
            row["unshaded"] = {k: dict(streak=streak(v, phase, period), rmse=rmse(v, ref)) for k, v in un.items()}
        rows.append(row)
        shown[view] = [imgs["before"], imgs["after"], imgs["thin"], imgs["object"]]
    best = _picture_method(rows)
    for row in rows:
        row["shown"] = best
    pics = [p[:3] + ([copies[best][v]] if best else []) + p[3:] for v, p in shown.items()]
    _write_png(img_dir / f"thick-{tag}.png", pics)
    tmp.cleanup()
    return rows


def best_effort_images(thick, c, sp, nk_obj, aug, preset, views, size, methods) -> dict:
    """The thick sample resampled along its thick axis (array axis 0) to the object's grid (``nk_obj`` slices of
    the in-slice spacing) by each of ``methods`` (benchmarks/_thick_resample.py: B-splines, Lanczos, the
    Catmull-Rom cubic as a copy; ``M+shading``: M's density with the normals and gradient magnitudes of the thick
    channels ``c`` mixed along k by the cubic B-spline's weights, the default's shading between slices), augmented
    in ``c``'s window and rendered by the default at each view:
    ``{method: {view: image, (view, "flat"): the unshaded image}}``. Only the thick data goes in: what the best
    standard reconstructions make of it."""
    from benchmarks import _thick_resample

    s0 = min(sp)
    if not methods:
        return {}
    if not (sp[0] == sp[1] == s0 < sp[2]):
        raise ValueError(f"best-effort copies: spacing {sp}; expected the thick axis k, i and j equal")
    out = {}
    for m in methods:
        _log(f"best effort: {m}")
        base, _, shading = m.partition("+")
        vol = _thick_resample.resample(thick, sp[2], nk_obj, s0, base)
        ch = channels(vol, (s0, s0, s0), c["window"])
        del vol
        if shading:          # the thick file's normals, mixed along k as the sampler's shading between slices
            ch["normal"], ch["gm"] = _thick_resample.blend_gradients(c["normal"], c["gm"], sp[2], nk_obj, s0)
            ch["gscale"] = c["gscale"]
        out[m] = {v: render_with(scene(aug, preset, v, size), ch, "after") for v in views}
        out[m].update({(v, "flat"): render_with(scene(aug, preset, v, size, shaded=False), ch, "after")
                       for v in views})
        del ch
    return out


def _picture_method(rows):
    """The best-effort copy the pictures show: of those measured, the nearest the object (the lowest RMSE summed
    over the views)."""
    rows = [r for r in rows if r.get("best")]
    if not rows:
        return None
    return min(rows[0]["best"], key=lambda m: sum(r["best"][m]["rmse"] for r in rows))


def mip_rows(size: int, img_dir: Path, rounds: int) -> list:
    """:data:`MIP_CASE` as a maximum-intensity projection (``render.mode = "mip"``, its preset's opacity deciding
    the quads of interest, the default window), each view linear (before) and cubic (after) between slices and
    the object: the streak measure with the phase of the point of the object's highest density along the ray
    (what a MIP shows), RMSE against the object, the band energy of the side view, and (oblique) the frame time
    before and after in interleaved rounds. Writes img/thick-mip-CASE.png (before, after, object; side, oblique)."""
    from isplat.samples import make_sample

    tag, name, shape, sp, preset, nk_obj = MIP_CASE
    _log(f"mip {tag}")
    c = channels(make_sample(name, shape)[0], sp, None)
    obj = channels(make_sample(name, (shape[0], shape[1], nk_obj))[0], (1.0, 1.0, 1.0), c["window"])
    rows, pics = [], []
    with tempfile.TemporaryDirectory() as tmp:
        aug = Path(tmp) / "scene.aug.h5"
        _write_aug(aug, c["raw"], name)
        for view in VIEWS:
            sc = scene(aug, preset, view, size, mode="mip")
            imgs = {k: render_with(sc, c, k) for k in ("before", "after")}
            imgs["object"] = render(sc, obj)
            phase = _measure().surface_phase(_view(sc, obj), _view(sc, c), obj["density"], None)
            period = max(sp) / pixel_size(sc, c)
            row = dict(case=tag, view=view, preset=preset, spacing=sp, size=size,
                       streak={k: streak(v, phase, period) for k, v in imgs.items()},
                       rmse={k: rmse(imgs[k], imgs["object"]) for k in ("before", "after")})
            if view == "side":
                row["band"] = {k: band_energy(v, period) for k, v in imgs.items()}
            if view == "oblique" and rounds:
                med, n = interleaved(sc, c, ("before", "after"), rounds)
                row["timing"] = dict(seconds_before=med["before"], seconds_after=med["after"], rounds=rounds,
                                     samples=n["after"])
            rows.append(row)
            pics.append([imgs["before"], imgs["after"], imgs["object"]])
    _write_png(Path(img_dir) / f"thick-mip-{tag}.png", pics)
    return rows


def mip_section(rows) -> list:
    """The page's lines on MIP between thick slices (:func:`mip_rows`)."""
    if not rows:
        return []
    tag = rows[0]["case"]
    L = ["", "## MIP between thick slices", "",
         "The maximum-intensity projection (`render.mode = \"mip\"`, isplat/splat/mip.py) samples the density as "
         "the post-classified technique does, so on the same grids it takes the same reconstruction between slices: "
         f"{_kind_text()} along the thick in-slice axis at and above `THICK_RATIO` (clamped to the codes; "
         "`isplat.splat.post._density_at`, imported), bilinear below it, bit for bit as before (tests/test_mip.py). "
         "A unit's bound (the most a sample of its quads can reach, which lets the index skip it) is widened by "
         "what the reconstruction can overshoot its voxels (Catmull-Rom: 1/8 of its eight voxels' range; the "
         "spline: 0.3 of its taps' range, `SPLINE_OVERSHOOT`). "
         f"The {tag} sample, {rows[0]['size']} x {rows[0]['size']}, orthographic, the mri-t1-head preset's opacity deciding the "
         "quads of interest, the default window (codes 0..255 as grey): *before* linear between slices "
         "(`BETWEEN_SLICES = \"linear\"`), *after* the cubic (the default), the *object* (1 mm slices). The streak "
         "measure's phase is that of the point of the object's highest density along each ray (what a MIP shows; "
         "tests/streak_measure.py `surface_phase` with no level).", "",
         f"![mip-{tag}](img/thick-mip-{tag}.png)", "",
         f"`img/thick-mip-{tag}.png` (MIP, `render.mode = \"mip\"`): before, after, object; side, then oblique.",
         "", "| case | technique, mode | view | streak before | after | object | RMSE before | after | "
         "band before | after | object |", "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        s, e, b = r["streak"], r["rmse"], r.get("band")
        L.append(f"| {r['case']} | MIP (`render.mode = \"mip\"`) | {r['view']} | {_f(s['before'])} | "
                 f"**{_f(s['after'])}** | {_f(s['object'])} | {_f(e['before'])} | **{_f(e['after'])}** | " +
                 (f"{_f(b['before'])} | **{_f(b['after'])}** | {_f(b['object'])} |" if b else "| | |"))
    timed = [r for r in rows if "timing" in r]
    for r in timed:
        t = r["timing"]
        L += ["", f"Its cost (MIP, {r['view']} view, {t['rounds']} interleaved rounds of linear and cubic, the "
              f"order swapped every round, after a warm-up frame of each; the median frame time, the whole frame): "
              f"{t['seconds_before'] * 1e3:.1f} ms linear, {t['seconds_after'] * 1e3:.1f} ms cubic, "
              f"{t['seconds_after'] / t['seconds_before']:.2f} times ({t['samples']:,} samples); a machine shared "
              "with other work, so the ratio is what to read."]
    return L


def sphere_label(n: int, dz: float, radius: float = LABEL_SPHERE[0], centre: float = LABEL_SPHERE[1]) -> np.ndarray:
    """Label 1 on an ``n`` x ``n`` x ``n / dz`` grid of 1 x 1 x ``dz`` mm voxels (``[k, j, i]``, uint8): a sphere
    of ``radius`` mm about the grid's middle, ``centre`` mm off it along k (so the poles fall between slices)."""
    nk = int(round(n / dz))
    x = np.arange(n) - (n - 1) / 2.0
    z = (np.arange(nk) - (nk - 1) / 2.0) * dz - centre
    return (x[None, None, :] ** 2 + x[None, :, None] ** 2 + z[:, None, None] ** 2 <= radius ** 2).astype(np.uint8)


def _label_render(tmp: Path, lab: np.ndarray, dz: float, view: str, size: int):
    """The shaded render of label 1 of ``lab`` (density 0 everywhere, its opacity 0: the label alone) on 1 x 1 x
    ``dz`` mm voxels, post-classified (the only technique that shows labels): the image and the view."""
    from isplat.augfile import write_augmented
    from isplat.renderer import Renderer
    from isplat.scene import parse_scene

    aug = tmp / f"labels-{dz:g}.aug.h5"
    if not aug.exists():
        d = np.zeros(lab.shape, np.uint8)
        write_augmented(aug, d, d, np.full(d.shape, 0x8080, np.uint16), (1.0, 1.0, dz), (0.0, 255.0), 0.0,
                        labels=lab)
    az, el = VIEWS[view]
    text = (f'version = 6\n[data]\naugmented = "{aug}"\n[image]\nwidth = {size}\nheight = {size}\n[camera]\n'
            f'projection = "orthographic"\nazimuth = {az}\nelevation = {el}\n[render]\nmethod = "full"\n'
            '[transfer]\nopacity = [[0, 0], [255, 0]]\n[shading]\nambient = 0.2\ndiffuse = 0.75\nspecular = 0.3\n'
            'shininess = 30\n[labels.1]\ncolor = [0.9, 0.75, 0.6]\nopacity = 1.0\n')
    r = Renderer(parse_scene(text, tmp, "labels.toml"))
    return r.render_view(0)[0].astype(np.float64), r.views[0]


def label_mismatch(n: int, dz: float, cubic: bool, phases: int = 32) -> float:
    """The label's shape between slices, without rendering: the 1/2 level of its indicator along the thick axis
    (linear, or ``cubic`` Catmull-Rom clamped to [0, 1] as the post technique's density) at every in-slice voxel
    column, at ``phases`` points between each two slices, against the true sphere: the mean number of columns
    (1 mm^2 each) whose membership is wrong, per point."""
    from isplat.splat.post import cubic as cr

    lab = sphere_label(n, dz).astype(np.float64)
    nk = lab.shape[0]
    x = np.arange(n) - (n - 1) / 2.0
    r2 = x[None, :] ** 2 + x[:, None] ** 2
    wrong, count = 0, 0
    for k in range(nk - 1):
        for t in np.arange(phases) / phases:
            if cubic:
                q = [lab[min(max(k + d, 0), nk - 1)] for d in (-1, 0, 1, 2)]
                ind = np.minimum(np.vectorize(lambda a, b, c, e: cr(a, b, c, e, t, 1))(*q), 1.0)
            else:
                ind = (1 - t) * lab[k] + t * lab[k + 1]
            z = ((k + t) - (nk - 1) / 2.0) * dz - LABEL_SPHERE[1]
            wrong += int(((ind > 0.5) != (r2 + z * z <= LABEL_SPHERE[0] ** 2)).sum())
            count += 1
    return wrong / count


def label_rows(size: int) -> list:
    """The sphere label (:func:`sphere_label`) on 1 x 1 x 7 mm voxels against the same sphere on 1 mm voxels (the
    object), each view: the streak (phase of the object's label surface), RMSE and band energy of the label's
    shaded render, post-classified; and :func:`label_mismatch` of the linear and the cubic indicator."""
    n, dz = LABEL_SPHERE[2], 7.0
    thick, obj = sphere_label(n, dz), sphere_label(n, 1.0)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for view in VIEWS:
            _log(f"labels: {view}")
            img, vt = _label_render(Path(tmp), thick, dz, view, size)
            ref, vo = _label_render(Path(tmp), obj, 1.0, view, size)
            phase = _measure().surface_phase(vo, vt, obj * 255, 128.0)
            period = dz / vt.frame.pixel_size
            row = dict(view=view, streak=streak(img, phase, period), object=streak(ref, phase, period),
                       rmse=rmse(img, ref))
            if view == "side":
                row["band"], row["band_object"] = band_energy(img, period), band_energy(ref, period)
            rows.append(row)
    rows.append(dict(mismatch={k: label_mismatch(n, dz, k == "cubic") for k in ("linear", "cubic")}))
    return rows


def label_section(rows) -> list:
    """The page's lines on labels between thick slices (:func:`label_rows`)."""
    if not rows:
        return []
    views, mm = rows[:-1], rows[-1]["mismatch"]
    r0, c0, n = LABEL_SPHERE
    L = ["", "## Labels between thick slices", "",
         f"A sphere label (radius {r0:g} mm, its centre {c0:g} mm off the grid's middle along the slices' axis) on "
         f"{n} x {n} x {round(n / 7)} voxels of 1 x 1 x 7 mm, against the same sphere on 1 mm voxels (the object), "
         "rendered alone (the density's opacity 0), shaded, orthographic, by the **post-classified** technique "
         "(`[labels]` scenes: membership by the quad's bilinear indicator above 1/2, normals from the label's "
         "smoothed indicator, isplat/splat/labels.py). The streak's phase is that of the object's label surface.", "",
         "| label | technique | view | streak | object | RMSE | band | object |", "|---|---|---|---:|---:|---:|---:|---:|"]
    for r in views:
        L.append(f"| sphere, 1 x 1 x 7 | post-classified, `[labels]` | {r['view']} | {_f(r['streak'])} | "
                 f"{_f(r['object'])} | {_f(r['rmse'])} | {_f(r.get('band'))} | {_f(r.get('band_object'))} |")
    L += ["", "The label shows the terraces of the slices (streak and band about twice the object's). The density's "
          "cubic would not remove them: a label's indicator is 0 or 1 at every voxel, and along the thick axis a "
          "Catmull-Rom cubic between a 1 and a 0 that each continue for a slice (1, 1, 0, 0) crosses 1/2 half-way, "
          "exactly where the linear one does; it differs only next to a label one slice thick. Measured without "
          "rendering (`label_mismatch`: the 1/2 level of the indicator at every in-slice voxel column, 32 points "
          "between each two slices, against the true sphere), the columns whose membership is wrong, per point: "
          f"linear {mm['linear']:.1f}, Catmull-Rom clamped to [0, 1] {mm['cubic']:.1f}. So labels keep the "
          "bilinear indicator. What would move a label's boundary between slices is shape-based interpolation "
          "(each slice's signed distance to the label's contour, interpolated between slices: Raya and Udupa "
          "1990), which needs a distance per voxel and label, not the ids."]
    return L


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
        # quick: one copy on the one case, to run the code; else every copy on the 7 mm cases
        methods = BEST_METHODS[:1] if quick else (BEST_METHODS if case[0] in BEST_CASES else ())
        rows += run_case(case, list(VIEWS), size, Path(out_dir) / "img", 2 if quick else ROUNDS, methods)
        tag, name, shape, sp = case[:4]
        if not quick:
            costs[tag] = thin_cost(name, shape, sp, WINDOWS.get(name))
    ratios = ratio_rows(size, RATIO_CASES[:1] if quick else RATIO_CASES)
    mip = mip_rows(size, Path(out_dir) / "img", 2 if quick else ROUNDS)
    labels = label_rows(size)
    path = Path(out_dir) / "thick-slices.md"
    path.write_text(render_doc(rows, costs, size, quick, time.perf_counter() - t0, ratios, mip, labels))
    return path


def ratio_rows(size: int, ratios) -> list:
    """The mr-head sample at 1 x 1 x R mm for each R of ``ratios`` (224 / R slices), oblique: the streak and
    RMSE of linear and cubic between slices (the cubic forced at every ratio) and the object's streak."""
    from isplat.samples import make_sample
    from isplat.splat import post

    out = []
    obj_vol, _ = make_sample("mr-head", (256, 256, 224))
    for R in ratios:
        _log(f"ratio {R}")
        sp = (1.0, 1.0, R)
        c = channels(make_sample("mr-head", (256, 256, int(round(224 / R))))[0], sp, None)
        obj = channels(obj_vol, (1.0, 1.0, 1.0), c["window"])
        with tempfile.TemporaryDirectory() as tmp:
            aug = Path(tmp) / "scene.aug.h5"
            _write_aug(aug, c["raw"], "mr-head")
            sc = scene(aug, "mri-t1-head", "oblique", size)
            phase = surface_phase(sc, obj, c, level(sc))
            period = R / pixel_size(sc, c)
            old = _sampler({"THICK_RATIO": 1.0})
            try:
                imgs = {k: render_with(sc, c, k) for k in ("before", "after")}
            finally:
                _sampler(old)
            objimg = render(sc, obj)
        out.append(dict(ratio=R, default=R >= post.THICK_RATIO, object=streak(objimg, phase, period),
                        streak={k: streak(v, phase, period) for k, v in imgs.items()},
                        rmse={k: rmse(v, objimg) for k, v in imgs.items()}))
    return out


def _f(x, n=4):
    return "" if x is None else f"{x:.{n}f}"



def _sp(sp) -> str:
    return " x ".join(f"{s:g}" for s in sp)


def _get(rows, case, view):
    return next((r for r in rows if r["case"] == case and r["view"] == view), None)


def render_doc(rows, costs, size, quick, seconds, ratios=(), mip=(), labels=()) -> str:
    L = ["```", "python -m benchmarks thick" + (" --quick" if quick else ""), "```", "",
         "# Thick slices: rings, terraces and streaks, their cause and their fix", "",
         f"Measured on {_doc.machine_line()}; {seconds:.0f} s. Every picture and number but those of the MIP section: isplat's default technique, "
         f"**post-classified** splatting (`render.classification = \"post\"`), {size} x {size}, orthographic, "
         "shaded (examples/ct-preset.toml's lights and Phong terms), early termination at its default. Each case is "
         "an isplat sample made with thick slices (`isplat sample NAME --shape ...`, augmented with `--spacing`) and "
         "the same sample made with slices as thin as its pixels, the *object* (the samples are painted in "
         "normalised coordinates: the same object). Columns of each picture: *before* (the sampler linear between "
         "slices, as isplat had it: the quad's bilinear density and Phong factors, "
         "`isplat.splat.post.BETWEEN_SLICES = \"linear\"`), *after* (the default now: along the thick in-slice "
         f"axis the density {_kind_text()} and the Phong factors of four slices weighted by "
         "the cubic B-spline, isplat/splat/post.py `_density_at`, `_shade_between`), *thin* (`isplat augment "
         "--thin-slices`, rendered by the default), the *object* (by the default). Rows: the side view (azimuth 90, "
         "elevation 0: the slices are horizontal), then the oblique view (azimuth 45, elevation 25). All use the "
         "same file (normals smoothed along the thin axes above 4:1, `isplat.augment.normal_sigmas`) and the "
         "shading weighted by the corners' gradient magnitudes (`WEIGHTED_SHADING`, an earlier run of this page); "
         "only the reconstruction between slices differs.", ""]
    for tag in dict.fromkeys(r["case"] for r in rows):
        shown = next(r.get("shown") for r in rows if r["case"] == tag)
        col = (f"the best-effort copy nearest the object ({BEST_NAMES[shown]}, the lowest RMSE: section *Best "
               "efforts from the thick data*), " if shown else "")
        L += [f"![{tag}](img/thick-{tag}.png)", "",
              f"`img/thick-{tag}.png` (post-classified): before, after, thin, {col}object; side, then oblique.", ""]
    L += ["## Streaks, measured", "",
          "*streak*: how much the picture's fine shading depends on where the surface lies between two thick "
          "slices (`streak` in benchmarks/thick.py): per pixel, the first point of the object's surface (the "
          "density where the preset's opacity reaches half its top) along the ray gives the phase 0..1 between "
          "two thick slices; the high-frequency luminance (luminance minus its Gaussian blur of sigma two slice "
          "periods in pixels) is averaged per eighth of that phase, and the streak is the RMS of those eight means. "
          "Rings, terraces and streaks are locked to the slices and make the eighths differ; the shapes' own "
          "shading and the object's fine detail are not, and average out: the object's own value (rendered with "
          "the same phases) is the floor. *monotone*: the density's cubic with Fritsch-Butland slopes instead of "
          "Catmull-Rom's (`BETWEEN_SLICES = \"monotone\"`: no overshoot, flat at every slice that is a local "
          "extremum). *corners*: the default's density with the quad's four corners' Phong factors, as between thin "
          "slices (`SHADE_BETWEEN = False`). *RMSE*: over RGB against the object. *band* (side views): RMS over the image's rows of the "
          "row's mean luminance minus its running mean over one slice period (the object's own is the floor).", "",
          "| case | preset | spacing (mm) | view | streak before | after | monotone | corners | thin | object | "
          "RMSE before | after | monotone | corners | thin | band before | after | thin | object |",
          "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        s, e, b = r["streak"], r["rmse"], r.get("band")
        L.append(f"| {r['case']} | {r['preset']} | {_sp(r['spacing'])} | {r['view']} | {_f(s['before'])} | "
                 f"**{_f(s['after'])}** | {_f(s['monotone'])} | {_f(s['corners'])} | {_f(s['thin'])} | "
                 f"{_f(s['object'])} | {_f(e['before'])} | **{_f(e['after'])}** | {_f(e['monotone'])} | "
                 f"{_f(e['corners'])} | {_f(e['thin'])} | " +
                 (f"{_f(b['before'])} | **{_f(b['after'])}** | {_f(b['thin'])} | {_f(b['object'])} |" if b
                  else "| | | |"))
    L += best_section(rows)
    if ratios:
        L += ["", "## Where the cubic starts", "",
              "The mr-head sample (mri-t1-head, oblique) made with slices 1 x 1 x R mm (224 / R slices), linear and "
              "cubic between slices, the cubic forced at every ratio: what it gains against the anisotropy. "
              "`isplat.splat.post.THICK_RATIO` (the thicker in-slice spacing over the finest) decides where the "
              "default uses it.", "",
              "| R | default | streak linear | cubic | object | RMSE linear | cubic |",
              "|---:|---|---:|---:|---:|---:|---:|"]
        for q in ratios:
            L.append(f"| {q['ratio']:g} | {'cubic' if q['default'] else 'linear'} | {_f(q['streak']['before'])} | "
                     f"{_f(q['streak']['after'])} | {_f(q['object'])} | {_f(q['rmse']['before'])} | "
                     f"{_f(q['rmse']['after'])} |")
    timed = [r for r in rows if "timing" in r]
    if timed:
        L += ["", "## What the cubic costs", "",
              f"The oblique view of each case rendered in {timed[0]['timing']['rounds']} interleaved rounds, before "
              "(linear), after (cubic) and *corners* (the cubic density, the corners' shading) in turn, the order swapped every round (one process, the same selection; "
              "`isplat.splat.post.BETWEEN_SLICES` switches the sampler), after a warm-up frame of each: the median "
              "frame time (the whole frame: traversal and set-up included) over the samples composited. The cubic "
              "reads 8 voxels' densities, normals and gradient magnitudes per sample instead of 4, from the same "
              "channels: no more memory, no resampled copy (*corners*: 8 densities, 4 normals). Measured on a machine "
              "shared with other work: the ratios, interleaved, are what to read.", "",
              "| case | samples | ms before | ms after | ms corners | ns per sample before | after | corners | "
              "after / before | corners / before |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for r in timed:
            t = r["timing"]
            L.append(f"| {r['case']} | {t['samples']:,} | {t['seconds_before'] * 1e3:.1f} | "
                     f"{t['seconds_after'] * 1e3:.1f} | {t['seconds_corners'] * 1e3:.1f} | {t['before']:.1f} | "
                     f"{t['after']:.1f} | {t['corners']:.1f} | {t['after'] / t['before']:.2f} | "
                     f"{t['corners'] / t['before']:.2f} |")
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
        ratios_ = [(c["thin"]["seconds"] / c["as_is"]["seconds"], c["thin"]["rss_mb"] - c["as_is"]["rss_mb"],
                    c["thin"]["file_mb"] / c["as_is"]["file_mb"]) for c in costs.values()]
        L += ["", f"With `--thin-slices`: {min(r[0] for r in ratios_):.2f}-{max(r[0] for r in ratios_):.2f} times "
              f"the seconds, {min(r[1] for r in ratios_):.0f}-{max(r[1] for r in ratios_):.0f} MB more peak memory, "
              f"{min(r[2] for r in ratios_):.1f}-{max(r[2] for r in ratios_):.1f} times the file."]
    L += mip_section(mip)
    L += label_section(labels)
    L += ["", reading(rows, costs, ratios), ""]
    return "\n".join(L)


BEST_NAMES = {"bspline3": "B-spline 3", "bspline5": "B-spline 5", "lanczos3": "Lanczos-3",
              "catmull-rom": "Catmull-Rom copy", "bspline3+shading": "B-spline 3, default's shading",
              "catmull-rom+shading": "Catmull-Rom, default's shading"}
TIE = 1.05           # "at or below": the default's measure at most this many times the best copy's
CLEAR = 0.9          # "clearly better": a copy's measure below this many times the default's
FLOOR = 1.2          # "at the object's floor": the default's streak at most this many times the object's


def best_section(rows) -> list:
    """The page's lines on the best-effort copies (:func:`best_effort_images`): the tables and, from their
    numbers, whether any reconstruction from the thick data alone comes nearer the object than the default."""
    best = [r for r in rows if r.get("best")]
    if not best:
        return []
    ms = list(best[0]["best"])
    pure = [m for m in ms if "+" not in m]
    L = ["", "## Best efforts from the thick data", "",
         "Could any reconstruction from the thick slices do better than the default? Each thick sample resampled "
         "along its thick axis to the object's grid (1 mm slices: the copy and the object have the same voxels) "
         "by the best standard interpolators, using the thick data only (benchmarks/_thick_resample.py, each a "
         "matrix from thick to thin slices): interpolating B-splines of degree 3 and 5 (what "
         "`scipy.ndimage.zoom(order=3|5, mode=\"mirror\")` computes along that axis), the windowed sinc Lanczos-3, "
         "and the renderer's Catmull-Rom cubic as a copy (the density *after* had while Catmull-Rom was the "
         "default, with its normals differenced on the thin grid); values clipped to the thick data's range, augmented in the thick file's "
         "window (as `--thin-slices` is) and rendered by the default at the same camera, size and preset. "
         "*default's shading*: a copy's density (B-spline 3, or the Catmull-Rom cubic as a control) with the "
         "thick file's own normals and gradient magnitudes instead of its own, their gradients mixed along the "
         "thick axis with the cubic B-spline's weights (`blend_gradients`; the sampler mixes the Phong factors "
         "with those weights, `_shade_between`): what the default would show with that density between slices. "
         "*default*: the thick file rendered by the default (*after* above: the cubic in the sampler, no copy); "
         "*thin*: `--thin-slices`; *object*: the sample painted on 1 mm slices, which no reconstruction from the "
         "thick data can know (the floor).", ""]

    def table(title, cells, cols, extra):
        head = " | ".join(BEST_NAMES[m] for m in cols)
        L.extend([title, "", f"| case | view | default | {head} | " + " | ".join(extra) + " |",
                  "|---|---|" + "---:|" * (1 + len(cols) + len(extra))])
        for r in best:
            c = cells(r)
            if c is not None:
                L.append(f"| {r['case']} | {r['view']} | **{_f(c[0])}** | " + " | ".join(_f(x) for x in c[1:]) + " |")
        L.append("")

    table("Streak (shaded):", lambda r: [r["streak"]["after"]] + [r["best"][m]["streak"] for m in ms] +
          [r["streak"]["thin"], r["streak"]["object"]], ms, ["thin", "object"])
    table("RMSE against the object:", lambda r: [r["rmse"]["after"]] + [r["best"][m]["rmse"] for m in ms] +
          [r["rmse"]["thin"]], ms, ["thin"])
    table("Band energy (side views):", lambda r: None if "band" not in r else
          [r["band"]["after"]] + [r["best"][m]["band"] for m in ms] + [r["band"]["object"]], ms, ["object"])
    table("Unshaded (`shading.enabled = false`: the density's reconstruction alone, the same phases), streak and "
          "RMSE against the unshaded object:",
          lambda r: [r["unshaded"]["default"]["streak"]] + [r["unshaded"][m]["streak"] for m in pure] +
          [r["unshaded"]["object"]["streak"], r["unshaded"]["default"]["rmse"]] +
          [r["unshaded"][m]["rmse"] for m in pure], pure,
          ["object", "RMSE default"] + [BEST_NAMES[m] for m in pure])
    L += [best_reading(best)]
    return L


def best_reading(best) -> str:
    """What the best-effort tables say, from their numbers (:data:`TIE`, :data:`CLEAR`, :data:`FLOOR`): per view,
    the default against the lowest copy; where the default's streak is above the object's floor, whether a copy
    removes the excess (then it is the default's reconstruction, else the data's)."""
    def low(r, key, part="best"):
        d = r[part]
        m = min((m for m in d if m in BEST_NAMES), key=lambda m: d[m][key])
        return m, d[m][key]

    out = []
    for r in best:
        (ms, vs), (me, ve) = low(r, "streak"), low(r, "rmse")
        out.append(f"- *{r['case']}* {r['view']}: streak default {r['streak']['after']:.4f}, lowest copy "
                   f"{vs:.4f} ({BEST_NAMES[ms]}), object {r['streak']['object']:.4f}; RMSE default "
                   f"{r['rmse']['after']:.4f}, lowest copy {ve:.4f} ({BEST_NAMES[me]}, "
                   f"{(ve / r['rmse']['after'] - 1) * 100:+.0f}%).")
    out = ["\n".join(out)]
    floor = [r for r in best if r["streak"]["after"] <= FLOOR * r["streak"]["object"]]
    above = [r for r in best if r not in floor]
    if floor:
        out.append(f"At the object's floor (the default's streak at most {FLOOR:g} times the object's: nothing locked "
                   "to the slices left to remove) in " + ", ".join(f"{r['case']} {r['view']}" for r in floor) +
                   "; there only the RMSE can improve, by the percentages above.")
    for r in above:
        m, v = low(r, "streak")
        times = r["streak"]["after"] / r["streak"]["object"]
        if v < CLEAR * r["streak"]["after"] and low(r, "rmse")[1] <= TIE * r["rmse"]["after"]:
            u = r["unshaded"]
            why = []
            mu, vu = low(r, "streak", "unshaded")
            if vu < CLEAR * u["default"]["streak"]:
                why.append(f"the density between slices (unshaded streak {BEST_NAMES[mu]} {vu:.4f} against the "
                           f"default's {u['default']['streak']:.4f}, the object's {u['object']['streak']:.4f})")
            cr = r["best"].get("catmull-rom")
            from isplat.splat import post
            if (cr and post.BETWEEN_SLICES == "catmull-rom" and cr["streak"] < CLEAR * r["streak"]["after"]
                    and u["catmull-rom"]["streak"] <= TIE * u["default"]["streak"]):
                why.append(f"the shading (the Catmull-Rom copy, the default's own density with normals differenced "
                           f"on the thin grid, streaks {cr['streak']:.4f} shaded against the default's "
                           f"{r['streak']['after']:.4f}, unshaded {u['catmull-rom']['streak']:.4f} against "
                           f"{u['default']['streak']:.4f})")
            out.append(f"**{r['case']} {r['view']}: the default's streak is {times:.2f} "
                       f"times the object's, and a copy made from the same slices removes the excess** "
                       f"({BEST_NAMES[m]}: streak {v:.4f}, {v / r['streak']['object']:.2f} times the object's" +
                       (" (below the object's own: the measure's floor holds the object's fine detail, which a "
                        "smooth interpolant lacks, so the RMSE is the surer sign)" if v < 0.8 * r["streak"]["object"]
                        else "") +
                       f"; RMSE {r['best'][m]['rmse']:.4f} against the default's {r['rmse']['after']:.4f}): the "
                       "excess is not "
                       "information missing from the slices but the default's reconstruction" +
                       (", in " + " and in ".join(why) if why else "") + ".")
        else:
            out.append(f"**{r['case']} {r['view']}**: the default's streak is {times:.2f} "
                       f"times the object's and no copy is clearly lower (the lowest {v / r['streak']['object']:.2f} "
                       "times): the excess is what the slices do not hold, within what the data allows.")
    return "\n\n".join(out + _hybrid_reading(best))


def _hybrid_reading(best) -> list:
    """The sentences on the B-spline density with the default's shading against its Catmull-Rom control and the
    default (:func:`best_reading`)."""
    h, k = "bspline3+shading", "catmull-rom+shading"
    if not all(h in r["best"] and k in r["best"] for r in best):
        return []

    def rel(a, b):
        return (a / b - 1) * 100 if b else 0.0

    ctl_s = [rel(r["best"][k]["streak"], r["streak"]["after"]) for r in best]
    ctl_e = [rel(r["best"][k]["rmse"], r["rmse"]["after"]) for r in best]
    e_lower = sum(r["best"][h]["rmse"] < r["best"][k]["rmse"] for r in best)
    s_lower = sum(r["best"][h]["streak"] < r["best"][k]["streak"] for r in best)
    return [f"**The density's reconstruction with the default's shading.** The control (Catmull-Rom, default's "
            f"shading: the default's density and, approximately, its shading, as a copy) is within "
            f"{min(ctl_s):+.0f}..{max(ctl_s):+.0f}% of the default's streak and {min(ctl_e):+.0f}..{max(ctl_e):+.0f}% "
            f"of its RMSE. Against it, the interpolating cubic B-spline's density (B-spline 3, default's shading) "
            f"has the lower RMSE in {e_lower} of {len(best)} views and the lower streak in {s_lower}: " +
            "; ".join(f"{r['case']} {r['view']} streak {r['best'][k]['streak']:.4f} -> {r['best'][h]['streak']:.4f}"
                      f" (default {r['streak']['after']:.4f}, object {r['streak']['object']:.4f}), RMSE "
                      f"{r['best'][k]['rmse']:.4f} -> {r['best'][h]['rmse']:.4f} (default "
                      f"{r['rmse']['after']:.4f})" for r in best) +
            ". In the sampler that density needs no thin copy: the cubic B-spline's weights over the same four "
            "slices, applied to coefficients prefiltered along the thick axis (a grid of the file's size); not built "
            "or measured in the renderer here."]


def reading(rows, costs, ratios=()) -> str:
    """The page's reading: the causes (from the earlier runs of this page, named by commit) and, with this run's
    numbers, what the cubic does."""
    from isplat.splat import post

    out = ["## Reading", "",
           "**What makes the rings and terraces.** The earlier runs of this page (git log docs/thick-slices.md; "
           "b27b5b8 measured them with a converged ray caster and unshaded renders) found three causes on shaded "
           "surfaces, and not the opacity correction: (1) the normals, central differences spanning two in-slice "
           "voxels but two thick slices, which swing slice by slice; fixed by smoothing the density along the thin "
           "axes before the differences above 4:1 (`isplat.augment.normal_sigmas`); (2) the sampler's shading "
           "mixing the four corners' Phong factors with the bilinear weights only, so a corner just off a surface "
           "nearly parallel to the slices shades as much as the corner on it: rings on the skull; fixed by "
           "weighting each corner by its gradient magnitude too (`WEIGHTED_SHADING`); (3) the reconstruction "
           "between slices: linear along the thick axis, so an isosurface is piecewise planar with a kink at every "
           "slice and the shading, linear too, kinks there as well; a shell thinner than a slice (the MRI head's "
           "scalp) cross-fades between slices. That is what this run changes: along the thick in-slice axis the "
           "density is a cubic through four slices (Catmull-Rom: C1, it interpolates the voxels, and it may "
           "overshoot between them, clamped to the codes 0..255), and the Phong factors of those four slices' "
           "voxels are mixed with the cubic B-spline's weights (positive, C2, so no kink in the shading; a little "
           "smoothing of the normals across the thick slices, whose differences are coarse there anyway), times "
           "the gradient magnitudes as before (the density is now the interpolating cubic spline instead: "
           "docs/design.md, \"The interpolating cubic spline between thick slices\"). Measured and not chosen: the monotone cubic (its slope is 0 at "
           "every slice that is a local extremum along the thick axis, which draws a flat at every slice of a "
           "thin shell: the *monotone* columns), and the Catmull-Rom weights for the Phong factors too (negative "
           "weights: more streak than the linear ones when tried).", "",
           "**Along the view's own axis** nothing is interpolated: the samples lie on the slices (a ray caster "
           "whose step is the slice spacing), so a thick axis that is the principal axis of the view (looking "
           "along the slices' normal, the elevation-90 views of these samples) keeps the slices' spacing as the "
           "step between samples; the cubic applies when the thick axis lies in the slices, which is every view "
           "whose direction is nearer another axis, the side and oblique views here. The quads sampled stay those "
           "one of whose four voxels is of interest; only the gather reads the voxel before and the one after "
           "along the thick axis (clamped at the volume's edges; slabs hold whole slices, so in-slice axes reach "
           "the volume's edges there too)."]
    items = []
    for r in rows:
        s, e = r["streak"], r["rmse"]
        items.append(f"- *{r['case']}*, {r['view']}: streak {s['before']:.4f} -> {s['after']:.4f} "
                     f"({(s['after'] / s['before'] - 1) * 100 if s['before'] else 0:+.0f}%; object "
                     f"{s['object']:.4f}), RMSE {e['before']:.4f} -> "
                     f"{e['after']:.4f}" + (f"; band {r['band']['before']:.4f} -> {r['band']['after']:.4f} (object "
                                             f"{r['band']['object']:.4f})" if "band" in r else "") + ".")
    out += ["", "**This run, before -> after** (linear -> cubic, each against the object):", ""] + items
    if rows and "corners" in rows[0]["streak"]:
        out += ["", "**The shading between slices** (`SHADE_BETWEEN`, the eight voxels' Phong factors with the "
                "B-spline's weights, against the quad's four corners' with the same cubic density), streak corners "
                "-> after: " + "; ".join(f"{r['case']} {r['view']} {r['streak']['corners']:.4f} -> "
                                         f"{r['streak']['after']:.4f}" for r in rows) + "."]
    near = [r for r in rows if r["streak"]["before"] <= 1.2 * r["streak"]["object"]]
    if near:
        out += ["", "Already within 20% of the object's own streak when linear (nothing locked to the slices to "
                "remove; the cubic's gain there is in the RMSE, if any): " +
                ", ".join(f"{r['case']} {r['view']}" for r in near) + "."]
    if ratios:
        out += ["", f"**The threshold.** `THICK_RATIO` = {post.THICK_RATIO:g}, by the table *Where the cubic starts* "
                "(the cubic against "
                "the linear, and the linear's streak against the object's floor): " +
                "; ".join(f"at {q['ratio']:g}:1 streak x{q['streak']['after'] / q['streak']['before']:.2f} and RMSE "
                          f"x{q['rmse']['after'] / q['rmse']['before']:.2f} (linear's streak "
                          f"{q['streak']['before'] / q['object']:.2f} times the floor)" for q in ratios) +
                ". The cubic costs 1.2-1.4x the frame time (the cost table above; 1.4-1.8x on the 512 x 512 x 133 "
                "chest of `python -m benchmarks sampler` when forced): where the linear reconstruction's streak is "
                "near the object's floor and the cubic changes the RMSE by a few per cent (up to 3:1 here, and the "
                "2.5 mm CT slices of the table above, 3.6:1) it buys too little for that, so the default keeps the "
                "linear one there; the 7 mm slices (7:1), where the terraces are, take the cubic. Isotropic grids and "
                "grids below the ratio keep the bilinear sampler bit for bit (tests/test_post.py)."]
    thin = [r for r in rows if r["streak"]["thin"] < 0.95 * r["streak"]["after"]]
    out += ["", f"**`--thin-slices`** lowers the streak measure more than 5% below *after* in {len(thin)} of the "
            f"{len(rows)} views above" + (" (" + ", ".join(f"{r['case']} {r['view']}" for r in thin) + ")" if thin else "") +
            "; it stores a linear interpolation between slices (a thinned file is below the cubic's ratio, so it "
            "is rendered linear), which is what the cubic replaces, and its normals, differenced over a linear "
            "ramp, are no better. Its cost is in the table above (file and memory grow with the factor of "
            "thinning, since the volume is held in memory). It stays for pre-classified splatting "
            "(`render.classification = \"pre\"`), where docs/sheets.md measures it closer to the trilinear field."]
    return "\n".join(out)
