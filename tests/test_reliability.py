"""The catalogue of bad inputs (benchmarks/reliability.py, docs/reliability.md) takes its runs-file cases from
tests/fuzzlab.py: the runs files beside an index that a stranger can make (formats/runs.md §5, §6) each end in one
error line naming the file, the problem and the command that rebuilds it; the named corruptions of the runs file
are refused by the scene that reads it."""

import pytest

import fuzzlab as R


@pytest.fixture(scope="module")
def fx(tmp_path_factory):
    return R.make_fixture(tmp_path_factory.mktemp("fx"), scenes=("post", "post_runs"))


@pytest.fixture(scope="module")
def cases(fx, tmp_path_factory):
    w = tmp_path_factory.mktemp("w")
    return w, R.runs_cases(fx, w)


def test_each_runs_case_is_one_line_naming_file_problem_and_rebuild(cases):
    w, got = cases
    assert len(got) >= 8
    for what, argv, word in got:
        code, out, err = R.run_cli(argv)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and lines[0].startswith("isplat: error: "), (what, err)
        assert ".runs.idx.h5" in lines[0] and word in lines[0], (what, err)
        if argv[0] != "index":      # isplat index itself: the runs file beside exists, use --force
            assert "isplat index " in lines[0] and "--force" in lines[0], (what, err)
        assert not list(w.glob("r*.png")), what


@pytest.mark.parametrize("case", R.RUNS_PAIR_CASES, ids=lambda c: c[0])
def test_pair_cases_of_the_runs_file_are_refused(fx, case):
    what, target, obj, op = case
    path = fx[target]
    mutant = R.corrupted_bytes(path, obj, op)
    out = R.check_mutant(fx, target, mutant, op)
    # the command last, with the files' names (a chunk's "(runs a..b)" before it)
    assert out.result == "error" and str(path) in out.message, out
    assert out.message.endswith(f"; rebuild it: isplat index {fx['aug']} -o {fx['idx']} --force"), out


def test_unreadable_runs_file_is_one_line(fx, tmp_path, monkeypatch):
    """A runs file this user may not read (simulated: the tests may run as root, who reads every file)."""
    import os

    from isplat import fileio

    real = os.access
    monkeypatch.setattr(fileio.os, "access", lambda p, mode: False if str(p) == str(fx["runs"]) else real(p, mode))
    code, _, err = R.run_cli(["render", str(fx["post_runs"]), "--view", "0", "-o", str(tmp_path / "x.png")])
    assert code == 2 and err.count("\n") == 1 and f"{fx['runs']}: runs file is not readable" in err
    assert f"rebuild it: isplat index {fx['aug']} -o {fx['idx']} --force" in err and not list(tmp_path.iterdir())
