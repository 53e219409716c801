# The two commands of the README: `make demo` and `make test`. Everything else builds on them.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
ISPLAT := $(BIN)/isplat
OUT    ?= out
STAMP  := $(VENV)/.installed

.PHONY: demo test bench data paper-table bench-peers clean venv readme-images reliability fuzz-boundscheck

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[all,test]'
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -q tests

demo: $(STAMP)
	OUT=$(OUT) ISPLAT=$(ISPLAT) bash scripts/demo.sh

bench: $(STAMP)
	$(BIN)/python -m isplat.bench all --out docs

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info

data: $(STAMP)
	$(BIN)/python scripts/fetch_data.py --out data --keep-going

paper-table: $(STAMP)
	$(BIN)/python -m isplat.bench paper --out docs

# Optional, not in CI: isplat against VTK's CPU ray caster (installs vtk; needs Mesa EGL or OSMesa).
bench-peers: $(STAMP)
	$(BIN)/pip install --quiet vtk
	$(BIN)/python -m isplat.bench.peers --out docs

# The README's pictures: make demo, then 256-pixel copies of its images into docs/img/.
readme-images: demo
	$(BIN)/python scripts/readme_images.py $(OUT) docs/img

# docs/reliability.md: the catalogue of bad inputs and their messages, fuzz figures, the checksums' cost.
reliability: $(STAMP)
	$(BIN)/python -m isplat.bench.reliability --out docs

# The fuzz test with numba bounds checking on; a fresh cache, since numba reuses kernels compiled without it.
FUZZ_SECONDS ?= 300
fuzz-boundscheck: $(STAMP)
	cache=$$(mktemp -d) && NUMBA_BOUNDSCHECK=1 NUMBA_CACHE_DIR=$$cache ISPLAT_FUZZ_SECONDS=$(FUZZ_SECONDS) \
	  $(BIN)/python -m pytest -q tests/test_fuzz.py; status=$$?; rm -rf $$cache; exit $$status
