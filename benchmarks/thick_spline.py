"""The interpolating cubic spline between thick slices against the Catmull-Rom cubic (issue 28 item 5).

``python -m benchmarks.thick_spline [--rounds N] [--size S]``: each of benchmarks/thick.py's cases and views
rendered by the post sampler with ``isplat.splat.post.BETWEEN_SLICES`` "linear", "catmull-rom" and "b-spline"
(the interpolating spline's kernel truncated to SPLINE_REACH slices each way, isplat/splat/post.py
``_spline_at``), the default's shading between slices for both cubics: RMSE against the object (the same sample
at slices of the in-plane spacing) and the streak (tests/streak_measure.py), as benchmarks/thick.py measures them;
then the frame time per sample of the oblique view, interleaved rounds (the order reversed every other round),
medians, and the median of the per-round ratios spline / Catmull-Rom. Cases below THICK_RATIO (the 2.5 mm ones:
3.6:1) take the cubics only with the ratio lowered to 3, which this does for those rows (marked "forced").
Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

from benchmarks import thick as T

KINDS = ("linear", "catmull-rom", "b-spline")


def _settings(kind: str, forced: bool) -> dict:
    s = {"BETWEEN_SLICES": kind}
    if forced:
        s["THICK_RATIO"] = 3.0
    return s


def _frame_ns(sc, c, forced: bool, rounds: int) -> dict:
    from isplat.frame import render_frame, views_for

    sel = T._selection(sc, c)
    view = views_for(sc, sel)[0]
    t = {k: [] for k in KINDS}
    n = {}
    for k in KINDS:                                 # compile and warm each
        old = T._sampler(_settings(k, forced))
        render_frame(sel, view)
        T._sampler(old)
    for r in range(rounds):
        for k in (KINDS if r % 2 == 0 else KINDS[::-1]):
            old = T._sampler(_settings(k, forced))
            try:
                _, st = render_frame(sel, view)
            finally:
                T._sampler(old)
            t[k].append(st.seconds)
            n[k] = st.samples
    out = {k: statistics.median(v) * 1e9 / max(1, n[k]) for k, v in t.items()}
    # the cost ratio: the median of the per-round ratios of ns per sample (spline over Catmull-Rom)
    out["ratio"] = statistics.median(b * n["catmull-rom"] / (a * max(1, n["b-spline"]))
                                     for a, b in zip(t["catmull-rom"], t["b-spline"]))
    return out


def case_rows(case, size: int, rounds: int) -> list:
    from isplat.samples import make_sample

    tag, name, shape, sp, preset, nk_obj = case
    forced = max(sp) < 4.0 * min(sp)
    thick, _ = make_sample(name, shape)
    c = T.channels(thick, sp, T.WINDOWS.get(name))
    s0 = min(sp)
    obj_vol, _ = make_sample(name, (shape[0], shape[1], nk_obj))
    obj = T.channels(obj_vol, (s0, s0, s0), c["window"])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        aug = Path(tmp) / "scene.aug.h5"
        T._write_aug(aug, c["raw"], name)
        for view in T.VIEWS:
            sc = T.scene(aug, preset, view, size)
            ref = T.render(sc, obj)
            period = max(sp) / T.pixel_size(sc, c)
            phase = T.surface_phase(sc, obj, c, T.level(sc))
            row = dict(case=tag, view=view, forced=forced, object=T.streak(ref, phase, period))
            for k in KINDS:
                old = T._sampler(_settings(k, forced))
                try:
                    img = T.render(sc, c)
                finally:
                    T._sampler(old)
                row[k] = (T.rmse(img, ref), T.streak(img, phase, period))
            if view == "oblique" and rounds:
                row["ns"] = _frame_ns(sc, c, forced, rounds)
            rows.append(row)
            print(row, file=sys.stderr, flush=True)
    return rows


def table(rows) -> str:
    out = ["| case | view | RMSE linear | RMSE Catmull-Rom | RMSE spline | streak object | streak linear | "
           "streak Catmull-Rom | streak spline | ns/sample CR | ns/sample spline (ratio) |",
           "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ns = r.get("ns")
        cost = f"{ns['catmull-rom']:.1f} | {ns['b-spline']:.1f} ({ns['ratio']:.2f})" \
            if ns else "| "
        out.append(f"| {r['case']}{' (forced)' if r['forced'] else ''} | {r['view']} | "
                   f"{r['linear'][0]:.4f} | {r['catmull-rom'][0]:.4f} | {r['b-spline'][0]:.4f} | "
                   f"{r['object']:.4f} | {r['linear'][1]:.4f} | {r['catmull-rom'][1]:.4f} | "
                   f"{r['b-spline'][1]:.4f} | {cost} |")
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks.thick_spline", description=__doc__)
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--size", type=int, default=T.SIZE)
    ap.add_argument("--cases", default="", help="comma-separated case tags (default: all of benchmarks/thick.py)")
    a = ap.parse_args(argv)
    cases = [c for c in T.CASES if not a.cases or c[0] in a.cases.split(",")]
    rows = []
    for case in cases:
        rows += case_rows(case, a.size, a.rounds)
    print(table(rows))


if __name__ == "__main__":
    main()
