# The two quickstart commands (README): `make report` and `make test`.
# Both create the virtual environment on first use and install bondc into it.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
FLAGSHIP := models/electro_pneumatic_hybrid.bg

.PHONY: install report test test-fast check clean

$(BIN)/bondc: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	@touch $@

install: $(BIN)/bondc

report: install
	$(BIN)/bondc report $(FLAGSHIP) --motors models/data/motors.csv -o reports/electro_pneumatic_hybrid.html

check: install
	$(BIN)/bondc check models/*.bg

# Python's bytecode written even where PYTHONDONTWRITEBYTECODE says not to: without it pytest
# rewrites the asserts of every test module again in every run (10 s of a worker's collection)
# on every core (pytest-xdist): the whole suite took 17 of CI's 20 minutes one test at a time
test: install
	env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest -n auto

# the inner loop: everything but the tests marked slow
test-fast: install
	env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest -m "not slow" -n auto

clean:
	rm -rf $(VENV) build *.egg-info
