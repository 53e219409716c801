"""Compare two versions of isplat side by side: the same images, and frame times interleaved in one run.

    python benchmarks/commits.py --old REV [--frames 15] [--rounds 5] [--out docs/render-core.md]

REV (a commit) is checked out into a temporary git worktree; one worker process runs each version (the old
one with its worktree first on ``sys.path``), and both load the same scenes through the public API both
versions have (``Renderer(scene).render_view(0)``). Frames are timed inside the workers, alternating between
them frame by frame, so load on this shared machine falls on both alike.

Images of the tests: the test suite of each version is run with a plugin that records every image
``Renderer.render_view`` returns (by test and call); the images of the tests both versions have are compared.

Images: every scene of the list below (small random volumes as the tests render them, indexed and full,
orthographic and perspective, 1 and 2 threads, shading, gradient modulation, cuts, early termination on and
off; and the head and engine samples) is rendered by both; the page gives, per scene, whether they are bit
for bit equal and the largest difference.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
WORK = ROOT / "out" / "bench-commits"

WORKER = r"""
import json, os, subprocess, sys, time
import numpy as np
try:
    from isplat.renderer import Renderer
except ImportError:                    # versions before the render core was cut into stages
    from isplat.render import Renderer
from isplat.scene import load_scene
DATA = sys.argv[1]                     # this version's copies of the data (file formats differ between versions)
held = {}


def isplat(*args):
    subprocess.run([sys.executable, "-m", "isplat", *map(str, args), "-q"], check=True, stdout=subprocess.DEVNULL)


def prepare():
    os.makedirs(DATA, exist_ok=True)
    for name, shape in (("head", None), ("head", "128,128,112"), ("engine", None)):
        tag = name if shape is None else f"{name}-{shape}"
        npy, aug, idx = (f"{DATA}/{tag}{e}" for e in (".npy", ".aug.h5", ".idx.h5"))
        if not os.path.exists(idx):
            isplat("sample", name, "-o", npy, "--force", *([] if shape is None else ["--shape", shape]))
            isplat("augment", npy, "-o", aug, "--force")
            isplat("index", aug, "-o", idx, "--force")
            os.unlink(npy)
    if not os.path.exists(f"{DATA}/random.idx.h5"):
        from isplat.augfile import write_augmented
        from isplat.index import build_index_file
        from isplat.normals import encode
        r = np.random.default_rng(1)
        shape = (9, 11, 13)
        dens = r.choice(np.array([0, 60, 120, 200], np.uint8), size=shape, p=[0.55, 0.15, 0.15, 0.15])
        write_augmented(f"{DATA}/random.aug.h5", dens, r.integers(0, 256, shape).astype(np.uint8),
                        encode(r.normal(size=shape + (3,))), (1.0, 1.2, 0.8), (0.0, 255.0), 0.5)
        build_index_file(f"{DATA}/random.aug.h5", f"{DATA}/random.idx.h5", force=True)


prepare()
for line in sys.stdin:
    cmd = json.loads(line)
    cmd["overrides"] = [o.replace("{DATA}", DATA) for o in cmd.get("overrides", [])]
    if cmd["op"] == "load":
        held[cmd["key"]] = Renderer(load_scene(cmd["scene"], cmd["overrides"]))
        held[cmd["key"]].render_view(0)                          # warm-up
        out = {}
    elif cmd["op"] == "time":
        r = held[cmd["key"]]
        t = time.perf_counter(); r.render_view(0); out = {"s": time.perf_counter() - t}
    elif cmd["op"] == "image":
        img, st = Renderer(load_scene(cmd["scene"], cmd["overrides"])).render_view(0)
        np.save(cmd["path"], img)
        drawn = getattr(st, "drawn", st.voxels_splatted)  # voxels_splatted counted post's samples until issue 25
        out = {"examined": st.voxels_examined, "splatted": drawn, "slices": st.slices}
    print(json.dumps(out), flush=True)
"""


class Worker:
    """A process running one version of isplat, driven by JSON lines."""

    def __init__(self, tree: Path, data: Path):
        env = dict(os.environ, PYTHONPATH=str(tree), ISPLAT_PROGRESS="0")
        self.p = subprocess.Popen([sys.executable, "-c", WORKER, str(data)], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, env=env, text=True, cwd=tree)

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


def _data(tag: str) -> list[str]:
    """Overrides naming a worker's own copy of data set ``tag`` (the worker fills in {DATA})."""
    return [f'data.augmented="{{DATA}}/{tag}.aug.h5"', f'data.index="{{DATA}}/{tag}.idx.h5"']


def image_cases() -> list[tuple[str, str, list]]:
    """(name, scene file, overrides) of every compared image."""
    WORK.mkdir(parents=True, exist_ok=True)
    scene = WORK / "random.toml"
    scene.write_text('[data]\naugmented = "random.aug.h5"\nindex = "random.idx.h5"\n[image]\nwidth = 40\nheight = 32\n'
                     '[transfer]\nopacity = [[50, 0.0], [60, 0.3], [130, 0.1], [200, 0.9]]\n'
                     'color = [[0, 1, 0, 0], [255, 0, 0.5, 1]]\n')
    cases = []
    for proj in ("orthographic", "perspective"):
        for az, el in ((0, 0), (90, 0), (33, 21), (150, -40), (0, 90)):
            for method in ("indexed", "full"):
                for threads in (1, 2):
                    for et in (1.0, 0.95):
                        o = [*_data("random"), f"camera.projection={proj}", f"camera.azimuth={az}", f"camera.elevation={el}",
                             f"render.method={method}", f"render.threads={threads}",
                             f"render.early_termination={et}"]
                        cases.append((f"random {proj} az{az} el{el} {method} t{threads} et{et}", scene, o))
    extra = [("shading, gradient opacity", ["shading.enabled=true", "transfer.gradient_opacity=[[0, 0.2], [60, 1]]"]),
             ("cut", ['cut=[{point = [0, 0, 0], normal = [1, 0.3, 0]}]']),
             ("float64", ["render.precision=float64"]),
             ("pre", ["render.classification=pre"]),
             ("pre shading, gradient opacity", ["render.classification=pre", "shading.enabled=true",
                                                "transfer.gradient_opacity=[[0, 0.2], [60, 1]]"]),
             ("pre perspective", ["render.classification=pre", "camera.projection=perspective"]),
             ("image sheets", ["render.sheets=image"])]
    for name, o in extra:
        for method in ("indexed", "full"):
            cases.append((f"random {name} {method}", scene, [*_data("random"), *o, f"render.method={method}"]))
    for name, tag, toml in (("head", "head-128,128,112", "head.toml"), ("engine", "engine", "engine.toml")):
        for method in ("indexed", "full"):
            for extra in ([], ["render.classification=pre"]):
                cases.append((f"{name} {method}", ROOT / "examples" / toml,
                              [*_data(tag), f"render.method={method}", *extra]))
    return cases


PLUGIN = r"""
import hashlib, json, os
import numpy as np
import pytest
try:
    from isplat.renderer import Renderer
except ImportError:
    from isplat.render import Renderer
RECORD, CURRENT = {}, {"test": None, "n": 0}
_render_view = Renderer.render_view
def render_view(self, *args, **kwargs):
    img, stats = _render_view(self, *args, **kwargs)
    key = f"{CURRENT['test']}#{CURRENT['n']}"
    CURRENT["n"] += 1
    RECORD[key] = {"sha": hashlib.sha256(np.ascontiguousarray(img).tobytes()).hexdigest(),
                   "path": os.environ["RECORD_DIR"] + f"/{len(RECORD)}.npy"}
    np.save(RECORD[key]["path"], img)
    return img, stats
Renderer.render_view = render_view
@pytest.hookimpl(tryfirst=True)
def pytest_runtest_call(item):
    CURRENT["test"], CURRENT["n"] = item.nodeid, 0
def pytest_sessionfinish(session):
    with open(os.environ["RECORD_DIR"] + "/record.json", "w") as f:
        json.dump(RECORD, f)
"""
TEST_FILES = ("tests/test_render.py", "tests/test_stability.py", "tests/test_cli_render.py", "tests/test_stats.py")


def record_tests(tree: Path, tmp: Path) -> dict:
    """Every image the render tests of ``tree`` make, by test id and call number."""
    (tmp / "isplat_record.py").write_text(PLUGIN)
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tmp}", RECORD_DIR=str(tmp), ISPLAT_PROGRESS="0")
    files = [f for f in TEST_FILES if (tree / f).exists()]
    subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "isplat_record", "-p", "no:cacheprovider", *files],
                   cwd=tree, env=env, check=False, stdout=subprocess.DEVNULL)
    return json.loads((tmp / "record.json").read_text())


def compare_tests(tree_old: Path, tmp: Path) -> dict:
    """Images of the tests both versions run: how many, how many bit for bit equal, the largest difference."""
    (tmp / "rec-old").mkdir()
    (tmp / "rec-new").mkdir()
    old, new = record_tests(tree_old, tmp / "rec-old"), record_tests(ROOT, tmp / "rec-new")
    common = sorted(set(old) & set(new))
    equal = sum(old[k]["sha"] == new[k]["sha"] for k in common)
    worst = max((float(np.abs(np.load(old[k]["path"]).astype(np.float64) - np.load(new[k]["path"])).max())
                 for k in common), default=0.0)
    return {"old": len(old), "new": len(new), "common": len(common), "equal": equal, "max_diff": worst,
            "tests": len({k.rsplit("#", 1)[0] for k in common})}


def compare_images(old: Worker, new: Worker) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n, (name, scene, o) in enumerate(image_cases()):
            imgs, stats = [], []
            for tag, w in (("old", old), ("new", new)):
                path = f"{tmp}/{n}-{tag}.npy"
                stats.append(w.ask(op="image", scene=str(scene), overrides=o, path=path))
                imgs.append(np.load(path))
            diff = float(np.abs(imgs[0].astype(np.float64) - imgs[1]).max())
            rows.append({"case": name, "technique": technique(o),
                         "bit_equal": bool(np.array_equal(imgs[0], imgs[1])), "max_diff": diff,
                         "same_counts": stats[0] == stats[1]})
    return rows


def time_cases() -> list[tuple[str, str, list]]:
    head, eng = _data("head"), _data("engine")
    cases = []
    for method in ("indexed", "full"):
        for size in (256, 512):
            cases.append((f"head bone {size}x{size} {method}", ROOT / "examples" / "head.toml",
                          head + [f"image.width={size}", f"image.height={size}", f"render.method={method}"]))
        cases.append((f"engine 512x384 {method}", ROOT / "examples" / "engine.toml",
                      eng + [f"render.method={method}"]))
    for size in (256, 512):
        cases.append((f"head bone {size}x{size} indexed", ROOT / "examples" / "head.toml",
                      head + [f"image.width={size}", f"image.height={size}", "render.classification=pre"]))
    return cases


def technique(overrides) -> str:
    """The technique a case renders with: the example scenes and the random one say version 4 or nothing, so
    post-classification unless the overrides ask for the paper's splatting or image-aligned sheets."""
    if "render.sheets=image" in overrides:
        return "image sheets (pre)"
    return "pre" if "render.classification=pre" in overrides else "post"


def compare_times(old: Worker, new: Worker, frames: int, rounds: int = 1) -> list[dict]:
    """Per case, ``rounds`` rounds over all the cases (the host's load changes over seconds), each the median of
    ``frames`` frames per version, the versions alternating frame by frame (which goes first alternating too):
    the median over rounds of each round's ratio, and their range."""
    per = {}
    for rnd in range(rounds):
        for name, scene, o in time_cases():
            key = f"{name} {technique(o)} {rnd}"
            for w in (old, new):
                w.ask(op="load", key=key, scene=str(scene), overrides=o)
            t = {"old": [], "new": []}
            for i in range(frames):
                for tag, w in ((("old", old), ("new", new)) if i % 2 == 0 else (("new", new), ("old", old))):
                    t[tag].append(w.ask(op="time", key=key)["s"])
            per.setdefault((name, technique(o)), []).append((statistics.median(t["old"]), statistics.median(t["new"])))
    rows = []
    for (name, tech), r in per.items():
        ratios = [mn / mo for mo, mn in r]
        rows.append({"case": name, "technique": tech, "old_ms": statistics.median(mo for mo, _ in r) * 1e3,
                     "new_ms": statistics.median(mn for _, mn in r) * 1e3, "ratio": statistics.median(ratios),
                     "lo": min(ratios), "hi": max(ratios)})
    return rows


def write_page(out: Path, rev: str, tests: dict, images: list, times: list, frames: int, command: str,
               rounds: int = 1):
    n_equal = sum(r["bit_equal"] for r in images)
    worst = max(r["max_diff"] for r in images)
    if str(ROOT) not in sys.path:               # run as a script: benchmarks/ is sys.path[0], not the root
        sys.path.insert(0, str(ROOT))
    from benchmarks._doc import historical

    lines = [
        historical("render-core", f"a one-time comparison of the working tree at {_doc_rev()} with {rev}: it documents "
                                  "that change (issue 25: techniques as units behind one request) and is not rerun"),
        "# The render core against an earlier commit: the same images, the same speed", "",
        f"Made by `{command}` (old = `{rev}`, new = the working tree), on {_machine()}.", "",
        "## Images of the tests", "",
        f"The render tests ({', '.join(TEST_FILES)}) of each version, every image `Renderer.render_view` returned "
        f"recorded by test and call: {tests['old']} images (old), {tests['new']} (new); {tests['common']} from "
        f"{tests['tests']} tests both versions have, of which {tests['equal']} bit for bit equal, largest "
        f"difference {tests['max_diff']:.3g}.", "",
        "## Images of the scenes below", "",
        f"{len(images)} scenes rendered by both versions: {n_equal} bit for bit equal, largest difference "
        f"{worst:.3g} (straight RGBA in [0, 1]); voxel, splat and slice counts equal in "
        f"{sum(r['same_counts'] for r in images)} of {len(images)}.", "",
        "| scene | technique | bit for bit | max difference | same counts |", "|---|---|---|---:|---|"]
    lines += [f"| {r['case']} | {r['technique']} | {'yes' if r['bit_equal'] else 'no'} | {r['max_diff']:.3g} | "
              f"{'yes' if r['same_counts'] else 'no'} |" for r in images]
    lines += ["", "## Frame time", "",
              f"Median of {frames} warm frames each, the two versions alternating frame by frame, all cores, in "
              f"{rounds} round(s) over all the cases; new / old is the median of the rounds' ratios, with their "
              f"range (the spread between rounds is this shared machine's noise).", "",
              "| case | technique | old (ms) | new (ms) | new / old | range over rounds |",
              "|---|---|---:|---:|---:|---|"]
    lines += [f"| {r['case']} | {r['technique']} | {r['old_ms']:.1f} | {r['new_ms']:.1f} | {r['ratio']:.3f} | "
              f"{r['lo']:.3f}-{r['hi']:.3f} |" for r in times]
    out.write_text("\n".join(lines) + "\n")


def _doc_rev() -> str:
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout.strip()


def _machine() -> str:
    cpu = next((ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text().splitlines()
                if ln.startswith("model name")), "unknown CPU")
    return f"{cpu}, {len(os.sched_getaffinity(0))} cores usable"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--old", required=True, help="the revision to compare with (a commit or tag)")
    ap.add_argument("--frames", type=int, default=15)
    ap.add_argument("--rounds", type=int, default=5, help="timing rounds over all the cases")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "render-core.md")
    args = ap.parse_args(argv)
    rev = subprocess.run(["git", "rev-parse", "--short", args.old], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.strip()
    shutil.rmtree(WORK / "data-new", ignore_errors=True)      # the working tree's formats may have changed
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "old"
        subprocess.run(["git", "worktree", "add", "--detach", "-q", str(tree), rev], cwd=ROOT, check=True)
        try:
            tests = compare_tests(tree, Path(tmp))
            old, new = Worker(tree, WORK / f"data-{rev}"), Worker(ROOT, WORK / "data-new")
            images = compare_images(old, new)
            times = compare_times(old, new, args.frames, args.rounds)
            old.close()
            new.close()
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT, check=False)
    cmd = f"python benchmarks/commits.py --old {args.old} --frames {args.frames} --rounds {args.rounds}"
    write_page(args.out, rev, tests, images, times, args.frames, cmd, args.rounds)
    print(args.out.read_text())


if __name__ == "__main__":
    main()
