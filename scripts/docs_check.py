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

``--mark`` writes, under the stamp of every stale section, one visible line saying that the section is older
than the code it measures, with its rerun command (``> **Older than the code it measures** ... <!-- isplat-stale
-->``), and removes that line where the section is no longer stale; a regenerated section is written without it.

``--rerun`` (``make docs-regen``) regenerates: it runs the rerun command of every stale section once (a command
shared by sections runs once), cheapest first by :data:`MINUTES` (what each took on a 2-core machine; one not in
it counts as :data:`UNKNOWN_MINUTES`), the long ones last, each command's wall time logged to stderr; the first
command that fails stops the run with one line (exit 1); the check is printed again at the end. ``--dry-run``
prints that order with the estimates and runs nothing; ``--max-minutes M`` runs only the commands estimated at
most M minutes (the others are listed as left out); ``--only NAME,...`` only those sections.
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

STAMP_RE = re.compile(r"^<!-- isplat-stamp: (\{.*\}) -->[ \t]*$", re.M)
BEGIN_RE = re.compile(r"^<!-- BEGIN (\S+) -->[ \t]*$", re.M)
TECHNIQUES = ("pre", "post", "mip", "minip")   # render.classification, or render.mode for an intensity projection
STALE_TAG = "<!-- isplat-stale -->"
STALE_RE = re.compile(r"^> \*\*Older than the code it measures\*\*.*" + re.escape(STALE_TAG) + r"[ \t]*\n\n?", re.M)


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


def stale_note(f: Finding) -> str:
    """The visible line under a stale section's stamp (``--mark``)."""
    if f.state == "unknown commit":
        why = f"measured at {f.stamp['commit']}, a commit this repository does not have"
    else:
        why = (f"measured at {f.stamp['commit']}; {len(f.changed)} of its source files changed since (first: "
               f"{', '.join(f.changed[:3])})")
    return (f"> **Older than the code it measures** (`make docs-check`): {why}. Rerun: "
            f"`{runnable(f.stamp['command'])}` (or `make docs-regen`). {STALE_TAG}\n\n")   # its own paragraph


def mark_page(repo: Path, page: Path, rel: str) -> bool:
    """Put :func:`stale_note` under each stale stamp of ``page`` and take it from the others; True if changed."""
    text = page.read_text(encoding="utf-8")
    findings = {f.section: f for f in check_page(repo, page, rel) if f.stamp}
    out, pos = [], 0
    for m in STAMP_RE.finditer(text):
        end = m.end() + 1 if text[m.end():m.end() + 1] == "\n" else m.end()
        out.append(text[pos:end])
        pos = end
        old = STALE_RE.match(text, pos)
        if old:
            pos = old.end()
        f = findings.get(json.loads(m.group(1)).get("section"))
        if f is not None and f.state in ("stale", "unknown commit"):
            out.append(stale_note(f))
    out.append(text[pos:])
    new = "".join(out)
    if new != text:
        page.write_text(new, encoding="utf-8")
    return new != text


# Estimated wall minutes of each rerun command (its first words, as in the stamps): what each took on this
# project's 2-core machine shared with other work (docs-regen logs the time of every run; update them from it).
# The order of --rerun: cheapest first. reference caches the references accuracy reads, so accuracy comes after
# it. The quick variants (--quick) of the long ones run in minutes: bench-check.
MINUTES = {
    "python -m benchmarks normals": 0.1,
    "make presets-doc": 0.2,
    "python -m benchmarks scale": 0.5,
    "python -m benchmarks.reliability --chunk-hash-cost": 0.7,
    "python -m benchmarks render": 0.9,
    "python -m benchmarks sheets": 1,
    "python -m benchmarks augment": 1.1,
    "python -m benchmarks paper": 1.1,
    "python -m benchmarks stability": 1.3,
    "python -m benchmarks index": 2,
    "python -m benchmarks startup": 3,
    "python -m benchmarks reference": 4,
    "python -m benchmarks thick": 4.6,
    "python -m benchmarks sampler": 6,                             # compiles the older commit's kernels once more
    "python -m benchmarks worksplit": 4.8,
    "python -m benchmarks accuracy": 6.5,                          # 25 paired rounds since the sign test
    "python -m benchmarks selective_read": 8,
    "python -m benchmarks bricks": 3,
    "python -m benchmarks.reliability --out docs": 15,           # its fuzz: 120 s per technique, and the catalogue
    "python -m benchmarks outofcore": 10,                          # 1024^3: augment, index, nine renders (7 min)
    "make bench-peers": 12,                                        # installs vtk; every case and size, VTK's too (8 min)
}
UNKNOWN_MINUTES = 15


def runnable(command: str) -> str:
    """The command of a stamp without its remark in parentheses: ``python -m benchmarks paper (make paper-table)``
    -> ``python -m benchmarks paper``."""
    return re.sub(r"\s*\(.*\)\s*$", "", command).strip()


def estimate(command: str) -> float:
    """:data:`MINUTES` of the longest key that starts ``command`` (word for word), else :data:`UNKNOWN_MINUTES`.

    >>> estimate("python -m benchmarks paper"), estimate("python -m benchmarks.reliability --chunk-hash-cost 1,1,1")
    (1.1, 0.7)
    >>> estimate("python -m benchmarks new")
    15
    """
    words = command.split()
    best = None
    for key, minutes in MINUTES.items():
        k = key.split()
        if words[:len(k)] == k and (best is None or len(k) > len(best[0].split())):
            best = (key, minutes)
    return UNKNOWN_MINUTES if best is None else best[1]


def rerun_plan(findings: list[Finding], only=None) -> list[tuple[str, float, list[str]]]:
    """(command, estimated minutes, the sections it regenerates) for the stale sections, cheapest first."""
    plan: dict[str, list[str]] = {}
    for f in findings:
        if f.state not in ("stale", "unknown commit"):
            continue
        if only and f.section not in only:
            continue
        plan.setdefault(runnable(f.stamp["command"]), []).append(f"{f.page} § {f.section}")
    return sorted(((c, estimate(c), secs) for c, secs in plan.items()), key=lambda t: t[1])


def _argv(command: str) -> list[str]:
    """The command's words, ``python`` being this interpreter (the venv's under make)."""
    words = shlex.split(command)
    if words and words[0] == "python":
        words[0] = sys.executable
    return words


def rerun(repo: Path, plan, max_minutes: float | None = None, dry_run: bool = False) -> int:
    """Run ``plan`` (:func:`rerun_plan`) in ``repo``; 0 when every command ran, 1 at the first that failed."""
    todo = [p for p in plan if max_minutes is None or p[1] <= max_minutes]
    left = [p for p in plan if p not in todo]
    log = sys.stderr
    total = sum(m for _, m, _ in todo)
    print(f"docs-regen: {len(todo)} commands, about {total:.0f} min" + (
        f"; left out (estimated over {max_minutes:g} min): " + "; ".join(f"{c} (~{m:g} min)" for c, m, _ in left)
        if left else ""), file=log)
    t_all = time.perf_counter()
    for n, (command, minutes, sections) in enumerate(todo, 1):
        print(f"docs-regen: [{n}/{len(todo)}] {command}   (~{minutes:g} min; {', '.join(sections)})", file=log,
              flush=True)
        if dry_run:
            continue
        t0 = time.perf_counter()
        try:
            code = subprocess.run(_argv(command), cwd=repo).returncode
        except OSError as exc:
            code = f"not started: {exc.strerror or exc}"
        took = time.perf_counter() - t0
        if code != 0:
            print(f"docs-regen: error: {command} failed ({f'exit {code}' if isinstance(code, int) else code}) "
                  f"after {took:.0f} s; the {n - 1} commands before it rewrote their pages; fix it and run "
                  f"docs-regen again (only what is still stale runs)", file=log)
            return 1
        print(f"docs-regen: [{n}/{len(todo)}] {command}: {took:.1f} s wall", file=log, flush=True)
    if not dry_run:
        print(f"docs-regen: {len(todo)} commands in {time.perf_counter() - t_all:.0f} s wall", file=log)
    return 0


def _checked(repo: Path, docs: Path) -> list | None:
    """:func:`check`, or None after one ``docs-check: error:`` line for a malformed stamp."""
    try:
        return check(repo, docs)
    except StampError as exc:
        print(f"docs-check: error: {exc}", file=sys.stderr)
        return None


def main(argv=None) -> int:
    root = Path(__file__).resolve().parents[1]
    ap = argparse.ArgumentParser(prog="docs_check", description=__doc__.split("\n\n")[0])
    ap.add_argument("--repo", type=Path, default=root, help="the git repository (default: this one)")
    ap.add_argument("--docs", type=Path, default=None, help="the folder of pages (default: REPO/docs)")
    ap.add_argument("--strict", action="store_true", help="exit 1 when a page or section is stale or unstamped")
    ap.add_argument("--mark", action="store_true", help="write under each stale section's stamp the line that "
                    "says it is older than the code (and remove it where it is not)")
    ap.add_argument("--rerun", action="store_true", help="run the rerun command of every stale section, cheapest "
                    "first, stopping at the first failure (make docs-regen)")
    ap.add_argument("--dry-run", action="store_true", help="with --rerun: print the order and estimates only")
    ap.add_argument("--max-minutes", type=float, default=None, metavar="M",
                    help="with --rerun: only the commands estimated at most M minutes")
    ap.add_argument("--only", default=None, metavar="NAME,...", help="with --rerun: only these sections")
    a = ap.parse_args(argv)
    repo = a.repo.resolve()
    docs = (a.docs or repo / "docs").resolve()
    findings = _checked(repo, docs)
    if findings is None:
        return 2
    if a.rerun:
        only = set(a.only.split(",")) if a.only else None
        unknown = only - {f.section for f in findings} if only else set()
        if unknown:
            print(f"docs-check: error: --only {','.join(sorted(unknown))}: no such section (the sections: "
                  f"{', '.join(f.section for f in findings)})", file=sys.stderr)
            return 2
        code = rerun(repo, rerun_plan(findings, only), a.max_minutes, a.dry_run)
        if code or a.dry_run:
            return code
        findings = _checked(repo, docs)
        if findings is None:
            return 2
    if a.mark:
        for page in sorted(docs.glob("*.md")):
            rel = str(page.relative_to(repo)) if page.is_relative_to(repo) else str(page)
            if mark_page(repo, page, rel):
                print(f"docs-check: marked {rel}", file=sys.stderr)
    print(report(findings))
    return 1 if a.strict and any(f.bad for f in findings) else 0


if __name__ == "__main__":
    sys.exit(main())
