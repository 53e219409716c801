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
    """One line describing the machine the numbers come from."""
    import os

    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"{cpu}, {cores} cores usable, Python {platform.python_version()}"


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
