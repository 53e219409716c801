# The two commands of the README: `make demo` and `make test`. Everything else builds on them.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
ISPLAT := $(BIN)/isplat
OUT    ?= out
STAMP  := $(VENV)/.installed
PREBUILT := isplat/_prebuilt/manifest.json

.PHONY: demo prebuilt test bench bench-check wheel-check data paper-table bench-peers accuracy reference stability clean venv readme-images labels-image presets-doc reliability fuzz-boundscheck docs-check docs-regen

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[all,test]'
	touch $(STAMP)

# The tests, and the examples in isplat's docstrings as doctests.
test: $(STAMP)
	$(BIN)/python -m pytest -q isplat tests

demo: $(STAMP) $(PREBUILT)
	OUT=$(OUT) ISPLAT=$(ISPLAT) bash scripts/demo.sh

# The kernels compiled ahead of time for x86-64-v3 (isplat.prebuilt), so that no first run compiles; made again
# when a source changes (a kernel's cache stamp covers every file of compiled functions).
prebuilt: $(PREBUILT)

$(PREBUILT): $(STAMP) $(wildcard isplat/*.py isplat/*/*.py)
	$(BIN)/python -m isplat.prebuilt isplat/_prebuilt

# The benchmarks live in benchmarks/ (not installed); each writes its page of docs/ with the command that made it.
bench: $(STAMP)
	$(BIN)/python -m benchmarks all --out docs

# Every benchmark at small sizes into $(OUT)/bench-check (docs/ untouched), and the benchmarks' doctests.
bench-check: $(STAMP)
	$(BIN)/python -m pytest -q --doctest-modules benchmarks
	$(BIN)/python -m benchmarks all --quick --out $(OUT)/bench-check

# The generated pages and sections of docs/ whose measured sources changed since the commit in their stamp
# (scripts/docs_check.py); DOCS_CHECK=--strict fails on a stale or unstamped one.
DOCS_CHECK ?=
docs-check: $(STAMP)
	$(BIN)/python scripts/docs_check.py $(DOCS_CHECK)

# Every stale section regenerated in one command: their rerun commands, cheapest first, each one's wall time on
# stderr, stopping at the first failure (scripts/docs_check.py --rerun). DOCS_REGEN="--max-minutes 10" leaves the
# long ones (reliability's fuzz, scale and outofcore at 1024^3, peers) out; DOCS_REGEN=--dry-run shows the order.
DOCS_REGEN ?=
docs-regen: $(STAMP)
	$(BIN)/python scripts/docs_check.py --rerun $(DOCS_REGEN)

# The wheel holds isplat/ (library and CLI) only.
wheel-check: $(STAMP)
	$(BIN)/python scripts/check_wheel.py

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info isplat/_prebuilt

data: $(STAMP)
	$(BIN)/python scripts/fetch_data.py --out data --keep-going

paper-table: $(STAMP)
	$(BIN)/python -m benchmarks paper --out docs

# docs/reference.md: the references independent of splatting (cached under out/references) and their convergence.
reference: $(STAMP)
	$(BIN)/python -m benchmarks reference --out docs

# docs/accuracy.md, accuracy.csv, accuracy_rounds.csv (every frame time), img/accuracy_pareto.png: error against
# the references (a) and (b) against frame time for every speed knob, VTK's sample distances when VTK can render
# here, the Pareto front (by a paired sign test over the rounds: tests/paired_times.py), popping.
accuracy: $(STAMP)
	$(BIN)/python -m benchmarks accuracy --out docs

# docs/stability.md: stiff and extreme cases against their analytic values.
stability: $(STAMP)
	$(BIN)/python -m benchmarks stability --out docs

# Optional, not in CI: isplat against VTK's CPU ray caster (installs vtk; needs Mesa EGL or OSMesa).
# PEERS=--load: the frames also timed with another process spinning on one core (docs/performance.md, "Under load").
PEERS ?=
bench-peers: $(STAMP)
	$(BIN)/pip install --quiet vtk
	$(BIN)/python -m benchmarks.peers --out docs $(PEERS)

# The README's pictures: make demo, then 256-pixel copies of its images into docs/img/.
readme-images: demo
	$(BIN)/python scripts/readme_images.py $(OUT) docs/img

# docs/img/demo-ct-chest-labels.png: the ct-chest sample with its segmentation labels (docs/labels.md).
labels-image: $(STAMP)
	OUT=$(OUT) ISPLAT=$(ISPLAT) bash scripts/labels_image.sh docs/img

# docs/presets.md and docs/img/preset-*.png: every transfer-function preset on a synthetic scan.
presets-doc: $(STAMP)
	$(BIN)/python scripts/presets_doc.py $(OUT)/presets docs

# docs/reliability.md: the catalogue of bad inputs and their messages, fuzz figures, the checksums' cost.
reliability: $(STAMP)
	$(BIN)/python -m benchmarks reliability --out docs

# The fuzz test with numba bounds checking on (every mutant rendered with both techniques, so both techniques'
# kernels are checked); a fresh cache, since numba reuses kernels compiled without it.
FUZZ_SECONDS ?= 300
fuzz-boundscheck: $(STAMP)
	cache=$$(mktemp -d) && NUMBA_BOUNDSCHECK=1 NUMBA_CACHE_DIR=$$cache ISPLAT_FUZZ_SECONDS=$(FUZZ_SECONDS) \
	  $(BIN)/python -m pytest -q tests/test_fuzz.py; status=$$?; rm -rf $$cache; exit $$status
