# benchtwin: `make demo` runs the main job on the embedded default; `make test` runs the suite;
# `make test-vcan` runs the kernel SocketCAN tests under a Linux guest that has vcan (root; see README).
PYTHON ?= python3.11
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test test-vcan bench clean

$(BIN)/python:
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) (set PYTHON=...)"; exit 1; }
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/benchtwin validate --out out/demo --figures

test: $(STAMP)
	$(BIN)/ruff check benchtwin tests benchmarks
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

test-vcan: $(STAMP)
	tests/vcan/run_vm.sh

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[bench]'
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) .venv-vng build *.egg-info .pytest_cache
