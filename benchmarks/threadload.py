"""Two threads against one, quiet and with another process on one core, on the chest case of the peers benchmark.

``python -m benchmarks.threadload [--quick] [--frames N] [--json PATH]`` prints a Markdown table (and writes the
medians as JSON): isplat's default (post) on the ``chest`` case of :mod:`benchmarks.peers` (the ct-chest sample at
512x512x133, spacing 0.7, 0.7, 2.5, the veil and bone, from -y, 512 pixels), frames on 1 thread, on 2 threads,
and *two copies* (two one-thread frames at once, one per renderer of its own: what the machine gives two
programs that share nothing, as docs/worksplit.md measures it), each quiet and while a child process spins on
one core (:class:`benchmarks.peers.BusyCore`), all kinds in turn round after round (in both orders), each timed
frame right after an untimed one of its kind, the bands learned per kind as in a run of frames. ``--pin``
(Linux): the busy process and one of the two rendering threads share core 0, the other thread and the one-thread
frame have core 1 (:func:`pin_threads`).

*2 threads, of the ceiling*: the 2-thread wall speed-up over the two copies' gain (twice the one-thread frame's
wall time over the pair's). Under load the one-thread frame keeps a core of its own (the busy process takes the
other), so the 2-thread frame's loss shows how much a thread slowed by another process holds the frame.

The same script runs on another version of isplat (``PYTHONPATH=<a checkout's root>``): before and after a change
of how the frame is split, side by side, run alternately.
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import ceiling_rounds as CR  # noqa: E402

KINDS = ("1", "2", "pair")


def _renderer(quick: bool):
    from isplat.renderer import Renderer

    from . import peers

    return Renderer(peers.peer_scene("chest", 48 if quick else 512, quick))


def _frame(r, view, bands):
    from isplat import frame as F

    t = time.perf_counter()
    F.render_frame(r.selection, view, None, bands)
    return time.perf_counter() - t


def _pair(rs, views, bands):
    from isplat.threads import run_parallel

    t = time.perf_counter()
    run_parallel(lambda k: _frame(rs[k], views[k], bands[k]), [0, 1], 2)
    return time.perf_counter() - t


def pin_threads() -> None:
    """Pin this process's calling thread to core 1 and the 2-thread pool's threads to cores 0 and 1 (by their
    names' numbers; a version of isplat whose calling thread renders beside a pool of one: that thread to core
    0), so that with ``BusyCore(cpu=0)`` one rendering thread shares its core with the busy process and the
    one-thread frame has a core of its own: a thread slowed by another process, every time."""
    import os
    import threading

    from isplat.threads import run_parallel

    os.sched_setaffinity(0, {1})
    gate = threading.Barrier(2)

    def pin(_):
        gate.wait()                     # both rendering threads take one item each
        name = threading.current_thread().name
        if name.startswith("isplat"):   # a pool's thread (the calling thread stays on core 1)
            os.sched_setaffinity(0, {int(name.rsplit("_", 1)[1]) % 2})
    run_parallel(pin, [0, 1], 2)


def measure(frames: int, quick: bool, pin: bool = False) -> dict:
    """Wall seconds per kind and load: ``{(kind, busy): [seconds per round]}``; ``pin``: :func:`pin_threads`
    and the busy process on core 0."""
    from isplat.frame import BandLearning

    from .peers import BusyCore

    r, twin = _renderer(quick), _renderer(quick)
    if pin:
        pin_threads()
    v = r.views[0]
    views = {k: replace(v, render=replace(v.render, threads=int(k))) for k in ("1", "2")}
    pair_views = (views["1"], replace(twin.views[0], render=replace(twin.views[0].render, threads=1)))
    learn = {(k, busy): (BandLearning(), BandLearning()) for k in KINDS for busy in (False, True)}
    out = {(k, busy): [] for k in KINDS for busy in (False, True)}

    def one(kind, busy):
        b = learn[(kind, busy)]
        return _pair((r, twin), pair_views, b) if kind == "pair" else _frame(r, views[kind], b[0])

    for rnd in range(frames + 1):               # the first round learns the bands, not counted
        for busy in ((False, True) if rnd % 2 == 0 else (True, False)):
            with (BusyCore(0 if pin else None) if busy else _Quiet()):
                for kind in (KINDS if rnd % 2 == 0 else KINDS[::-1]):
                    one(kind, busy)
                    dt = one(kind, busy)
                    if rnd:
                        out[(kind, busy)].append(dt)
    return out


class _Quiet:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def summary(out: dict) -> dict:
    """Medians (ms), the 2-thread speed-up, the two copies' gain and the speed-up of that, quiet and loaded.

    >>> s = summary({("1", False): [2.0], ("2", False): [1.1], ("pair", False): [2.1],
    ...              ("1", True): [2.0], ("2", True): [1.6], ("pair", True): [3.0]})
    >>> round(s["quiet"]["speedup"], 3), round(s["quiet"]["of_ceiling"], 3), round(s["loaded"]["speedup"], 3)
    (1.818, 0.955, 1.25)
    """
    med = statistics.median
    res = {}
    for name, busy in (("quiet", False), ("loaded", True)):
        m = {k: med(out[(k, busy)]) for k in KINDS}
        c = CR.ceiling(*(out[(k, busy)] for k in KINDS))     # gain and "of that": per round, then the median
        res[name] = dict(ms={k: 1000.0 * x for k, x in m.items()}, speedup=m["1"] / m["2"],
                         speedup_rounds=c.speedup, gain=c.gain, of_ceiling=c.of)
    res["loss_2"] = res["loaded"]["ms"]["2"] / res["quiet"]["ms"]["2"]
    return res


def table(s: dict, label: str) -> str:
    L = []
    for name in ("quiet", "loaded"):
        x = s[name]
        L.append(f"| {label} | {name} | {x['ms']['1']:.1f} | {x['ms']['2']:.1f} | {x['speedup']:.2f} | "
                 f"{x['speedup_rounds']:.2f} | {x['ms']['pair']:.1f} | {x['gain']:.2f} | {x['of_ceiling']:.2f} |")
    return "\n".join(L)


HEADER = ("| isplat | machine | 1 thread ms | 2 threads ms | speed-up | speed-up, per-round median | two copies ms | "
          "two copies: gain, per-round median | 2 threads, of that, per-round median |\n"
          "|---|---|---:|---:|---:|---:|---:|---:|---:|")


SECTION = "threads"
COMMANDS = ("python -m benchmarks.threadload --json out/threadload/this.json",
            "python -m benchmarks.threadload --pin --json out/threadload/this-pinned.json")


def page(rows: list[dict], command: str, machine: str) -> str:
    """The section ``threads`` of performance.md: ``rows`` as :func:`main` writes them (``--json``), this run's
    last; ``machine``: :func:`benchmarks._doc.machine_line` before any thread was pinned."""
    from . import _doc

    L = ["### Two threads against one, quiet and with a process on one core", "", "```", command, "```", "",
         f"Machine: {machine}; isplat {_doc.git_rev()}. " + __doc__.split("\n\n", 1)[1].replace(
             "\n", " ").strip(), "", "Rows from other runs (``--with``: their ``--json`` files; an older checkout "
         "run with ``PYTHONPATH=<its root>`` and the same command) come first, in the order given.", "", HEADER]
    L += [table(r["summary"], r["label"]) for r in rows]
    L += ["", "*2 threads, of that*: the 2-thread wall speed-up over the two copies' gain of the same round, what "
          "isplat makes of the cores the machine gives (the median over rounds, tests/ceiling_rounds.py; rows "
          "made before this column was per round divided medians from different rounds); *loaded*: with the busy "
          "process. The chest case is post-classified (isplat's "
          "default)."]
    return "\n".join(L)


def old_against_new(a, argv) -> int:
    """``--old REV``: the same measurement on isplat/ at REV and on this checkout, run after each other
    ``--repeats`` times (each run a process of its own, the old one with ``PYTHONPATH`` at REV's tree), then the
    page from all the runs' rows, old and new alternately."""
    import os
    import subprocess

    from .sampler import REPO, old_tree

    base = ["--frames", str(a.frames)] + (["--pin"] if a.pin else []) + (["--quick"] if a.quick else [])
    trees = {"old": (old_tree(a.old), f"{a.old} (before)"), "new": (REPO, f"{_doc_rev()} (this checkout)")}
    runs = []
    for k in range(a.repeats):
        for tag, (tree, label) in trees.items():
            js = REPO / "out" / "threadload" / f"{tag}-{k}.json"
            env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{REPO}")
            # -P: not the working directory first on sys.path, where this checkout's isplat/ would hide REV's
            subprocess.run([sys.executable, "-P", "-m", "benchmarks.threadload", *base, "--json", str(js), "--label",
                            f"{label}, run {k + 1}"], cwd=REPO, env=env, check=True)
            runs.append(js)
    if a.out:               # one page of every run's rows, stamped with the --old command
        _write_page(a.out, [json.loads(p.read_text()) for p in runs],
                    "python -m benchmarks.threadload " + shlex.join(argv))
    return 0


def _doc_rev() -> str:
    from . import _doc

    return _doc.git_rev()


def _write_page(out: Path, rows, cmd: str, machine: str | None = None) -> None:
    from . import _doc
    from .peers import SOURCES

    out.mkdir(parents=True, exist_ok=True)
    doc = out / "performance.md"
    _doc.update_section(doc, SECTION, page(rows, cmd, machine or _doc.machine_line()), title="Performance")
    src = [*SOURCES, "benchmarks/threadload.py", "tests/ceiling_rounds.py"]
    _doc.put_stamp(doc, _doc.stamp(SECTION, cmd, ["post"], src), SECTION)
    print(f"[threadload] wrote {doc}", file=sys.stderr)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.threadload", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="the chest at 64x64x17, 48 pixels")
    ap.add_argument("--frames", type=int, default=9)
    ap.add_argument("--json", type=Path, default=None, help="write the per-round seconds and the summary here")
    ap.add_argument("--pin", action="store_true",
                    help="the busy process and one rendering thread on core 0, the other and the one-thread frame "
                         "on core 1 (Linux; a thread slowed by another process every time)")
    ap.add_argument("--out", type=Path, default=None,
                    help="write the section 'threads' of OUT/performance.md (stamped) from this run and --with's")
    ap.add_argument("--with", dest="others", type=Path, action="append", default=[],
                    help="a --json file of another run (another checkout) to show above this run's rows")
    ap.add_argument("--label", default=None, help="the table's first column (default: isplat's source folder)")
    ap.add_argument("--old", default=None, metavar="REV",
                    help="run this command on isplat/ at REV (git archive) and on this checkout, alternately "
                         "--repeats times, each in a process of its own, and write the rows of all the runs")
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args(argv)
    if a.old:
        return old_against_new(a, argv if argv is not None else sys.argv[1:])
    import isplat

    from . import _doc

    machine = _doc.machine_line()           # before pinning: the cores this process may use
    out = measure(2 if a.quick else a.frames, a.quick, a.pin)
    s = summary(out)
    label = a.label or str(Path(isplat.__file__).resolve().parent.parent)
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(dict(label=label, summary=s, rounds={f"{k}|{b}": v for (k, b), v in out.items()}),
                                     indent=1))
    print(HEADER)
    print(table(s, label))
    if a.out:
        rows = [json.loads(p.read_text()) for p in a.others] + [dict(label=label, summary=s)]
        _write_page(a.out, rows, "python -m benchmarks.threadload " + shlex.join(argv if argv is not None
                                                                                 else sys.argv[1:]), machine)
    return 0


if __name__ == "__main__":
    sys.exit(main())
