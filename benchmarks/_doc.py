"""Write benchmark results into Markdown files, one marked section per benchmark.

Several benchmarks share a page (docs/performance.md holds the render benchmark and the paper's
Figure 5 table); each owns the text between ``<!-- BEGIN name -->`` and ``<!-- END name -->``, and rerunning
one replaces only its own section.

Every generated page or section carries a stamp (:func:`stamp`), one HTML comment line that Markdown does not show:

    <!-- isplat-stamp: {"section": "paper", "commit": "ad6551e", "command": "python -m benchmarks paper",
         "techniques": ["pre", "post"], "sources": ["isplat/frame.py", "isplat/splat/**", ...]} -->

(on one line): the commit measured, the command that made it, the render techniques its rows used
(``render.classification``: "pre", the paper's splatting, or "post", the default from scene version 4; empty when
nothing is rendered) and the source paths (git globs) whose change makes it stale. ``make docs-check``
(scripts/docs_check.py) lists the stamps whose sources changed since their commit. A hand-written page or
section that is deliberately not regenerated says so with ``{"section": ..., "historical": "why"}``.
"""

from __future__ import annotations

import json
import platform
import statistics
import subprocess
from pathlib import Path

STAMP_TAG = "isplat-stamp"

# Source globs (git pathspec globs, relative to the repository root) shared by the benchmarks' SOURCES: what a
# measurement of reading, of rendering or of augmenting depends on.
READ = ("isplat/index/**", "isplat/augfile.py", "isplat/fileio.py", "isplat/selection.py", "isplat/runs.py",
        "isplat/runsfile.py", "isplat/runsplace.py")      # (post reads the runs file beside the index)
RENDER = ("isplat/frame.py", "isplat/renderer.py", "isplat/selection.py", "isplat/splat/**", "isplat/camera.py",
          "isplat/transfer.py", "isplat/scene.py", "isplat/jit.py", "isplat/threads.py", "isplat/normals.py")
AUGMENT = ("isplat/augment.py", "isplat/augfile.py", "isplat/normals.py", "isplat/volume_io.py", "isplat/fileio.py")
SAMPLES = ("isplat/samples.py",)


def machine_line() -> str:
    """One line describing the machine the numbers come from: the CPU's name with its family, model and widest
    vector unit (a cloud CPU's name alone, "AMD EPYC", covers generations a factor 2 apart in speed), the cores
    this process may use, and Python's version."""
    import os

    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        text = ""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"{cpu_description(text)}, {cores} cores usable, Python {platform.python_version()}"


def cpu_description(cpuinfo: str) -> str:
    r"""The first processor of a Linux ``/proc/cpuinfo`` text in a few words.

    >>> cpu_description("model name\t: AMD EPYC\ncpu family\t: 26\nmodel\t\t: 2\nflags\t\t: sse avx2 avx512f\n")
    'AMD EPYC (family 26 model 2, AVX-512)'
    >>> cpu_description("model name\t: Some CPU\nflags\t\t: sse2 avx2\n")
    'Some CPU (AVX2)'
    >>> cpu_description("")
    'unknown CPU'
    """
    fields = {}
    for line in cpuinfo.splitlines():
        if not line.strip():
            break                                   # the first processor's block only
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    if "model name" not in fields:
        return "unknown CPU"
    flags = set(fields.get("flags", "").split())
    simd = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "SSE" if flags else ""
    gen = f"family {fields['cpu family']} model {fields['model']}" if "cpu family" in fields and "model" in fields \
        else ""
    detail = ", ".join(x for x in (gen, simd) if x)
    return fields["model name"] + (f" ({detail})" if detail else "")


def git_rev() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def sources(*groups) -> list[str]:
    """The union of source globs, in order, without repeats.

    >>> sources(("a.py", "b/**"), ["b/**", "c.py"])
    ['a.py', 'b/**', 'c.py']
    """
    return list(dict.fromkeys(s for g in groups for s in g))


def stamp(section: str, command: str, techniques, sources, commit: str | None = None, **extra) -> str:
    """The stamp line of a generated page or section (see the module's docstring).

    >>> stamp("paper", "python -m benchmarks paper", ["pre", "post"], ["benchmarks/paper.py"], commit="ad6551e")
    '<!-- isplat-stamp: {"section": "paper", "commit": "ad6551e", "command": "python -m benchmarks paper", \
"techniques": ["pre", "post"], "sources": ["benchmarks/paper.py"]} -->'
    """
    bad = [t for t in techniques if t not in ("pre", "post", "mip", "minip")]
    if bad:
        raise ValueError(f"unknown techniques {bad}: expected 'pre', 'post', 'mip' or 'minip'")
    d = {"section": section, "commit": commit or git_rev(), "command": command, "techniques": list(techniques),
         "sources": list(sources), **extra}
    return f"<!-- {STAMP_TAG}: {json.dumps(d)} -->"


def historical(section: str, why: str) -> str:
    """The stamp of a page or section that is deliberately not regenerated, with the reason."""
    return f"<!-- {STAMP_TAG}: {json.dumps({'section': section, 'historical': why})} -->"


# Runs argv[1:] in a child forked from this small process and prints the child's exit status, its peak resident set
# (RUSAGE_CHILDREN.ru_maxrss, KiB) and its wall seconds. Linux carries a process's high-water RSS across fork and
# exec (a child spawned by a big benchmark process reports that process's peak: a /bin/true spawned by the render
# benchmark "used" 431 MiB), so the measured command is started from this fresh, small one.
_PEAK_WRAPPER = """import os, resource, sys, time
t = time.perf_counter()
pid = os.fork()
if pid == 0:
    fd = os.open(os.devnull, os.O_WRONLY)
    os.dup2(fd, 1)
    try:
        os.execv(sys.argv[1], sys.argv[1:])
    finally:
        os._exit(127)
_, status = os.waitpid(pid, 0)
dt = time.perf_counter() - t
print(os.waitstatus_to_exitcode(status), resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, dt)
"""


def child_peak(argv, env=None) -> tuple[float, float]:
    """(peak resident set in MiB, wall seconds) of the command ``argv`` (stdout discarded) run in a process of
    its own, started from a fresh small process so that the figure is the command's own (see _PEAK_WRAPPER).
    Raises RuntimeError when it fails. Compare with :func:`baseline_peak`, the floor of the method."""
    import sys

    r = subprocess.run([sys.executable, "-c", _PEAK_WRAPPER, *map(str, argv)], capture_output=True, text=True,
                       env=env)
    try:
        code, kib, dt = r.stdout.split()
    except ValueError:
        raise RuntimeError(f"{' '.join(map(str, argv))}: no measurement ({r.stderr.strip()[-300:]})") from None
    if int(code) != 0:
        raise RuntimeError(f"{' '.join(map(str, argv))} failed (exit {code}): {r.stderr.strip()[-300:]}")
    return int(kib) / 1024.0, float(dt)


def baseline_peak() -> float:
    """Peak RSS (MiB) that :func:`child_peak` reports for ``/bin/true``: what the method itself counts."""
    return child_peak(["/bin/true"])[0]


def median_ms(seconds) -> float:
    return 1000.0 * statistics.median(seconds)


def update_section(path: Path, name: str, body: str, title: str | None = None) -> Path:
    """Replace section ``name`` of the Markdown file ``path`` with ``body`` (creating file/section)."""
    path = Path(path)
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    block = f"{begin}\n{body.rstrip()}\n{end}\n"
    text = path.read_text() if path.exists() else (f"# {title}\n\n" if title else "")
    if begin in text and end in text:
        pre = text[:text.index(begin)]
        post = text[text.index(end) + len(end):].lstrip("\n")
        text = pre + block + ("\n" + post if post else "")
    else:
        text = text.rstrip("\n") + "\n\n" + block
    path.write_text(text)
    return path


_STAMP_RE = None


def stamp_re():
    """The regular expression of a stamp line: group 1 is its JSON."""
    import re

    global _STAMP_RE
    if _STAMP_RE is None:
        _STAMP_RE = re.compile(r"^<!-- " + STAMP_TAG + r": (\{.*\}) -->[ \t]*$", re.M)
    return _STAMP_RE


def put_stamp(path: Path, line: str, section: str | None = None) -> Path:
    r"""Put the stamp ``line`` into ``path``: as the first line inside section ``section`` (between its BEGIN and
    END markers), or as the page's first line when ``section`` is None; an older stamp there is replaced.

    >>> import tempfile
    >>> page = Path(tempfile.mkdtemp()) / "p.md"
    >>> _ = page.write_text("# P\n\n<!-- BEGIN a -->\nrows\n<!-- END a -->\n")
    >>> for commit in ("1111111", "2222222"):
    ...     _ = put_stamp(page, stamp("a", "cmd", ["post"], ["src/**"], commit=commit), "a")
    >>> print(page.read_text().replace('"sources": ["src/**"]', '...'))
    # P
    <BLANKLINE>
    <!-- BEGIN a -->
    <!-- isplat-stamp: {"section": "a", "commit": "2222222", "command": "cmd", "techniques": ["post"], ...} -->
    rows
    <!-- END a -->
    <BLANKLINE>
    """
    path = Path(path)
    text = path.read_text()
    if section is None:
        lo, hi = 0, len(text)
    else:
        begin, end = f"<!-- BEGIN {section} -->\n", f"<!-- END {section} -->"
        if begin not in text or end not in text:
            raise ValueError(f"{path}: no section {section!r}")
        lo = text.index(begin) + len(begin)
        hi = text.index(end, lo)
    body = text[lo:hi]
    first = body.split("\n", 1)[0]
    if stamp_re().match(first):
        body = body.split("\n", 1)[1] if "\n" in body else ""
    path.write_text(text[:lo] + line + "\n" + body + text[hi:])
    return path


def stamp_output(path: Path, module, command: str) -> Path:
    """Stamp what benchmark ``module`` wrote at ``path``: its section (``module.SECTION``) or the whole page, with
    its ``TECHNIQUES`` and ``SOURCES``."""
    section = getattr(module, "SECTION", None)
    line = stamp(section or Path(path).stem, command, module.TECHNIQUES, module.SOURCES)
    return put_stamp(path, line, section)
