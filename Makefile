# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test typecheck bench clean constraints

# `make bench QUICK=1`: every benchmark with --quick (fewer runs; to see that they work)
QUICK ?=
BENCH_FLAGS := $(if $(QUICK),--quick,)

$(STAMP): pyproject.toml constraints.txt
	@echo "calbench: creating the virtual environment $(VENV) (once)"
	$(PYTHON) -m venv $(VENV)
	@echo "calbench: installing calbench and its dependencies (MuJoCo, Rerun, SciPy, ...) into $(VENV): about 90 s, once"
	@echo "  (setuptools may warn 'Please be careful with folders in your working directory with the same"
	@echo "  name as your package': harmless here, the package is calbench and no folder of the checkout has that name)"
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[test]'
	touch $(STAMP)
	@echo "calbench: installed in $(VENV)"

demo: $(STAMP)
	@echo "calbench: the demo (simulate, view, identify, discover; about a minute)"
	$(BIN)/calbench demo

# The suite on two processes (pytest-xdist), each test file whole in one of them so that its
# module fixtures are built once: 2 cores give about half the wall time of one process.
test: $(STAMP) typecheck
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m pytest -n 2 --dist loadfile

# mypy over the public faces (every room's __init__.pyi) and the code that only uses them (the CLI,
# the demo): a face naming a function that moved or a CLI calling one with the wrong arguments fails
# here. The folders are bench/ and identify/ but the import name is calbench.*, so mypy reads them
# through a tree of two links under .venv (settings: [tool.mypy] in pyproject.toml).
TYPES := $(VENV)/typecheck
typecheck: $(STAMP)
	@mkdir -p $(TYPES)/calbench
	@ln -sfn $(CURDIR)/bench $(TYPES)/calbench/bench
	@ln -sfn $(CURDIR)/identify $(TYPES)/calbench/identify
	cd $(TYPES) && MYPYPATH=. $(CURDIR)/$(BIN)/mypy --config-file $(CURDIR)/pyproject.toml \
	  $$(find -L calbench -name __init__.pyi | sort) calbench/identify/cli.py calbench/identify/demo.py

bench: $(STAMP)
	@n=$$(ls benchmarks/*_bench.py | wc -l); i=0; for b in benchmarks/*_bench.py; do i=$$((i+1)); \
	  echo "== [$$i/$$n] $$b $(BENCH_FLAGS) (JSON on stdout, progress on stderr)"; \
	  $(BIN)/python $$b $(BENCH_FLAGS) || exit 1; done

clean:
	rm -rf $(VENV) logs/*.mcap logs/*.rrd logs/*.json

# `make constraints`: upgrade. Installs the newest versions pyproject.toml allows into a scratch
# environment, runs the suite there, and only if it passes writes their pins to constraints.txt
# (then commit it; the next `make test` reinstalls .venv with them).
constraints:
	rm -rf .venv-upgrade
	$(PYTHON) -m venv .venv-upgrade
	.venv-upgrade/bin/python -m pip install --quiet --upgrade pip
	.venv-upgrade/bin/python -m pip install --quiet -e '.[test]'
	.venv-upgrade/bin/ruff check . && .venv-upgrade/bin/ruff format --check .
	.venv-upgrade/bin/python -m pytest
	(head -n 3 constraints.txt; .venv-upgrade/bin/python -m pip freeze --exclude-editable | grep -v '^calbench') > constraints.new
	mv constraints.new constraints.txt
	rm -rf .venv-upgrade
	@echo "calbench: constraints.txt upgraded; commit it"
