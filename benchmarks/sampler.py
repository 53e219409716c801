"""The post-classified sampler's cost per sample at one thread, an older commit against the working tree.

``python -m benchmarks sampler [--quick]`` writes the section ``sampler`` of docs/design.md. The old commit is
:data:`BASELINE` (``ISPLAT_SAMPLER_OLD=REV`` in the environment to choose another).

Issue 27's scene: the ``ct-chest`` sample made at 512 x 512 x 133 voxels, augmented at spacing 0.703125,
0.703125, 2.5 mm with ``--window=-1000,2000``, a semi-transparent veil (opacity 0.03 from code 62 to 78) and
opaque bone (opacity 1 from code 140), orthographic from -y, 512 px, unshaded and shaded; the head sample's
bone scene (examples/head.toml), shaded; and the same chest made with 48 slices 7 mm thick, shaded, whose view
from -y takes the cubic between slices (:data:`isplat.splat.post.THICK_RATIO`); and benchmarks/peers.py's
translucent head at 256 px, unshaded (the one case where isplat's default was slower than VTK at step 1).
``render.threads = 1``.

Each version runs in a worker process of its own (the old one from ``git archive`` of its ``isplat/`` under
out/bench-sampler/, its kernels compiled there once); the frames go in turn, old and new, round after round, so
load on the shared machine falls on both alike. A frame's time is the worker's thread CPU time of
``Renderer.render_view(0)``; ns per sample is the median frame time over the samples the frame composited
(``FrameStats.drawn``), and the ratio is the median of the per-round ratios. Both versions' images are compared
(bit for bit, else the largest difference).

Stage shares (the new version only, when it has :data:`isplat.splat.post.SAMPLE_STAGES`): the same frames from
copies of the kernel whose sample stops after a stage (``ISPLAT_SAMPLE_STAGES``: 0 scan only, 1 the density
gather too, 2 the opacity too, 3 everything; each copy with numba's cache in a folder of its own), no pixel
saturating in any of them so that every copy does the same pixels and slices; a stage's share is the difference of
two copies' times over the full one's. ``ISPLAT_SAMPLER_SHARES=0``: without them.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks import _doc
from benchmarks.peers import HEAD_TRANSLUCENT, UNSHADED

TECHNIQUES = ["post"]
SOURCES = _doc.sources(_doc.RENDER, ("benchmarks/sampler.py", "benchmarks/peers.py", "isplat/augment.py",
                                     "isplat/samples.py", "examples/head.toml"))
REPO = Path(__file__).resolve().parents[1]
WORK = REPO / "out" / "bench-sampler"
BASELINE = os.environ.get("ISPLAT_SAMPLER_OLD", "1e1b519")      # main before the compositing in lanes (jit.over4)
PAGE, SECTION = "design.md", "sampler"
ROUNDS = int(os.environ.get("ISPLAT_SAMPLER_ROUNDS", "15"))

CHEST_TF = ['transfer.opacity=[[0, 0.0], [50, 0.0], [62, 0.03], [78, 0.03], [82, 0.0], [110, 0.0], [140, 1.0], '
            '[255, 1.0]]',
            'transfer.color=[[50, 0.9, 0.7, 0.6], [80, 0.9, 0.7, 0.6], [140, 1.0, 0.97, 0.9], [255, 1.0, 1.0, 1.0]]',
            'camera.azimuth=0', 'camera.elevation=0', 'camera.projection="orthographic"', 'camera.zoom=1.0']
# name, data tag, overrides after examples/head.toml's
CASES = [
    ("chest veil + bone, unshaded", "chest", [*CHEST_TF, "shading.enabled=false"]),
    ("chest veil + bone, shaded", "chest", CHEST_TF),
    ("head bone (examples/head.toml), shaded", "head", []),
    # 7 mm slices seen from the side: the cubic between slices (isplat.splat.post.THICK_RATIO)
    ("chest 7 mm slices, veil + bone, shaded (cubic)", "chest7", CHEST_TF),
    # benchmarks/peers.py's "head translucent" at 256 px, where isplat's default was slower than VTK at step 1
    ("head translucent, unshaded, 256 px (benchmarks/peers.py's case)", "head",
     [*UNSHADED, *HEAD_TRANSLUCENT, "image.width=256", "image.height=256"]),
]

WORKER = r"""
import json, os, sys, time
import numpy as np
from isplat.renderer import Renderer
from isplat.scene import load_scene
held = {}
for line in sys.stdin:
    cmd = json.loads(line)
    if cmd["op"] == "load":
        r = Renderer(load_scene(cmd["scene"], cmd["overrides"]))
        img, st = r.render_view(0)                                  # warm-up (and compile)
        held[cmd["key"]] = r
        np.save(cmd["image"], img)
        out = {"samples": int(st.drawn)}
    else:
        r = held[cmd["key"]]
        t = time.thread_time(); r.render_view(0); out = {"s": time.thread_time() - t}
    print(json.dumps(out), flush=True)
"""


def _log(msg):
    print(f"[sampler] {msg}", file=sys.stderr, flush=True)


def _cli(*args, root: Path = REPO):
    subprocess.run([sys.executable, "-m", "isplat", *map(str, args), "-q"], check=True, cwd=root,
                   env=dict(os.environ, PYTHONPATH=str(root)))


def data(quick: bool, old: Path) -> dict:
    """(augmented, index) of each data tag, made once under out/bench-sampler/<old commit>/data: augmented and
    indexed by the old commit's isplat (tree ``old``), whose formats both read (the new reads older formats; the
    old may not read the new ones: a file augmented by the new isplat made the old one's ``index`` fail)."""
    d = old / "data"
    d.mkdir(parents=True, exist_ok=True)
    chest_shape = "256,256,67" if quick else "512,512,133"
    chest7_shape = "256,256,24" if quick else "512,512,48"
    specs = {"chest": ("ct-chest", chest_shape, ["--spacing", "0.703125,0.703125,2.5", "--window=-1000,2000"]),
             "head": ("head", None, []),
             "chest7": ("ct-chest", chest7_shape, ["--spacing", "0.703125,0.703125,7", "--window=-1000,2000"])}
    out = {}
    for tag, (sample, shape, aug_args) in specs.items():
        name = f"{tag}-{shape or 'default'}"
        npy, aug, idx = (d / f"{name}{e}" for e in (".npy", ".aug.h5", ".idx.h5"))
        if not idx.exists():
            _cli("sample", sample, "-o", npy, "--force", *(["--shape", shape] if shape else []))
            _cli("augment", npy, "-o", aug, "--force", *aug_args, root=old)
            _cli("index", aug, "-o", idx, "--force", root=old)
            npy.unlink()
        out[tag] = (aug, idx)
    return out


def old_tree(rev: str, work: Path = WORK) -> Path:
    """``isplat/`` at ``rev`` under ``work``/<sha>/ (kept: its compiled kernels too)."""
    sha = subprocess.run(["git", "rev-parse", "--short=12", rev], cwd=REPO, capture_output=True, text=True,
                         check=True).stdout.strip()
    home = work / sha
    if not (home / "isplat").exists():
        home.mkdir(parents=True, exist_ok=True)
        tar = subprocess.run(["git", "archive", sha, "isplat"], cwd=REPO, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(home)], input=tar, check=True)
    return home


class Worker:
    """A process running the isplat of ``tree``, driven by JSON lines."""

    def __init__(self, tree: Path, env: dict | None = None):
        e = dict(os.environ, PYTHONPATH=str(tree), ISPLAT_PROGRESS="0", **(env or {}))
        self.p = subprocess.Popen([sys.executable, "-c", WORKER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  env=e, text=True, cwd=tree)

    def ask(self, **cmd) -> dict:
        self.p.stdin.write(json.dumps(cmd) + "\n")
        self.p.stdin.flush()
        line = self.p.stdout.readline()
        if not line:
            raise RuntimeError(f"worker failed on {cmd}")
        return json.loads(line)

    def close(self):
        self.p.stdin.close()
        self.p.wait()


def overrides(tag: str, files, ov, extra=()) -> list[str]:
    aug, idx = files[tag]
    return [f'data.augmented="{aug}"', f'data.index="{idx}"', "image.width=512", "image.height=512",
            "render.threads=1", *ov, *extra]


def interleaved(workers: dict, cases, files, rounds: int, extra=()) -> dict:
    """Per worker and case: the samples, the images' paths and the frame seconds, frames taken in turn."""
    res = {w: {} for w in workers}
    for ci, (name, tag, ov) in enumerate(cases):
        for w, wk in workers.items():
            img = WORK / f"img-{w}-{ci}.npy"
            got = wk.ask(op="load", key=ci, scene=str(REPO / "examples" / "head.toml"),
                         overrides=overrides(tag, files, ov, extra), image=str(img))
            res[w][ci] = {"samples": got["samples"], "image": img, "s": []}
        order = list(workers)
        for i in range(rounds):
            for w in (order if i % 2 == 0 else order[::-1]):
                res[w][ci]["s"].append(workers[w].ask(op="time", key=ci)["s"])
        _log(f"{name}: " + ", ".join(f"{w} {1e3 * statistics.median(res[w][ci]['s']):.1f} ms" for w in workers))
    return res


def compare(old: dict, new: dict) -> dict:
    """ns per sample of both, the per-round ratio's median and the images' difference."""
    a, b = np.load(old["image"]), np.load(new["image"])
    ratios = sorted(y / x for x, y in zip(old["s"], new["s"]))
    return {"old_ns": 1e9 * statistics.median(old["s"]) / max(old["samples"], 1),
            "new_ns": 1e9 * statistics.median(new["s"]) / max(new["samples"], 1),
            "old_ms": 1e3 * statistics.median(old["s"]), "new_ms": 1e3 * statistics.median(new["s"]),
            "samples": new["samples"], "same_samples": old["samples"] == new["samples"],
            "ratio": ratios[len(ratios) // 2], "equal": bool(np.array_equal(a, b)),
            "maxdiff": float(np.abs(a.astype(np.float64) - b).max()) if a.shape == b.shape else float("nan")}


def has_stages() -> bool:
    return "SAMPLE_STAGES" in (REPO / "isplat" / "splat" / "post.py").read_text()


def stage_shares(files, rounds: int) -> dict:
    """Per case: the time of each truncated copy (0 scan, 1 + density, 2 + opacity, 3 everything) in ns per
    sample of the full frame's samples, early termination off."""
    workers = {f"s{k}": Worker(REPO, {"ISPLAT_SAMPLE_STAGES": str(k),
                                      "NUMBA_CACHE_DIR": str(WORK / f"cache-stages-{k}")}) for k in range(4)}
    try:
        res = interleaved(workers, CASES, files, rounds)
    finally:
        for w in workers.values():
            w.close()
    out = {}
    for ci in range(len(CASES)):
        n = res["s3"][ci]["samples"]
        out[ci] = [1e9 * statistics.median(res[f"s{k}"][ci]["s"]) / max(n, 1) for k in range(4)]
    return out


PROBE = """
def kernel(density, i00, sa, sb, fu, fv, out, n):
    for j in range(n):
        i = np.uint64(i00[j])
        a, b = fu[j], fv[j]
        out[j] = ((1.0 - a) * (1.0 - b) * density[i] + a * (1.0 - b) * density[i + np.uint64(sa)]
                  + (1.0 - a) * b * density[i + np.uint64(sb)] + a * b * density[i + np.uint64(sa + sb)])
"""


def vector_probe() -> list[tuple[str, int, int]]:
    """Whether numba's LLVM vectorises the samples' density gather written as a loop over a chunk of points (the
    points' quads and fractions in small arrays, the densities out into another): per build (fastmath off, on),
    the vector gathers and the packed double-precision arithmetic instructions in its machine code."""
    import re

    import numba as nb

    scope = {"np": np}
    exec(PROBE, scope)
    d = np.zeros(4096, np.uint8)
    i00, fu, out = np.zeros(64, np.int64), np.zeros(64), np.zeros(64)
    rows = []
    for fast in (False, True):
        f = nb.njit(nogil=True, fastmath=fast)(scope["kernel"])
        f(d, i00, 1, 64, fu, fu, out, 64)
        asm = f.inspect_asm(f.signatures[0])
        rows.append(("fastmath" if fast else "exact", len(re.findall(r"\bvp?gather", asm)),
                     len(re.findall(r"\bv(?:mul|add|sub|fmadd\w*|fnmadd\w*)pd\b", asm))))
    return rows


def run(out_dir: Path, quick: bool) -> Path:
    from isplat.frame import FrameStats  # noqa: F401  (the working tree is importable)

    rounds = 3 if quick else ROUNDS
    old = old_tree(BASELINE)
    files = data(quick, old)
    workers = {"old": Worker(old), "new": Worker(REPO)}
    try:
        res = interleaved(workers, CASES, files, rounds)
    finally:
        for w in workers.values():
            w.close()
    rows = [compare(res["old"][ci], res["new"][ci]) for ci in range(len(CASES))]
    shares = stage_shares(files, rounds) if has_stages() and os.environ.get("ISPLAT_SAMPLER_SHARES") != "0" \
        else None
    body = render_doc(rows, shares, quick, rounds, vector_probe())
    page = out_dir / PAGE
    _doc.update_section(page, SECTION, body)
    return page


def render_doc(rows, shares, quick, rounds, probe) -> str:
    lines = [f"Measured by `python -m benchmarks sampler{' --quick' if quick else ''}` "
             f"({'quick: a 256 x 256 x 67 chest, ' if quick else ''}{rounds} interleaved rounds, one thread, "
             f"thread CPU time; {_doc.machine_line()}, shared with other work, so under load): old = "
             f"`{BASELINE}`, new = `{_doc.git_rev()}` (the working tree).", "",
             "| case | samples | ms old | ms new | ns per sample old | new | new / old (per-round median) "
             "| images |", "|---|---|---|---|---|---|---|---|"]
    for (name, _, _), r in zip(CASES, rows):
        img = "bit for bit equal" if r["equal"] else f"max difference {r['maxdiff']:.2e}"
        if not r["same_samples"]:
            img += " (sample counts differ)"
        lines.append(f"| {name} | {r['samples']:,} | {r['old_ms']:.1f} | {r['new_ms']:.1f} | {r['old_ns']:.1f} | "
                     f"{r['new_ns']:.1f} | {r['ratio']:.3f} | {img} |")
    if shares:
        lines += ["", "Stage shares of the new version (copies of the kernel whose sample stops after a stage, "
                  "`ISPLAT_SAMPLE_STAGES`; no pixel saturating; ns per sample of the full frame's samples):", "",
                  "| case | scan and traversal | density gather | opacity and its compositing | colour and shading "
                  "| full |", "|---|---|---|---|---|---|"]
        for (name, _, _), t in zip(CASES, shares.values()):
            full = t[3]
            parts = [t[0], t[1] - t[0], t[2] - t[1], t[3] - t[2]]
            lines.append(f"| {name} | " + " | ".join(f"{p:.1f} ({100 * p / full:.0f}%)" for p in parts) +
                         f" | {full:.1f} |")
    import numba

    lines += ["", f"Does LLVM vectorise the density gather as a loop over a chunk of points (`PROBE` in "
              f"benchmarks/sampler.py, numba {numba.__version__}, this CPU)? "
              + "; ".join(f"{k}: {g} vector gathers, {p} packed double-precision operations" for k, g, p in probe)
              + (". Scalar: the loop stores its densities while it gathers, and LLVM, not knowing that the stores "
                 "cannot alias the gathered array (numba marks no array noalias), presumably cannot vectorise it; "
                 "a vectorised sampler needs explicit vector code." if not any(g or p for _, g, p in probe) else ".")]
    return "\n".join(lines)
