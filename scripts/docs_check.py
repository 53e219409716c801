"""Which generated pages and sections of docs/ are stale: ``make docs-check`` (``python scripts/docs_check.py``).

Every generated page or section carries a stamp line (benchmarks/_doc.py, ``stamp``)::

    <!-- isplat-stamp: {"section": "paper", "commit": "ad6551e", "command": "python -m benchmarks paper",
                        "techniques": ["pre", "post"], "sources": ["isplat/splat/**", "benchmarks/paper.py"]} -->

A stamp is stale when a file matching one of its ``sources`` (git pathspec globs from the repository root)
changed between its ``commit`` and HEAD (``git diff --name-only COMMIT HEAD``), or when its commit is not in
the repository. A stamp ``{"section": ..., "historical": "why"}`` marks a page or section that is deliberately
not regenerated; it is listed, never stale. A page of docs/ with no stamp at all, and a
``<!-- BEGIN name -->`` section with no stamp of its own, are listed as unstamped.

Prints one line per stamp and per unstamped page or section, then a summary; exits 1 with ``--strict`` when
something is stale or unstamped (CI runs it without, so that the list is printed and the run goes on), else 0.
A malformed stamp exits 2.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

STAMP_RE = re.compile(r"^<!-- isplat-stamp: (\{.*\}) -->[ \t]*$", re.M)
BEGIN_RE = re.compile(r"^<!-- BEGIN (\S+) -->[ \t]*$", re.M)
TECHNIQUES = ("pre", "post", "mip", "minip")   # render.classification, or render.mode for an intensity projection


class StampError(Exception):
    pass


@dataclass
class Finding:
    page: str
    section: str
    state: str                      # "ok", "stale", "unknown commit", "historical", "unstamped"
    detail: str = ""
    changed: list = field(default_factory=list)
    stamp: dict = field(default_factory=dict)

    @property
    def bad(self) -> bool:
        return self.state in ("stale", "unknown commit", "unstamped")


def _git(repo: Path, *args) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True)


def parse_stamp(text: str, where: str) -> dict:
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise StampError(f"{where}: stamp is not JSON: {exc}") from None
    if not isinstance(d, dict) or not isinstance(d.get("section"), str):
        raise StampError(f"{where}: stamp without a 'section' name")
    if "historical" in d:
        if not isinstance(d["historical"], str) or not d["historical"].strip():
            raise StampError(f"{where}: a historical stamp says why, as a string")
        return d
    for key, kind in (("commit", str), ("command", str), ("techniques", list), ("sources", list)):
        if not isinstance(d.get(key), kind):
            raise StampError(f"{where}: stamp {d['section']!r}: '{key}' missing or not a {kind.__name__}")
    bad = [t for t in d["techniques"] if t not in TECHNIQUES]
    if bad:
        raise StampError(f"{where}: stamp {d['section']!r}: techniques {bad}, expected among {list(TECHNIQUES)}")
    if not d["sources"] or not all(isinstance(s, str) and s for s in d["sources"]):
        raise StampError(f"{where}: stamp {d['section']!r}: 'sources' must name at least one path or glob")
    return d


def _sections(text: str) -> list[tuple[str, int, int]]:
    """(name, start, end) of every BEGIN/END section of a page."""
    out = []
    for m in BEGIN_RE.finditer(text):
        end = text.find(f"<!-- END {m.group(1)} -->", m.end())
        out.append((m.group(1), m.end(), end if end >= 0 else len(text)))
    return out


def changed_since(repo: Path, commit: str, sources) -> list[str] | None:
    """Files matching ``sources`` that differ between ``commit`` and HEAD; None when the commit is unknown."""
    if _git(repo, "rev-parse", "--verify", "--quiet", f"{commit}^{{commit}}").returncode != 0:
        return None
    r = _git(repo, "diff", "--name-only", commit, "HEAD", "--", *(f":(glob){s}" for s in sources))
    if r.returncode != 0:
        raise StampError(f"git diff {commit} HEAD failed: {r.stderr.strip()}")
    return [ln for ln in r.stdout.splitlines() if ln]


def check_page(repo: Path, page: Path, rel: str) -> list[Finding]:
    text = page.read_text(encoding="utf-8")
    found = []
    stamps = [(m.start(), parse_stamp(m.group(1), rel)) for m in STAMP_RE.finditer(text)]
    if not stamps:
        return [Finding(rel, "(page)", "unstamped", "no isplat-stamp line: generated pages and sections carry one, "
                        "hand-written ones say 'historical' with a reason")]
    for name, lo, hi in _sections(text):
        if not any(lo <= pos < hi for pos, _ in stamps):
            found.append(Finding(rel, name, "unstamped", f"section {name!r} has no stamp of its own"))
    for _, d in stamps:
        if "historical" in d:
            found.append(Finding(rel, d["section"], "historical", d["historical"], stamp=d))
            continue
        changed = changed_since(repo, d["commit"], d["sources"])
        if changed is None:
            found.append(Finding(rel, d["section"], "unknown commit",
                                 f"commit {d['commit']} is not in this repository", stamp=d))
        elif changed:
            found.append(Finding(rel, d["section"], "stale", f"{len(changed)} source files changed since "
                                 f"{d['commit']}", changed, stamp=d))
        else:
            found.append(Finding(rel, d["section"], "ok", f"measured at {d['commit']}", stamp=d))
    return found


def check(repo: Path, docs: Path) -> list[Finding]:
    out = []
    for page in sorted(docs.glob("*.md")):
        try:
            rel = str(page.relative_to(repo))
        except ValueError:
            rel = str(page)
        out.extend(check_page(repo, page, rel))
    return out


def report(findings: list[Finding], show: int = 3) -> str:
    lines = []
    for f in findings:
        s = f.stamp
        tech = f" [{', '.join(s['techniques']) or 'no render'}]" if "techniques" in s else ""
        line = f"{f.state.upper():<15} {f.page} § {f.section}{tech}: {f.detail}"
        if f.changed:
            more = f", ... (+{len(f.changed) - show})" if len(f.changed) > show else ""
            line += ": " + ", ".join(f.changed[:show]) + more
        if f.state in ("stale", "unknown commit"):
            line += f"; rerun: {s['command']}"
        lines.append(line)
    n = {k: sum(1 for f in findings if f.state == k) for k in ("ok", "stale", "unknown commit", "unstamped",
                                                                 "historical")}
    lines.append(f"docs-check: {n['ok']} up to date, {n['stale'] + n['unknown commit']} stale, "
                 f"{n['unstamped']} unstamped, {n['historical']} historical")
    return "\n".join(lines)


def main(argv=None) -> int:
    root = Path(__file__).resolve().parents[1]
    ap = argparse.ArgumentParser(prog="docs_check", description=__doc__.split("\n\n")[0])
    ap.add_argument("--repo", type=Path, default=root, help="the git repository (default: this one)")
    ap.add_argument("--docs", type=Path, default=None, help="the folder of pages (default: REPO/docs)")
    ap.add_argument("--strict", action="store_true", help="exit 1 when a page or section is stale or unstamped")
    a = ap.parse_args(argv)
    repo = a.repo.resolve()
    docs = (a.docs or repo / "docs").resolve()
    try:
        findings = check(repo, docs)
    except StampError as exc:
        print(f"docs-check: error: {exc}", file=sys.stderr)
        return 2
    print(report(findings))
    return 1 if a.strict and any(f.bad for f in findings) else 0


if __name__ == "__main__":
    sys.exit(main())
