"""Where a frame's time goes, per compiled function and per instruction (a developer's tool; needs Linux ``perf``).

    python scripts/perf_kernels.py [--case "head translucent"] [--size 256] [--threads 1] [--seconds 10]
                                   [--set KEY=VALUE ...] [--annotate post_slice] [--top 30]

``perf`` samples the process's instruction pointers but cannot name numba's functions: they are machine code
that LLVM placed in memory, with no symbols perf can see (numba's ``NUMBA_ENABLE_PROFILING`` needs an LLVM built
with perf support). So this renders benchmarks/peers.py's case in a child process under ``perf record``, with a
numba cache of its own (the kernels compile in the child: their object code is then at hand), and the child
writes, for every function of isplat's kernel modules, its address in memory, its size and the object file
that holds it (``nm``). The samples are then counted per function (``--annotate NAME``: per instruction of the
function whose name holds NAME, from ``objdump``'s disassembly of its object file). Only the frames are timed:
the child warms up (compiles) before it writes the table, and the samples outside the kernels (Python, the
compiler) are counted apart.

A sample lands on the instruction that waits, not on the one that is slow: a load's latency shows on the first
instruction that uses its value.
"""

from __future__ import annotations

import argparse
import bisect
import collections
import importlib
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _symbols(out: Path) -> list[tuple[int, int, str, str, int]]:
    """(address, size, name, object file, offset in it) of every defined function of isplat's compiled ones."""
    from numba.core.dispatcher import Dispatcher

    from isplat.jit import KERNEL_SOURCES

    mods = [importlib.import_module("isplat." + f[:-3].replace("/", ".")) for f in KERNEL_SOURCES]
    disp = {id(v): v for m in mods for v in vars(m).values() if isinstance(v, Dispatcher)}
    syms, k = [], 0
    for d in disp.values():
        for cres in d.overloads.values():
            lib = cres.library
            try:
                obj = lib._get_compiled_object()        # (compiled in this process: its object code is kept)
            except Exception:                           # noqa: BLE001 (loaded from a cache: no object code)
                continue
            k += 1
            path = out / f"{k}.o"
            path.write_bytes(obj)
            nm = subprocess.run(["nm", "-S", "--defined-only", str(path)], capture_output=True, text=True).stdout
            for line in nm.splitlines():
                parts = line.split()
                if len(parts) == 4 and parts[2] in "tT":
                    try:
                        addr = lib.get_pointer_to_function(parts[3])
                    except Exception:                   # noqa: BLE001
                        continue
                    if addr:
                        syms.append((addr, int(parts[1], 16), parts[3], str(path), int(parts[0], 16)))
    return sorted(set(syms))


def child(a) -> None:
    sys.path.insert(0, str(ROOT))
    from benchmarks import peers as P
    from isplat import frame as F
    from isplat.renderer import Renderer

    sc = P.peer_scene(a.case, a.size, False, render={"threads": a.threads}, extra=a.set)
    r = Renderer(sc)
    view = F.views_for(sc, r.selection)[0]
    bands = F.BandLearning()
    for _ in range(3):
        F.render_frame(r.selection, view, None, bands)
    out = Path(a.work)
    with open(out / "symbols.txt", "w") as f:
        for addr, size, name, path, off in _symbols(out):
            f.write(f"{addr:x} {size:x} {name} {path} {off:x}\n")
    t0, n = time.perf_counter(), 0
    while time.perf_counter() - t0 < a.seconds:
        F.render_frame(r.selection, view, None, bands)
        n += 1
    print(f"{n} frames in {time.perf_counter() - t0:.1f} s", file=sys.stderr)


def short(name: str) -> str:
    """isplat.splat.post._post_slice from numba's mangled name."""
    m = re.match(r"_ZN(.*?)B\d", name)
    if not m:
        return name
    parts, s = [], m.group(1)
    while s and s[0].isdigit():
        n = int(re.match(r"\d+", s).group())
        s = s[len(str(n)):]
        parts.append(s[:n])
        s = s[n:]
    return ".".join(parts)


def annotate(sym, hits: dict, top: int) -> None:
    addr, size, name, path, off = sym
    asm = subprocess.run(["objdump", "-d", "--no-show-raw-insn", "-M", "intel", path], capture_output=True,
                         text=True).stdout.splitlines()
    total = sum(hits.values()) or 1
    rows, inside = [], False
    for line in asm:
        head = re.match(r"^([0-9a-f]+) <(.*)>:", line)
        if head:
            inside = head.group(2) == name
            continue
        m = re.match(r"\s+([0-9a-f]+):\s+(.*)", line)
        if inside and m:
            at = int(m.group(1), 16) - off
            rows.append((at, hits.get(at, 0), re.sub(r"<.*", "", m.group(2)).strip()))
    print(f"\n{short(name)}: {total} samples; the {top} instructions with most (offset, share, instruction):")
    for at, c, text in sorted(rows, key=lambda r: -r[1])[:top]:
        print(f"  {at:6x} {100 * c / total:5.2f}%  {text}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", default="head translucent")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--annotate", action="append", default=[], metavar="NAME")
    ap.add_argument("--top", type=int, default=30)
    ap.add_argument("--child", metavar="WORK", dest="work", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.work:
        child(a)
        return
    work = Path(tempfile.mkdtemp(prefix="isplat-perf-"))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(work / "cache"), ISPLAT_PREBUILT="none", ISPLAT_PROGRESS="0")
    args = [sys.executable, __file__, "--case", a.case, "--size", str(a.size), "--threads", str(a.threads),
            "--seconds", str(a.seconds), *[f"--set={s}" for s in a.set], "--child", str(work)]
    subprocess.run(["perf", "record", "-q", "-F", "4000", "-o", str(work / "perf.data"), "--", *args], env=env,
                   check=True)
    ips = subprocess.run(["perf", "script", "-i", str(work / "perf.data"), "-F", "ip"], capture_output=True,
                         text=True).stdout.split()
    syms = []
    for line in (work / "symbols.txt").read_text().splitlines():
        addr, size, name, path, off = line.split()
        syms.append((int(addr, 16), int(size, 16), name, path, int(off, 16)))
    starts = [s[0] for s in syms]
    per_fn, per_ins, outside = collections.Counter(), collections.defaultdict(collections.Counter), 0
    for text in ips:
        ip = int(text, 16)
        i = bisect.bisect_right(starts, ip) - 1
        if i >= 0 and ip < syms[i][0] + syms[i][1]:
            per_fn[i] += 1
            per_ins[i][ip - syms[i][0] + syms[i][4]] += 1
        else:
            outside += 1
    inside = sum(per_fn.values()) or 1
    print(f"{a.case}, {a.size} px, {a.threads} thread(s): {len(ips)} samples, {inside} in isplat's kernels "
          f"({outside} elsewhere: Python, the compiler, numpy); per function, of the kernels' samples:")
    for i, c in per_fn.most_common(a.top):
        print(f"  {100 * c / inside:6.2f}%  {short(syms[i][2])}")
    for want in a.annotate:
        found = [i for i in per_fn if want in syms[i][2]]
        for i in sorted(found, key=lambda j: -per_fn[j])[:1]:
            annotate(syms[i], {at - syms[i][4]: c for at, c in per_ins[i].items()}, a.top)
    print(f"\n(perf data and object files kept in {work})")


if __name__ == "__main__":
    main()
