"""Write benchmark results into Markdown files, one marked section per benchmark.

Several benchmarks share a page (docs/performance.md holds the render benchmark and the paper's
Figure 5 table); each owns the text between ``<!-- BEGIN name -->`` and ``<!-- END name -->``, and rerunning
one replaces only its own section.
"""

from __future__ import annotations

import platform
import statistics
import subprocess
from pathlib import Path


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
