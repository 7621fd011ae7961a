# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench clean

# `make bench QUICK=1`: every benchmark with --quick (fewer runs; to see that they work)
QUICK ?=
BENCH_FLAGS := $(if $(QUICK),--quick,)

$(STAMP): pyproject.toml
	@echo "calbench: creating the virtual environment $(VENV) (once)"
	$(PYTHON) -m venv $(VENV)
	@echo "calbench: installing calbench and its dependencies (MuJoCo, Rerun, SciPy, ...) into $(VENV): about 90 s, once"
	@echo "  (setuptools may warn 'Please be careful with folders in your working directory with the same"
	@echo "  name as your package': harmless here, the package is calbench and no folder of the checkout has that name)"
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)
	@echo "calbench: installed in $(VENV)"

demo: $(STAMP)
	@echo "calbench: the demo (simulate, view, identify, discover; about a minute)"
	$(BIN)/calbench demo

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m pytest

bench: $(STAMP)
	@n=$$(ls benchmarks/*_bench.py | wc -l); i=0; for b in benchmarks/*_bench.py; do i=$$((i+1)); \
	  echo "== [$$i/$$n] $$b $(BENCH_FLAGS) (JSON on stdout, progress on stderr)"; \
	  $(BIN)/python $$b $(BENCH_FLAGS) || exit 1; done

clean:
	rm -rf $(VENV) logs/*.mcap logs/*.rrd logs/*.json
