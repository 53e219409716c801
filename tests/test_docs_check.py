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


def test_mark_says_on_the_page_that_a_section_is_older_than_its_code(repo):
    page = repo / "docs" / "bench.md"
    clean = page.read_text()
    assert _check(repo, "--mark").returncode == 0 and page.read_text() == clean       # up to date: no note
    (repo / "src" / "kernel.py").write_text("x = 2\n")
    _git(repo, "commit", "-q", "-am", "kernel changed")
    assert _check(repo, "--mark").returncode == 0
    lines = page.read_text().splitlines()
    assert lines[1].startswith("> **Older than the code it measures**") and "src/kernel.py" in lines[1]
    assert "Rerun: `python -m benchmarks bench`" in lines[1] and lines[2] == ""
    assert lines[3:] == clean.splitlines()[1:]
    _check(repo, "--mark")
    assert page.read_text().count("Older than the code") == 1                          # once, however often
    # the source back as measured: not stale any more, the note goes
    (repo / "src" / "kernel.py").write_text("x = 1\n")
    _git(repo, "commit", "-q", "-am", "kernel back")
    _check(repo, "--mark")
    assert page.read_text() == clean


def _bench_writer(repo, name, code=0):
    """A stand-in benchmark: rewrites its page stamped at HEAD (so it is no longer stale), or fails with ``code``."""
    head = _git(repo, "rev-parse", "--short", "HEAD")
    text = _stamp(section=name, commit=head, command=f"python bench_{name}.py", techniques=["post"],
                  sources=["src/**"]) + f"\n# {name}\n"
    write = f"pathlib.Path('docs/{name}.md').write_text({text!r})\n" if code == 0 else ""
    (repo / f"bench_{name}.py").write_text(f"import pathlib, sys\n{write}sys.exit({code})\n")


def test_rerun_runs_each_stale_command_cheapest_first_and_stops_at_a_failure(repo):
    head = _git(repo, "rev-parse", "--short", "HEAD")
    for name in ("one", "two"):
        (repo / "docs" / f"{name}.md").write_text(
            _stamp(section=name, commit=head, command=f"python bench_{name}.py (make {name})", techniques=["pre"],
                   sources=["src/**"]) + f"\n# {name}\n")
    (repo / "src" / "kernel.py").write_text("x = 3\n")
    _git(repo, "add", "-A")
    _git(repo, "commit", "-q", "-m", "kernel changed")
    _bench_writer(repo, "one")
    dry = _check(repo, "--rerun", "--dry-run")
    assert dry.returncode == 0 and "3 commands" in dry.stderr and "python bench_one.py   (~15 min" in dry.stderr
    assert (repo / "docs" / "one.md").read_text().endswith("# one\n")                  # nothing ran
    _bench_writer(repo, "two", code=3)
    out = _check(repo, "--rerun", "--only", "one,two")
    err = out.stderr.splitlines()
    assert out.returncode == 1 and err[-1].startswith("docs-regen: error: python bench_two.py failed (exit 3)"), err
    assert any(ln.startswith("docs-regen: [1/2] python bench_one.py: ") and ln.endswith(" s wall") for ln in err)
    _bench_writer(repo, "two")
    out = _check(repo, "--rerun", "--only", "one,two")
    assert out.returncode == 0, out.stderr
    assert "1 commands" in out.stderr and "bench_one" not in out.stderr               # one is up to date now
    assert "STALE" in out.stdout and "docs/bench.md" in out.stdout                       # not asked for: still stale
    assert _check(repo, "--rerun", "--only", "nope").returncode == 2
