# Two commands for a fresh machine with python3: `make demo` and `make test`.
# Both create .venv on first use and install the project with pinned versions (constraints.txt);
# later runs reuse it (the stamp is rebuilt only when the metadata or pins change).

PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export PIP_DISABLE_PIP_VERSION_CHECK = 1

.PHONY: venv demo test lint bench clean

$(STAMP): setup.cfg pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[dev,render,ray]'
	touch $(STAMP)

venv: $(STAMP)

demo: venv  ## run the main job on its built-in default and print where the results are
	$(BIN)/python tools/demo.py

test: venv  ## lint and format check, then the whole test suite, one pytest worker per CPU
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m pytest -n auto --dist loadfile

bench: venv  ## every benchmark; figures go to benchmarks/results.json
	$(BIN)/python benchmarks/run_all.py

clean:
	rm -rf $(VENV) outputs .pytest_cache .ruff_cache
