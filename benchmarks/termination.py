"""What a pixel that reaches early termination gets: filled with its last sample's colour, or stopped as it is.

``python -m benchmarks termination [--out docs] [--quick]`` writes the section ``termination`` of
``termination.md`` (a page of its own: ``accuracy.md`` is rewritten whole by :mod:`benchmarks.accuracy`): on
each case of :mod:`benchmarks.peers` (the smallest of its image sizes; no VTK needed), ``"stop"`` (what a pixel
got before version 7) at the opacity a stopped pixel stops at (0.99, or the case's own), against the
post-classified default, ``render.termination = "fill"``: at that opacity (version 7), at the fill's default
opacity (version 8: 0.986, or the case's own) and below it. Per setting: its RMSE against reference (a) of
:mod:`benchmarks.reference` (the converged ray integral, no early termination), the samples it composited, and
its median frame time over interleaved rounds with its median per-round ratio to the stop's. The sentences
under the table are computed from it: where the fill is closer than the stop at the same opacity, whether the
default is as close as the stop in every case, and how far below the fill stays so (what the default's opacity
was chosen by). A second table gives the same errors over a white background, where the stop loses least.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

from . import _doc

SECTION = "termination"
TECHNIQUES = ["post"]
SOURCES = _doc.sources(_doc.RENDER, _doc.READ, _doc.SAMPLES, ("benchmarks/termination.py", "benchmarks/peers.py",
                                                              "benchmarks/reference.py", "tests/ray_reference.py"))
LOWER = (0.01, 0.02, 0.04)      # the fill also at the stop's opacity minus these
ROUNDS, QUICK_ROUNDS = 9, 2
WHITE = (1.0, 1.0, 1.0, 1.0)    # the background of the second table


def settings(stop_et: float, fill_et: float) -> list[tuple[str, float]]:
    """(termination, early_termination) of a case whose scene stops a pixel at ``stop_et`` and fills it at
    ``fill_et`` (its defaults for either): the stop (before version 7), the fill at the stop's opacity (version
    7), the fill at its own default (version 8), then the fill at the lower opacities."""
    lower = [("fill", round(stop_et - d, 4)) for d in LOWER]
    out = [("stop", stop_et), ("fill", stop_et)]
    for p in [("fill", fill_et)] + lower:
        if p not in out:
            out.append(p)
    return out


def measure(name: str, quick: bool, rounds: int, extra=()) -> dict:
    """One case (``extra``: overrides of its scene): per setting its RMSE against reference (a), samples
    composited and, with ``rounds``, frame times."""
    from isplat.frame import BandLearning, render_frame, views_for
    from isplat.renderer import Renderer

    from . import peers as P
    from . import reference as REF

    size = min(P.CASES[name][5 if quick else 4])
    base = P.peer_scene(name, size, quick, extra=extra)
    ref, _, _ = REF.reference(base)
    sel = Renderer(base).selection
    stop_et = P.peer_scene(name, size, quick, {"termination": "stop"}, extra).render.early_termination
    points = []
    for term, et in settings(stop_et, base.render.early_termination):
        view = views_for(P.peer_scene(name, size, quick, {"termination": term, "early_termination": et}, extra),
                         sel)[0]
        img, st = render_frame(sel, view, None, BandLearning())
        points.append(dict(term=term, et=et, view=view, bands=BandLearning(), times=[], samples=st.drawn,
                           rmse=REF.errors(img, ref)["rmse"], default=term == "fill" and
                           et == base.render.early_termination))
    for rnd in range(rounds):           # interleaved, the order turning each round; a warm frame before each
        for p in points[rnd % len(points):] + points[:rnd % len(points)]:
            render_frame(sel, p["view"], None, p["bands"])
            t0 = time.perf_counter()
            render_frame(sel, p["view"], None, p["bands"])
            p["times"].append(time.perf_counter() - t0)
    stop = points[0]["times"]
    for p in points:
        p["ms"] = _doc.median_ms(p["times"]) if rounds else None
        p["ratio"] = statistics.median(a / b for a, b in zip(p["times"], stop)) if rounds else None
        del p["view"], p["bands"], p["times"]
    return dict(case=name, size=size, points=points)


def _label(p) -> str:
    return f'{p["term"]}, ET {p["et"]:g}' + (" (default)" if p["default"] else "")


def _digits(x: float) -> float:
    """``x`` to the table's precision, four significant digits."""
    return float(f"{x:.4g}")


def summary(results) -> list[str]:
    """The sentences the table supports: fill against stop at the stop's opacity, the default fill against that
    stop, and how low the fill may go."""
    closer = [r["case"] for r in results if r["points"][1]["rmse"] < r["points"][0]["rmse"]]
    farther = [f"{r['case']} ({r['points'][1]['rmse']:.6f} against {r['points'][0]['rmse']:.6f})"
               for r in results if r["points"][1]["rmse"] > r["points"][0]["rmse"]]
    lines = [f"- At each case's own early-termination opacity the fill is closer to reference (a) than the stop in "
             f"{len(closer)} of {len(results)} cases" + (f"; farther in: {'; '.join(farther)}." if farther else ".")]
    defaults = [(r, next(p for p in r["points"] if p["default"])) for r in results]
    worse = [f'{r["case"]} ({p["rmse"]:.6f} against {r["points"][0]["rmse"]:.6f})' for r, p in defaults
             if _digits(p["rmse"]) > _digits(r["points"][0]["rmse"])]
    tied = [f'{r["case"]} ({p["rmse"]:.9f} against {r["points"][0]["rmse"]:.9f})' for r, p in defaults
            if p["rmse"] > r["points"][0]["rmse"] and _digits(p["rmse"]) <= _digits(r["points"][0]["rmse"])]
    ratios = [p["ratio"] for _, p in defaults if p["ratio"] is not None]
    lines.append("- The default (the fill at its default opacity, marked): "
                 + (f"farther from reference (a) than the stop at the stop's opacity in {len(worse)} cases "
                    f"({'; '.join(worse)})" if worse else
                    f"no farther from reference (a) than the stop at the stop's opacity in any of the "
                    f"{len(results)} cases, RMSE to four significant digits as in the table")
                 + (f"; farther below that precision in {'; '.join(tied)}" if tied else "")
                 + (f". Its frames are {min(ratios):.2f}-{max(ratios):.2f}x the stop's." if ratios else "."))
    for d in LOWER:
        worse = [f'{r["case"]} {p["rmse"]:.6f} against {r["points"][0]["rmse"]:.6f}'
                 for r in results for p in r["points"][2:]
                 if abs(p["et"] - round(r["points"][0]["et"] - d, 4)) < 1e-9 and p["rmse"] > r["points"][0]["rmse"]]
        ratios = [p["ratio"] for r in results for p in r["points"][2:]
                  if abs(p["et"] - round(r["points"][0]["et"] - d, 4)) < 1e-9 and p["ratio"] is not None]
        verdict = ("no farther than the stop at the stop's opacity in every case" if not worse else
                   f"farther than the stop at the stop's opacity in {len(worse)} cases ({'; '.join(worse)})")
        lines.append(f"- The fill {d:g} below the stop's opacity: {verdict}" +
                     (f"; its frames {min(ratios):.2f}-{max(ratios):.2f}x the stop's." if ratios else "."))
    return lines


def body(results, white, command: str, rounds: int) -> str:
    from isplat.scene_schema import STOP_EARLY_TERMINATION as stop_et, RenderOptions, defaults

    fill_et = defaults(RenderOptions)["early_termination"]
    L = ["### Filling a pixel that stops (`render.termination`)", "",
         f"`{command}` ({_doc.machine_line()}; {rounds} interleaved rounds, each timed frame after a warm one of "
         "its own). Technique **post** throughout. `render.termination = \"fill\"` (the default from scene "
         f"version 7; from version 8 at `render.early_termination = {fill_et:g}` by default, {stop_et:g} before): "
         "a pixel that "
         "reaches `render.early_termination` takes the colour of the sample that took it "
         "there for the rest of its transmittance (isplat.splat.composite.saturated); `\"stop\"` (before version "
         "7): it keeps the opacity it reached, the background showing through the rest. Reference (a) integrates "
         "the whole ray, so what a stopped pixel leaves out is error: the stop's error there is everything behind "
         "the point, the fill's only the change of colour behind it. Cases: benchmarks/peers.py's, each at its "
         f"smallest image size; the stop at the opacity a stopped pixel stops at ({stop_et:g}, the engine's own "
         f"0.98), the fill there, at its default opacity (*default*: {fill_et:g}, the engine's own 0.98) and "
         f"{', '.join(f'{d:g}' for d in LOWER[:-1])} and {LOWER[-1]:g} "
         "below the stop's; ratio = median per-round ratio of the frame to the stop's.", "",
         "| case | pixels | setting | RMSE (a) | samples | ms | / stop |", "|---|---:|---|---:|---:|---:|---:|"]
    for r in results:
        for p in r["points"]:
            L.append(f'| {r["case"]} | {r["size"]} | {_label(p)} | {p["rmse"]:.5f} | {p["samples"]:,} | '
                     f'{p["ms"]:.1f} | {p["ratio"]:.2f} |')
    L += [""] + summary(results)
    L += ["", "#### On a white background", "",
          "The fill's estimate and the stop's are judged above over the peers' black background, where the stop "
          "leaves black in place of the colour behind. Over a background as bright as the material, the stop's "
          "error shrinks and the fill's does not, so the same cases, settings and reference over "
          f"`image.background = {list(WHITE)}` (errors only: the frame does not depend on the background):", "",
          "| case | pixels | setting | RMSE (a) |", "|---|---:|---|---:|"]
    for r in white:
        for p in r["points"]:
            L.append(f'| {r["case"]} | {r["size"]} | {_label(p)} | {p["rmse"]:.5f} |')
    return "\n".join(L + [""] + summary(white)) + "\n"


def run(out_dir: Path, quick: bool = False) -> Path:
    from . import peers as P

    rounds = QUICK_ROUNDS if quick else ROUNDS
    results = [measure(name, quick, rounds) for name in P.CASES]
    white = [measure(name, quick, 0, [f"image.background={list(WHITE)}"]) for name in P.CASES]
    command = "python -m benchmarks termination" + (" --quick" if quick else "")
    return _doc.update_section(Path(out_dir) / "termination.md", SECTION, body(results, white, command, rounds),
                               title="Early termination: a stopped pixel filled or left as it is")
