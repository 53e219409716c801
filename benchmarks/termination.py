"""What a pixel that reaches early termination gets: filled with its last sample's colour, or stopped as it is.

``python -m benchmarks termination [--out docs] [--quick]`` writes the section ``termination`` of
``termination.md`` (a page of its own: ``accuracy.md`` is rewritten whole by :mod:`benchmarks.accuracy`): on each case of :mod:`benchmarks.peers` (the smallest of its image sizes; no VTK needed), the
post-classified default (``render.termination = "fill"``, scene version 7) at the case's early-termination
opacity and below it, against ``"stop"`` (what a pixel got before version 7) at that opacity: each setting's
RMSE against reference (a) of :mod:`benchmarks.reference` (the converged ray integral, no early termination),
the samples it composited, and its median frame time over interleaved rounds with its median per-round ratio
to the stop's. The sentences under the table are computed from it: where the fill is closer than the stop at
the same opacity, and the lowest opacity at which the fill is no farther than the stop in every case (what
would let the default stop earlier without a worse picture anywhere).
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
LOWER = (0.01, 0.02, 0.04)      # the fill also at the case's opacity minus these
ROUNDS, QUICK_ROUNDS = 9, 2


def settings(et: float) -> list[tuple[str, float]]:
    """(termination, early_termination) of a case whose scene stops at ``et``: the stop (before version 7) and
    the fill (the default) there, then the fill at the lower opacities."""
    return [("stop", et), ("fill", et)] + [("fill", round(et - d, 4)) for d in LOWER]


def measure(name: str, quick: bool, rounds: int) -> dict:
    """One case: per setting its RMSE against reference (a), samples composited and frame times."""
    from isplat.frame import BandLearning, render_frame, views_for
    from isplat.renderer import Renderer

    from . import peers as P
    from . import reference as REF

    size = min(P.CASES[name][5 if quick else 4])
    base = P.peer_scene(name, size, quick)
    ref, _, _ = REF.reference(base)
    sel = Renderer(base).selection
    points = []
    for term, et in settings(base.render.early_termination):
        view = views_for(P.peer_scene(name, size, quick, {"termination": term, "early_termination": et}), sel)[0]
        img, st = render_frame(sel, view, None, BandLearning())
        points.append(dict(term=term, et=et, view=view, bands=BandLearning(), times=[], samples=st.drawn,
                           rmse=REF.errors(img, ref)["rmse"]))
    for rnd in range(rounds):           # interleaved, the order turning each round; a warm frame before each
        for p in points[rnd % len(points):] + points[:rnd % len(points)]:
            render_frame(sel, p["view"], None, p["bands"])
            t0 = time.perf_counter()
            render_frame(sel, p["view"], None, p["bands"])
            p["times"].append(time.perf_counter() - t0)
    stop = points[0]["times"]
    for p in points:
        p["ms"] = _doc.median_ms(p["times"])
        p["ratio"] = statistics.median(a / b for a, b in zip(p["times"], stop))
        del p["view"], p["bands"], p["times"]
    return dict(case=name, size=size, points=points)


def _label(p) -> str:
    return f'{p["term"]}, ET {p["et"]:g}'


def summary(results) -> list[str]:
    """The sentences the table supports: fill against stop at the case's opacity, and how low the fill may go."""
    closer = [r["case"] for r in results if r["points"][1]["rmse"] < r["points"][0]["rmse"]]
    farther = [f"{r['case']} ({r['points'][1]['rmse']:.6f} against {r['points'][0]['rmse']:.6f})"
               for r in results if r["points"][1]["rmse"] > r["points"][0]["rmse"]]
    lines = [f"- At each case's own early-termination opacity the fill is closer to reference (a) than the stop in "
             f"{len(closer)} of {len(results)} cases" + (f"; farther in: {'; '.join(farther)}." if farther else ".")]
    for d in LOWER:
        worse = [f'{r["case"]} {p["rmse"]:.6f} against {r["points"][0]["rmse"]:.6f}'
                 for r in results for p in r["points"][2:]
                 if abs(p["et"] - round(r["points"][0]["et"] - d, 4)) < 1e-9 and p["rmse"] > r["points"][0]["rmse"]]
        ratios = [p["ratio"] for r in results for p in r["points"][2:]
                  if abs(p["et"] - round(r["points"][0]["et"] - d, 4)) < 1e-9]
        verdict = ("no farther than the stop at the case's opacity in every case" if not worse else
                   f"farther than the stop at the case's opacity in {len(worse)} cases ({'; '.join(worse)})")
        lines.append(f"- The fill {d:g} below each case's opacity: {verdict}; its frames "
                     f"{min(ratios):.2f}-{max(ratios):.2f}x the stop's.")
    return lines


def body(results, command: str, rounds: int) -> str:
    L = ["### Filling a pixel that stops (`render.termination`)", "",
         f"`{command}` ({_doc.machine_line()}; {rounds} interleaved rounds, each timed frame after a warm one of "
         "its own). Technique **post** throughout. `render.termination = \"fill\"` (the default from scene "
         "version 7): a pixel that reaches `render.early_termination` takes the colour of the sample that took it "
         "there for the rest of its transmittance (isplat.splat.composite.saturated); `\"stop\"` (before version "
         "7): it keeps the opacity it reached, the background showing through the rest. Reference (a) integrates "
         "the whole ray, so what a stopped pixel leaves out is error: the stop's error there is everything behind "
         "the point, the fill's only the change of colour behind it. Cases: benchmarks/peers.py's, each at its "
         "smallest image size, with its own early-termination opacity (0.99, the engine's 0.98); "
         "ratio = median per-round ratio of the frame to the stop's at the case's opacity.", "",
         "| case | pixels | setting | RMSE (a) | samples | ms | / stop |", "|---|---:|---|---:|---:|---:|---:|"]
    for r in results:
        for p in r["points"]:
            L.append(f'| {r["case"]} | {r["size"]} | {_label(p)} | {p["rmse"]:.5f} | {p["samples"]:,} | '
                     f'{p["ms"]:.1f} | {p["ratio"]:.2f} |')
    return "\n".join(L + [""] + summary(results)) + "\n"


def run(out_dir: Path, quick: bool = False) -> Path:
    from . import peers as P

    rounds = QUICK_ROUNDS if quick else ROUNDS
    results = [measure(name, quick, rounds) for name in P.CASES]
    command = "python -m benchmarks termination" + (" --quick" if quick else "")
    return _doc.update_section(Path(out_dir) / "termination.md", SECTION, body(results, command, rounds),
                               title="Early termination: a stopped pixel filled or left as it is")
