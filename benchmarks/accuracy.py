"""Error against the truth, against run time: every speed knob of ``[render]``, VTK's ray steps, the Pareto front.

``python -m benchmarks accuracy [--out docs] [--quick]`` writes ``accuracy.md``, ``accuracy.csv``,
``accuracy_rounds.csv`` (every frame time) and ``img/accuracy_pareto.png`` (and ``img/popping_head.png``). For
each case (the head, the engine and the Marschner-Lobb sample, see :mod:`benchmarks.reference`) and each setting
(the format defaults, then one knob changed at a time: early termination, footprint radius, table and sigma,
precision, thread count, method, the slice stride (``render.slice_stride``: 1 is the defaults' point) and
``render.sheets`` when this isplat has it), the frame times (every setting of a case takes one turn per round, in
a random order each round: interleaved; the front's "faster" is the paired sign test of tests/paired_times.py)
and the error of the image against reference (a), the converged ray integral of the same 8-bit densities, and for
Marschner-Lobb also against (b), the analytic signal. When VTK is importable
and can open an offscreen context, ``vtkFixedPointVolumeRayCastMapper`` at sample distances 2, 1 (its default),
0.5 and 0.25 voxel is timed in the same rounds and measured against the same references.

Then the known artefact of axis-aligned sheets (Mueller and Crawfis 1998): the change of the head's image across
the azimuth where the principal axis switches, against the change between neighbouring views on one side.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from . import _doc

# the paired test of "faster" (shared with its tests, which must not import benchmarks; see its docstring)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import paired_times as PT  # noqa: E402

TECHNIQUES = ["pre", "post"]     # render.classification of its rows (the page's stamp)
SOURCES = _doc.sources(_doc.RENDER, _doc.SAMPLES, ("isplat/augment.py", "examples/*.toml",
                       "tests/ray_reference.py", "tests/paired_times.py", "benchmarks/reference.py",
                       "benchmarks/accuracy.py"))
from . import reference as REF
from .reference import errors, make_scene

REPO = Path(__file__).resolve().parents[1]
KNOBS = [                    # knobs of the default, post-classified, renderer
    ("early_termination", [1.0, 0.999, 0.99, 0.98, 0.95]),     # 0.99: the default before scene version 8
    ("precision", ["float64"]),
    ("threads", [1]),
    ("method", ["full"]),
    ("slice_stride", [2, 3, 4]),      # every n-th slice, the opacity corrected for n slices (issue 27 item 3)
    ("termination", ["stop"]),        # a pixel that reaches early termination as it is, not filled (scene version 6)
]
PRE_KNOBS = [                # the footprint's knobs, which act on pre-classified splatting only
    ("footprint_radius", [1.5, 2.0, 3.0, 4.0]),
    ("footprint_table", [32, 128, 65536]),
    ("footprint_sigma", [0.5, 0.6, 0.85]),
]
PRE = {"classification": "pre"}
VTK_STEPS = [2.0, 1.0, 0.5, 0.25]
CASES = list(REF.CASES)
ROUNDS = 25                  # rounds per setting (each renders every setting once); see tests/paired_times.py
MIN_MS = 20.0                # a setting's measurement in a round: back-to-back frames lasting this long at least
POP_OFFSETS = [-0.9, -0.7, -0.5, -0.3, -0.1, 0.1, 0.3, 0.5, 0.7, 0.9]   # degrees from the switch


def _log(msg):
    print(f"[accuracy] {msg}", file=sys.stderr, flush=True)


def sheets_key(size=16) -> list[str] | None:
    """The overrides that select image-aligned sheets, or None when this isplat has no ``render.sheets``."""
    from isplat.errors import IsplatError

    for extra in (['render.sheets="image"'], ["version=3", 'render.sheets="image"']):
        try:
            make_scene("head", size, extra=extra, shape=REF.QUICK_SHAPES["head"])
            return extra
        except IsplatError:
            continue
    return None


def settings(sheets):
    """(knob, value, overrides) of every setting measured; the defaults first."""
    out = [("defaults", "", [])]
    for knob, values in KNOBS:
        out += [(knob, v, REF.render_overrides({knob: v})) for v in values]   # make_scene: the current version
    out.append(("classification", "pre", REF.render_overrides(PRE)))
    for knob, values in PRE_KNOBS:
        out += [(knob, v, REF.render_overrides({**PRE, knob: v})) for v in values]
    if sheets:
        out.append(("sheets", "image", sheets))
    return out


def vtk_window() -> str | None:
    """VTK's offscreen window class, or None (with the reason logged) when VTK cannot render here."""
    from .peers import PeerUnavailable, offscreen_window_class, vtk_version

    try:
        vtk_version()
        cls = offscreen_window_class()
    except PeerUnavailable as exc:
        _log(f"VTK points skipped: {str(exc).splitlines()[0]}")
        return None
    os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = cls
    return cls


# ---- measuring ---------------------------------------------------------------------------------------------------
def measure_case(case, size, frames, shape, sheets, with_vtk):
    from isplat.renderer import Renderer

    base = make_scene(case, size, shape=shape)
    refs = {k: REF.reference(base, kind=k)[0] for k in REF.kinds_for(case)}
    rows, jobs = [], []
    for knob, value, ov in settings(sheets):
        r = Renderer(make_scene(case, size, extra=ov, shape=shape))
        rows.append(dict(case=case, renderer="isplat", knob=knob, value=value,
                         default=(knob == "defaults")))
        jobs.append(lambda r=r: r.render_view(0)[0])
    if with_vtk:
        from .peers import VTKView

        r0 = Renderer(base)
        for step in VTK_STEPS:
            v = VTKView(r0, 0, sample_distance=step)
            rows.append(dict(case=case, renderer="VTK", knob="sample_distance", value=step, default=(step == 1.0)))
            jobs.append(lambda v=v: (v.render(), v.image_float())[1])
    times = [[] for _ in jobs]
    imgs = [None] * len(jobs)
    warm = [0.0] * len(jobs)
    for _ in range(2):                                   # warm-up: JIT, caches, VTK's gradients
        for i, job in enumerate(jobs):
            t0 = time.perf_counter()
            imgs[i] = job()
            warm[i] = time.perf_counter() - t0
    # a setting's turn in a round: one frame untimed (the first frame after another setting's is slower by up to
    # a few ms, by how much depends on the setting), then k frames back to back, timed, k such that they last
    # MIN_MS at least: a frame of a few ms often falls inside one time slice of another process, k average it out
    reps = [max(1, math.ceil(MIN_MS / (1000 * w))) for w in warm]
    # a fresh random order each round (seeded: the same orders every run), so that no setting always follows the
    # same one (a rotation would put the defaults, job 0, after VTK's last point in most rounds)
    rng = np.random.default_rng(CASES.index(case))
    for _ in range(frames):
        for i in rng.permutation(len(jobs)):
            imgs[i] = jobs[i]()
            t0 = time.perf_counter()
            for _ in range(reps[i]):
                imgs[i] = jobs[i]()
            times[i].append((time.perf_counter() - t0) / reps[i])
    for row, img, t, k in zip(rows, imgs, times, reps):
        row["times"] = [1000 * x for x in t]             # ms per frame per round, in round order (paired)
        row["reps"] = k
        row["ms"] = statistics.median(row["times"])
        for kind, ref in refs.items():
            row[kind] = errors(img, ref)
    return rows, refs


def pixels_per_voxel(scene) -> float:
    from isplat.augfile import open_augmented
    from isplat.frame import views_for

    v = views_for(scene, open_augmented(scene.data.augmented))[0]
    return float(v.geom.spacing.min() / v.frame.pixel_size)


# ---- Pareto front and plot ---------------------------------------------------------------------------------------
def front(rows, kind, tol):
    """Indices into ``rows`` of the points on their Pareto front against reference ``kind``, fastest first: no
    other row dominates them by tests/paired_times.py (paired sign test on the per-round times, errors within
    ``tol`` equal)."""
    return PT.front([r["times"] for r in rows], [r[kind]["rmse"] for r in rows], tol)


def dominates(a, b, kind, tol):
    """Row ``a`` dominates row ``b`` against reference ``kind`` (tests/paired_times.py ``dominates``)."""
    return PT.dominates(a["times"], a[kind]["rmse"], b["times"], b[kind]["rmse"], tol)


def vs(a, b) -> PT.Comparison:
    """Row ``a``'s frame times against row ``b``'s, round by round."""
    return PT.compare(a["times"], b["times"])


def _label(row):
    """A row's setting, its technique first for isplat's rows ("post, ET 0.95", "pre, radius 2.0")."""
    if row["knob"] == "defaults":
        return "post, defaults"
    if row["renderer"] == "VTK":
        return f"VTK {row['value']:g}"
    short = {"early_termination": "ET", "footprint_radius": "pre, radius", "footprint_table": "pre, table",
             "footprint_sigma": "pre, sigma", "precision": "", "threads": "threads", "method": "",
             "sheets": "pre, sheets", "classification": "", "slice_stride": "stride", "termination": "termination"}
    label = f"{short[row['knob']]} {row['value']}".strip()
    return label if label.startswith("pre") else "post, " + label


def plot(rows_by_case, path: Path, conv=None):
    """Error (RMSE against the reference) against median frame time, one panel per case and reference."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        _log("matplotlib missing (pip install 'isplat[plot]'): no plot")
        return None
    panels = [(c, k) for c in rows_by_case for k in REF.kinds_for(c)]
    ncol = 2
    nrow = -(-len(panels) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(6.0 * ncol, 4.6 * nrow), squeeze=False)
    for ax in axes.ravel()[len(panels):]:
        ax.set_visible(False)
    for ax, (case, kind) in zip(axes.ravel(), panels):
        rows = rows_by_case[case]
        iso = [r for r in rows if r["renderer"] == "isplat"]
        vtk = [r for r in rows if r["renderer"] == "VTK"]
        pts = [(r["ms"], r[kind]["rmse"]) for r in iso]
        on = front(iso, kind, conv[(case, kind)]["rmse"] if conv else 0.0)
        ax.plot([pts[i][0] for i in on], [pts[i][1] for i in on], "-", color="tab:blue", lw=1, alpha=0.6,
                label="isplat Pareto front")
        ax.scatter([p[0] for p in pts], [p[1] for p in pts], s=18, color="tab:blue", label="isplat settings")
        for r, p in zip(iso, pts):
            ax.annotate(_label(r), p, fontsize=6, xytext=(3, 2), textcoords="offset points")
        d = next(r for r in iso if r["default"])
        ax.scatter([d["ms"]], [d[kind]["rmse"]], marker="*", s=160, color="tab:red", zorder=5, label="isplat defaults")
        if vtk:
            ax.plot([r["ms"] for r in vtk], [r[kind]["rmse"] for r in vtk], "s--", color="tab:green", ms=5, lw=1,
                    label="VTK sample distances")
            for r in vtk:
                ax.annotate(f"{r['value']:g}" + (" (default)" if r["default"] else ""), (r["ms"], r[kind]["rmse"]),
                            fontsize=6, xytext=(3, -8), textcoords="offset points", color="tab:green")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("median frame time (ms)")
        ax.set_ylabel(f"RMSE against reference {'(a) grid' if kind == 'grid' else '(b) analytic'}")
        ax.set_title(f"{case}: against {'(a)' if kind == 'grid' else '(b)'}", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6, loc="best")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_csv(rows, path: Path):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["case", "renderer", "knob", "value", "default", "median_ms", "ratio_to_defaults",
                    "rounds_faster_than_defaults", "rounds", "reference", "max_abs", "rmse", "psnr_db",
                    "share_8bit_pixels_changed"])
        for r in rows:
            d = next(x for x in rows if x["case"] == r["case"] and x["default"] and x["renderer"] == "isplat")
            c = vs(r, d)
            for kind in ("grid", "analytic"):
                if kind in r:
                    e = r[kind]
                    w.writerow([r["case"], r["renderer"], r["knob"], r["value"], int(r["default"]), f"{r['ms']:.3f}",
                                f"{c.ratio:.4f}", c.wins, len(r["times"]),
                                "a" if kind == "grid" else "b", f"{e['max']:.6g}", f"{e['rmse']:.6g}",
                                f"{e['psnr']:.3f}", f"{e['px8']:.6f}"])


def write_rounds_csv(rows, path: Path):
    """Every frame time (ms), one row per case and setting, one column per round (round order): the data the
    page's "faster" verdicts come from (tests/paired_times.py reruns them)."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["case", "renderer", "setting", "frames_per_round"]
                   + [f"round_{n}" for n in range(len(rows[0]["times"]))])
        for r in rows:
            w.writerow([r["case"], r["renderer"], _label(r), r["reps"]] + [f"{t:.4f}" for t in r["times"]])


# ---- popping -----------------------------------------------------------------------------------------------------
def switch_azimuth(scene, lo=0.0, hi=90.0) -> tuple[float, str, str]:
    """The azimuth in (lo, hi) where the principal axis of ``scene``'s camera changes (bisection)."""
    from isplat import camera as C
    from isplat.augfile import open_augmented

    aug = open_augmented(scene.data.augmented)
    geom = C.volume_geometry(aug.shape, scene.volume.spacing or aug.spacing_ijk, scene.volume.origin,
                             scene.volume.axes)
    cam0 = scene.views[0]

    def axis(az):
        f = C.view_frame(dataclasses.replace(cam0, azimuth=az), geom, scene.image.width, scene.image.height)
        return C.principal_axis(f, geom)

    a_lo = axis(lo)
    if a_lo == axis(hi):
        raise RuntimeError(f"no principal-axis switch between azimuth {lo} and {hi}")
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if axis(mid) == a_lo else (lo, mid)
    return 0.5 * (lo + hi), a_lo[0], axis(hi)[0]


def measure_popping(size, shape, extra, label):
    from isplat.renderer import Renderer

    base = make_scene("head", size, extra=extra, shape=shape)
    s, ax_lo, ax_hi = switch_azimuth(base)
    cams = [dataclasses.replace(base.views[0], azimuth=s + o) for o in POP_OFFSETS]
    r = Renderer(base, views=cams)
    out = [r.render_view(n) for n in range(len(cams))]
    imgs, axes = [o[0] for o in out], [o[1].axis for o in out]
    steps = [dict(a0=s + POP_OFFSETS[n], a1=s + POP_OFFSETS[n + 1], cross=axes[n] != axes[n + 1],
                  **errors(imgs[n + 1], imgs[n])) for n in range(len(cams) - 1)]
    same = [x["rmse"] for x in steps if not x["cross"]]
    cross = [x for x in steps if x["cross"]]
    ratio = (cross[0]["rmse"] / statistics.median(same)) if cross and same and statistics.median(same) > 0 else None
    return dict(label=label, switch=s, ax_lo=ax_lo, ax_hi=ax_hi, steps=steps, imgs=imgs, ratio=ratio)


def popping_strip(pop: dict, path: Path):
    """The view just before the switch, just after, |difference| across the switch, |difference| between two
    views 0.2 degrees apart on one side (both differences with the same gain)."""
    import imageio.v3 as iio

    n = POP_OFFSETS.index(-0.1)
    a, b, c = pop["imgs"][n - 1], pop["imgs"][n], pop["imgs"][n + 1]
    cross = np.abs(c[..., :3] - b[..., :3]).max(-1)
    same = np.abs(b[..., :3] - a[..., :3]).max(-1)
    gain = 1.0 / max(float(np.percentile(cross, 99.5)), 1e-6)
    panels = [b[..., :3], c[..., :3]] + [np.repeat(np.clip(d * gain, 0, 1)[..., None], 3, -1) for d in (cross, same)]
    gap = np.ones((panels[0].shape[0], 4, 3))
    strip = np.concatenate([x for p in panels for x in (p, gap)][:-1], axis=1)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, (np.clip(strip, 0, 1) * 255 + 0.5).astype(np.uint8))
    return gain


# ---- page --------------------------------------------------------------------------------------------------------
def _psnr(p):
    return "exact" if math.isinf(p) else f"{p:.1f}"


def case_table(rows, kinds, conv, case) -> list[str]:
    d = next(r for r in rows if r["default"] and r["renderer"] == "isplat")
    head = "| renderer | setting | ms/frame | x defaults | rounds faster |"
    sep = "|---|---|---:|---:|---:|"
    for k in kinds:
        tag = "(a)" if k == "grid" else "(b)"
        head += f" RMSE {tag} | PSNR {tag} dB | max {tag} | 8-bit px {tag} |"
        sep += "---:|---:|---:|---:|"
    L = [head, sep]
    iso = [r for r in rows if r["renderer"] == "isplat"]
    fronts = {k: set(front(iso, k, conv[(case, k)]["rmse"])) for k in kinds}
    for r in rows:
        name = _label(r) + (" **(default)**" if r["default"] and r["renderer"] == "isplat" else
                            " (VTK's default)" if r["default"] else "")
        c = vs(r, d)
        ratio = f"{c.ratio:.2f}" + (" (faster)" if c.faster else " (slower)" if vs(d, r).faster else "")
        wins = "" if r is d else f"{c.wins}/{len(r['times'])}"
        line = f"| {r['renderer']} | {name} | {r['ms']:.1f} | {ratio} | {wins} |"
        for k in kinds:
            e = r[k]
            on = r["renderer"] == "isplat" and iso.index(r) in fronts[k]
            line += f" {e['rmse']:.4f}{' ·' if on else ''} | {_psnr(e['psnr'])} | {e['max']:.3f} | {100 * e['px8']:.1f}% |"
        L.append(line)
    return L


def _point(r, d, k) -> str:
    """Row ``r``'s time and RMSE, and its frames against the defaults' ``d``: "post, ET 0.98: 5.1 ms, 0.0065,
    0.97x the defaults, faster in 12/21 rounds"."""
    c = vs(r, d)
    return (f"{_label(r)}: {r['ms']:.1f} ms, {r[k]['rmse']:.4f}, {c.ratio:.2f}x the defaults, faster in "
            f"{c.wins}/{len(r['times'])} rounds")


def front_sentences(rows_by_case, conv) -> list[str]:
    """Which defaults sit on the front, per case and reference, from the measured points (RMSE differences
    within the reference's step-halving RMSE count as ties; "faster" is tests/paired_times.py's paired test)."""
    out = []
    for case, rows in rows_by_case.items():
        iso = [r for r in rows if r["renderer"] == "isplat"]
        vtk = [r for r in rows if r["renderer"] == "VTK"]
        for k in REF.kinds_for(case):
            tol = conv[(case, k)]["rmse"]
            on_front = front(iso, k, tol)
            di = next(i for i, r in enumerate(iso) if r["default"])
            d = iso[di]
            beat = _beaters(iso, d, k, tol)
            on = di in on_front
            txt = (f"- **{case}**, against {'(a)' if k == 'grid' else '(b)'}: the defaults "
                   f"({d['ms']:.1f} ms, RMSE {d[k]['rmse']:.4f}) are {'on' if on else '**not** on'} isplat's front")
            if not on:
                txt += " (beaten by " + "; ".join(_point(r, d, k) for r in beat) + ")"
            ties = [r for r in iso if r is not d and all(r is not b for b in beat)
                    and abs(r[k]["rmse"] - d[k]["rmse"]) <= tol and not vs(d, r).faster]
            if ties:
                txt += ("; as close and not slower, but not faster by the test either (ties): "
                        + "; ".join(_point(r, d, k) for r in ties))
            txt += "; front: " + ", ".join(_label(iso[i]) for i in on_front) + "."
            if vtk:
                vd = next(r for r in vtk if r["default"])
                better = [r for r in vtk if dominates(r, d, k, tol)]
                txt += (f" VTK at its default step 1: {vd['ms']:.1f} ms, RMSE {vd[k]['rmse']:.4f} "
                        f"({'closer to' if vd[k]['rmse'] < d[k]['rmse'] else 'farther from'} the reference than "
                        f"isplat's defaults, {vs(vd, d).ratio:.2f}x their time)")
                txt += ("; VTK points that beat isplat's defaults: "
                        + (", ".join(f"step {r['value']:g}" for r in better) or "none") + ".")
            out.append(txt)
    return out


def _beaters(iso, d, k, tol):
    """The isplat rows that dominate row ``d`` against reference ``k`` (:func:`dominates`)."""
    return [r for r in iso if r is not d and dominates(r, d, k, tol)]


def stride_sentences(rows_by_case, conv) -> list[str]:
    """Where the slice stride's points (1, the defaults, and each n of KNOBS) lie, per case and reference, and
    whether the default stride, 1, stays on the front: beaten by no stride, and on isplat's whole front or not."""
    out = ["`render.slice_stride = n` samples the slices whose index is a multiple of n, each with the opacity "
           "1 - (1 - alpha)^n of n slices (isplat/splat/post.py, formats/scene.md); stride 1 is the defaults' point. "
           "Per case and reference: each stride's time and RMSE (*front*: on isplat's front), its frames against "
           "stride 1's (median per-round ratio, rounds faster, *faster* when the test calls it), and whether a "
           "stride beats the default stride 1 (dominates it, as above).\n"]
    for case, rows in rows_by_case.items():
        iso = [r for r in rows if r["renderer"] == "isplat"]
        pts = [r for r in iso if r["knob"] in ("defaults", "slice_stride")]
        for k in REF.kinds_for(case):
            tol = conv[(case, k)]["rmse"]
            on_front = set(front(iso, k, tol))
            parts = [f"{r['value'] or 1}: {r['ms']:.1f} ms, {r[k]['rmse']:.4f}"
                     + ("" if c is None else f", {c.ratio:.2f}x in {c.wins}/{len(r['times'])} rounds"
                        + (" faster" if c.faster else " (not called faster)"))
                     + (" (front)" if iso.index(r) in on_front else "")
                     for r, c in ((r, None if r is pts[0] else vs(r, pts[0])) for r in pts)]
            beat = _beaters(iso, pts[0], k, tol)
            strides = [f"stride {r['value']}" for r in beat if r["knob"] == "slice_stride"]
            others = [_label(r) for r in beat if r["knob"] != "slice_stride"]
            txt = (f"- **{case}**, against {'(a)' if k == 'grid' else '(b)'}: stride " + "; ".join(parts) + ". "
                   + (f"{', '.join(strides)} beat the default stride 1" if strides else
                      "No stride beats the default stride 1: it stays on the front of the strides")
                   + ("; it is on isplat's whole front." if not beat else
                      f"; on isplat's whole front it is beaten by {', '.join(others)} (not strides; see above)."
                      if others else "."))
            out.append(txt)
    return out


def render_doc(rows_by_case, conv, pops, quick, size, frames, seconds, load0, sheets, vtk_cls, gain, ppv) -> str:
    from isplat.scene_schema import STOP_EARLY_TERMINATION as stop_et, RenderOptions, defaults
    from isplat.splat.footprint import MIN_SIGMA_PIXELS

    fill_et = defaults(RenderOptions)["early_termination"]
    ppv_head = ppv.get("head", float("nan"))

    cmd = "python -m benchmarks accuracy" + (" --quick" if quick else "")
    L = [f"```\n{cmd}\n```\n", "# Accuracy against run time: error against the truth\n",
         f"Machine: {_doc.machine_line()}; git {_doc.git_rev()}; load average {load0:.2f} at the start; the bench "
         f"took {seconds:.0f} s. The numbers below, `accuracy.csv` and `accuracy_rounds.csv` (every frame time) "
         f"come from this run; rerun the command after changing the renderer.\n",
         "Error is measured against references that are not splatting (docs/reference.md, "
         "`benchmarks/reference.py`): **(a)** the converged float64 emission-absorption ray integral of the same "
         "8-bit densities with trilinear reconstruction and the transfer function applied after it, step 0.05 "
         "voxel, shaded with the same lights from the reconstructed gradient; **(b)** for Marschner-Lobb, the same "
         "integral of the exact signal (no grid). isplat's default (`render.classification = \"post\"`, "
         "isplat/splat/post.py) reconstructs the density in each slice (bilinear: the tent kernel's splat) and "
         "classifies it after, so along each ray it samples the trilinear field at the slice planes; the *pre* rows "
         "are the paper's splatting, each voxel classified *before* reconstruction and spread by a Gaussian "
         "footprint, whose blur of sharp transfer-function edges is most of their error.\n",
         f"Every image is {size}x{size}, orthographic, one view per case. Each setting is the format defaults "
         f"(`method = \"indexed\"`, `classification = \"post\"`, `early_termination = {fill_et:g}` (scene "
         f"version 8; {stop_et:g} before, and where a pixel is stopped), `termination = \"fill\"` (scene version "
         f"7: a pixel that stops is filled with its last sample's colour; `termination stop` stops it at "
         f"{stop_et:g}), "
         "`precision = \"float32\"`, `threads = 0` = all cores) with one knob changed; the footprint's knobs "
         "(`footprint_radius = 2.5`, `footprint_sigma = 0.7`, `footprint_table = 1024` by default) act on "
         "pre-classified splatting only, so their rows change one of them with `classification = \"pre\"`. "
         f"Every setting of a case (and VTK's points) takes one turn per round, in a fresh random order each "
         f"round, for {frames} rounds after 2 warm-up rounds, so that load from other processes hits the settings of "
         "a round alike. In its turn a setting renders one frame untimed (the first frame after another "
         "setting's was slower by up to a few ms, more for some settings than others), then k frames back to "
         f"back, k such that they last {MIN_MS:g} ms at least (by the warm-up); its frame time in the round is "
         "their mean (a frame of a few ms often falls inside one time slice of another process; "
         "`accuracy_rounds.csv` has k and every time). "
         "ms/frame is the median over the rounds of a setting's frame time, *x defaults* the median over the "
         "rounds of its frame time over the defaults' in the same round, *rounds faster* the rounds where its "
         "frame was faster than the defaults'. "
         "Errors over RGB in [0, 1] after compositing on the background: RMSE, PSNR = -20 log10(RMSE), max abs "
         "error, and the share of pixels where an 8-bit channel differs. A `·` after an RMSE marks a setting on "
         "isplat's Pareto front (no other isplat setting dominates it; the rule is in the next section).\n",
         ("VTK: `vtkFixedPointVolumeRayCastMapper` offscreen through `" + vtk_cls + "`, set up as in "
          "docs/performance.md (benchmarks/peers.py: same densities, transfer function, camera, lights, threads), "
          "at sample distances " + ", ".join(f"{s:g}" for s in VTK_STEPS) + " voxel (1 is its default); its image "
          "is read back as 8 bits.\n") if vtk_cls else "VTK was not available in this run: no VTK points.\n",
         ("`render.sheets` exists in this isplat: the row *sheets image* is `render.sheets = \"image\"`.\n" if sheets
          else "`render.sheets` does not exist in this isplat (image-aligned sheets not merged yet): no sheets row.\n"),
         "Cases:\n"]
    for c in rows_by_case:
        L.append(f"- **{c}**: {REF.CASES[c][2]}; {ppv[c]:.2f} pixels per voxel, so `footprint_sigma` below about "
                 f"{MIN_SIGMA_PIXELS / ppv[c]:.2f} voxel is raised to the footprint's floor of {MIN_SIGMA_PIXELS:g} "
                 "pixel (isplat.splat.footprint.MIN_SIGMA_PIXELS): pre sigma rows below it equal the *pre* row")
    L.append("\nThe references give a volume the extent of its voxel boxes (as isplat does); VTK's volume ends at "
             "the outer voxel centres, half a voxel thinner on each face. Only the Marschner-Lobb signal has material "
             "on the faces, so part of VTK's error there is that convention, not its sampling.")
    L += ["", "![error against time](img/accuracy_pareto.png)\n",
          "`img/accuracy_pareto.png`: RMSE against the reference (log) over median frame time (log); blue: isplat "
          "settings and their Pareto front (by the rule below: settings whose times the test cannot tell apart "
          "all stay on it, so its line need not fall at every step), red star: the defaults, green: VTK at its "
          "sample distances.\n",
          "## Which defaults sit on the front\n"]
    need = PT.min_wins(frames)
    L.append("The rule (tests/paired_times.py, with its tests in tests/test_paired_times.py). Setting A is "
             "**faster** than B only when both hold: the median over the rounds of A's frame time over B's in the "
             f"same round is below {1 - PT.MARGIN:g} (differences within {100 * PT.MARGIN:g}% are ties however "
             "consistent), and a one-sided sign test over the rounds rejects \"A's frame is as likely slower as "
             f"faster\" at level {PT.ALPHA:g}: with {frames} rounds, A's frame must be the faster in "
             + (f"at least {need} of them" if need else "more rounds than there are (too few rounds: nothing is "
                "called faster)")
             + ". The sign test assumes nothing about the noise and counts a frame hit by a burst of load as one lost "
             "round, whatever its size. Otherwise neither is faster: a tie. A is **not slower** than B when, by the "
             f"same sign test, A's frame is below {1 + PT.MARGIN:g} times B's in that many rounds. RMSE differences "
             "smaller than the reference's own (what halving its step changes, see the convergence table below) "
             "count as ties. A **dominates** B when A's RMSE is at most B's plus that tie margin and A is faster, or "
             "closer by more than the margin and not slower; the front is the settings no other dominates. Every "
             "claim needs its evidence: a closer setting whose frames do not show that it is not slower leaves the "
             "others on the front. Each sentence lists the settings that dominate the defaults, and the settings as "
             "close as the defaults that the test calls neither faster nor slower (ties), with their frames against "
             "the defaults'.\n")
    L += front_sentences(rows_by_case, conv)
    L += ["", "### Every n-th slice (`render.slice_stride`)\n"] + stride_sentences(rows_by_case, conv)
    L.append("")
    for c, rows in rows_by_case.items():
        L.append(f"## {c}\n")
        L += case_table(rows, REF.kinds_for(c), conv, c)
        L.append("")
    L.append("## How converged the references are\n")
    L.append("Halving the reference's step (from the step in the table) changes these images by (docs/reference.md has "
             "every case):\n")
    L.append("| case | reference | step (voxel) | max abs | RMSE | smallest RMSE in the case's table | ratio |\n"
             "|---|---|---:|---:|---:|---:|---:|")
    for (c, k), e in conv.items():
        least = min(r[k]["rmse"] for r in rows_by_case[c])
        L.append(f"| {c} | {'(a)' if k == 'grid' else '(b)'} | {e['step']:g} | {e['max']:.2e} | {e['rmse']:.2e} | "
                 f"{least:.2e} | {least / max(e['rmse'], 1e-300):.0f}x |")
    worst = min(min(r[k]["rmse"] for r in rows_by_case[c]) / max(e["rmse"], 1e-300) for (c, k), e in conv.items())
    L.append(f"\nEvery RMSE in the tables is at least {worst:.0f}x what halving the reference's step changes, so the "
             "references resolve the RMSE differences between settings that are larger than that; max-abs errors "
             "are resolved only above the max-abs column here.\n")
    L.append("## Popping: the principal-axis switch (Mueller and Crawfis 1998)\n")
    p0 = pops[0]
    L.append(f"The head's slices switch from axis `{p0['ax_lo']}` to `{p0['ax_hi']}` at azimuth {p0['switch']:.6f} "
             "degrees (bisection on `isplat.camera.principal_axis`). Views 0.2 degrees apart straddle it; the ratio "
             "is the RMSE across the switch over the median RMSE between neighbouring views on one side (1 would "
             "be no popping).\n")
    L.append("| settings | RMSE across the switch | median RMSE one side | ratio |\n|---|---:|---:|---:|")
    for pop in pops:
        cross = [s for s in pop["steps"] if s["cross"]]
        same = statistics.median(s["rmse"] for s in pop["steps"] if not s["cross"])
        ratio = "n/a" if pop["ratio"] is None else f"{pop['ratio']:.1f}x"
        across = f"{cross[0]['rmse']:.2e}" if cross else "no switch seen"
        L.append(f"| {pop['label']} | {across} | {same:.2e} | {ratio} |")
    post, pre = pops[0], pops[1]
    one_side = {p["label"]: statistics.median(s["rmse"] for s in p["steps"] if not s["cross"]) for p in (post, pre)}
    L.append(f"\nPost-classified (the defaults), views 0.2 degrees apart on one side differ by RMSE "
             f"{one_side[post['label']]:.2e}, pre-classified by {one_side[pre['label']]:.2e}: post-classification "
             f"samples the reconstructed field at the pixel centres without a footprint's blur, so where voxels are "
             f"smaller than pixels ({ppv_head:.2f} pixels per voxel here) the image changes more from one view to the "
             f"next (aliasing, as a ray caster's does), while the switch of slice axis adds little to that.")
    L.append(f"\n![popping](img/popping_head.png)\n\n`img/popping_head.png` (defaults): the view 0.1 degree before "
             f"the switch, 0.1 degree after, |difference| across the switch and |difference| between two views 0.2 "
             f"degrees apart on one side, both differences times the same gain {gain:.0f}.\n")
    return "\n".join(L) + "\n"


def run(out_dir: Path, quick: bool) -> Path:
    t0 = time.time()
    load0 = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    out_dir = Path(out_dir)
    size = 48 if quick else 256
    frames = 7 if quick else ROUNDS   # 7: the fewest rounds in which the sign test can call anything
    sheets = sheets_key()
    vtk_cls = vtk_window()
    rows_by_case, conv, ppv = {}, {}, {}
    for case in CASES:
        shape = REF.QUICK_SHAPES[case] if quick else None
        ppv[case] = pixels_per_voxel(make_scene(case, size, shape=shape))
        _log(f"{case}: references and {len(settings(sheets))} settings" + (" + VTK" if vtk_cls else ""))
        rows, _ = measure_case(case, size, frames, shape, sheets, vtk_cls is not None)
        rows_by_case[case] = rows
        for k in REF.kinds_for(case):
            conv[(case, k)] = REF.convergence(make_scene(case, size, shape=shape), k)
    _log("popping")
    shape = REF.QUICK_SHAPES["head"] if quick else None
    pops = [measure_popping(size, shape, [], "defaults (post-classified, axis-aligned sheets)"),
            measure_popping(size, shape, REF.render_overrides(PRE), "pre-classified, axis-aligned sheets"),
            measure_popping(size, shape, REF.render_overrides({**PRE, "footprint_radius": 4.0,
                                                                "footprint_table": 1 << 20, "precision": "float64",
                                                                "early_termination": 1.0}),
                            "pre, radius 4, table 2^20, float64, ET off")]
    if sheets:
        pops.append(measure_popping(size, shape, sheets, "pre-classified with sheets = \"image\""))
    gain = popping_strip(pops[0], out_dir / "img" / "popping_head.png")
    all_rows = [r for rows in rows_by_case.values() for r in rows]
    write_csv(all_rows, out_dir / "accuracy.csv")
    write_rounds_csv(all_rows, out_dir / "accuracy_rounds.csv")
    plot(rows_by_case, out_dir / "img" / "accuracy_pareto.png", conv)
    p = out_dir / "accuracy.md"
    p.write_text(render_doc(rows_by_case, conv, pops, quick, size, frames, time.time() - t0, load0, sheets, vtk_cls,
                            gain, ppv))
    return p
