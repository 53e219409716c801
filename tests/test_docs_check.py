"""make docs-check (scripts/docs_check.py): a stamp's source list makes the check fail when one of those sources
changes, and only then; pages without a stamp are listed; historical pages are listed, never stale."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHECK = ROOT / "scripts" / "docs_check.py"


def _git(repo, *args):
    return subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True, text=True).stdout.strip()


def _check(repo, *args):
    return subprocess.run([sys.executable, str(CHECK), "--repo", str(repo), *args], capture_output=True, text=True)


def _stamp(**d):
    return f"<!-- isplat-stamp: {json.dumps(d)} -->"


@pytest.fixture
def repo(tmp_path):
    """A repository with a source, an unrelated file and a page stamped at the commit that measured them."""
    r = tmp_path / "repo"
    (r / "src").mkdir(parents=True)
    (r / "docs").mkdir()
    _git(r, "init", "-q")
    _git(r, "config", "user.email", "t@example.invalid")
    _git(r, "config", "user.name", "t")
    (r / "src" / "kernel.py").write_text("x = 1\n")
    (r / "other.txt").write_text("a\n")
    _git(r, "add", "-A")
    _git(r, "commit", "-q", "-m", "measured")
    head = _git(r, "rev-parse", "--short", "HEAD")
    page = r / "docs" / "bench.md"
    page.write_text(_stamp(section="bench", commit=head, command="python -m benchmarks bench",
                           techniques=["pre", "post"], sources=["src/**"]) + "\n# Bench\n\n| post | 1 ms |\n")
    _git(r, "add", "-A")
    _git(r, "commit", "-q", "-m", "page")
    return r


def test_a_changed_source_makes_the_page_stale(repo):
    ok = _check(repo, "--strict")
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert "OK" in ok.stdout and "0 stale" in ok.stdout
    (repo / "other.txt").write_text("b\n")                  # not one of the page's sources
    _git(repo, "commit", "-q", "-am", "unrelated")
    assert _check(repo, "--strict").returncode == 0
    (repo / "src" / "kernel.py").write_text("x = 2\n")
    _git(repo, "commit", "-q", "-am", "kernel changed")
    stale = _check(repo, "--strict")
    assert stale.returncode == 1
    line = next(ln for ln in stale.stdout.splitlines() if ln.startswith("STALE"))
    assert "docs/bench.md" in line and "src/kernel.py" in line and "python -m benchmarks bench" in line
    assert _check(repo).returncode == 0                     # without --strict it lists and passes (as CI runs it)


def test_pages_without_a_stamp_and_unknown_commits_are_listed(repo):
    (repo / "docs" / "loose.md").write_text("# No stamp\n\n<!-- BEGIN part -->\n1 ms\n<!-- END part -->\n")
    out = _check(repo, "--strict")
    assert out.returncode == 1 and "UNSTAMPED" in out.stdout and "docs/loose.md" in out.stdout
    (repo / "docs" / "loose.md").write_text(_stamp(section="loose", commit="0" * 40, command="c", techniques=[],
                                                   sources=["src/**"]) + "\n# x\n")
    out = _check(repo, "--strict")
    assert out.returncode == 1 and "UNKNOWN COMMIT" in out.stdout


def test_a_section_needs_its_own_stamp_and_historical_is_not_stale(repo):
    page = repo / "docs" / "mixed.md"
    page.write_text(_stamp(section="mixed", historical="hand-written notes") + "\n# Notes\n\n"
                    "<!-- BEGIN one -->\n1 ms\n<!-- END one -->\n")
    out = _check(repo, "--strict")
    assert out.returncode == 1 and "UNSTAMPED" in out.stdout and "§ one" in out.stdout
    head = _git(repo, "rev-parse", "HEAD")
    one = _stamp(section="one", commit=head, command="cmd", techniques=["post"], sources=["src/**"])
    page.write_text(page.read_text().replace("<!-- BEGIN one -->\n", f"<!-- BEGIN one -->\n{one}\n"))
    out = _check(repo, "--strict")
    assert out.returncode == 0, out.stdout
    assert "HISTORICAL" in out.stdout


def test_a_malformed_stamp_is_an_error(repo):
    (repo / "docs" / "bad.md").write_text(_stamp(section="bad", commit="x", command="c", techniques=["fast"],
                                                 sources=["src/**"]) + "\n")
    out = _check(repo)
    assert out.returncode == 2 and "techniques" in out.stderr
