"""Seeded fuzzing of the index and augmented files, and of the index's values and runs files (issue #13): every
mutant ends in one error line and a non-zero exit, or renders the unmutated images with both techniques (issue 30:
the paper's pre-classified splatting, indexed and full, and the default post-classification, shaded, once from
whole channels and once from the runs file; fuzzlab.SCENES). Budget: ISPLAT_FUZZ_SECONDS (default 45 s); the seed
is ISPLAT_FUZZ_SEED (default: a new one per day, printed on failure). `make fuzz-boundscheck` runs it with numba
bounds checking on. A mutant that fails belongs, as a named corruption, in tests/corpus/mutations.json."""

import datetime
import os

import pytest

import fuzzlab as R

SECONDS = float(os.environ.get("ISPLAT_FUZZ_SECONDS", "45"))
SEED = int(os.environ.get("ISPLAT_FUZZ_SEED", datetime.date.today().toordinal()))


@pytest.mark.slow
def test_fuzz_index_and_augmented(tmp_path):
    fx = R.make_fixture(tmp_path)
    assert {R.SCENES[s][1] for s in fx["scenes"]} == {"pre", "post"}
    # the runs file beside the index (formats/runs.md) is mutated too, and a post scene reads it
    assert fx["runs"].is_file() and R.RUNS_SCENES and all(R.reads_runs(fx[s]) for s in R.RUNS_SCENES)
    rep = R.fuzz(fx, SECONDS, seed=SEED)
    runs = len(rep.outcomes)
    assert runs >= 20, f"only {runs} mutants in {SECONDS} s"
    assert {o.target for o in rep.outcomes} == {"aug", "idx", "values", "runs"}
    bad = [f"{o.target}: {o.mutation}: {o.result}: {o.message[:300]}" for o in rep.failures]
    assert not bad, f"seed {SEED}: {len(bad)} of {runs} mutants failed:\n" + "\n".join(bad[:20])
    # the fuzzer must reach the checks: most mutants of these small files are detected, some change nothing
    assert rep.count(lambda o: o.result == "error") > runs // 2
