# The two commands of the README: `make demo` and `make test`. Everything else builds on them.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
ISPLAT := $(BIN)/isplat
OUT    ?= out
STAMP  := $(VENV)/.installed

.PHONY: demo test bench data paper-table bench-peers clean venv

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
