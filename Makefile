# Bootstrap .venv/ from the pinned lock, then run. `make test` and `make demo` work on a fresh clone.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install test check demo lint bench clean

$(STAMP): requirements.lock pyproject.toml npm/package-lock.json
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -r requirements.lock
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	# the dashboard's Plotly.js (basic bundle); without npm it serves the plotly package's full one
	(command -v npm >/dev/null && npm ci --prefix npm --no-audit --no-fund --loglevel=error) \
		|| echo "no npm: the dashboard loads the full Plotly.js bundle (4.8 MB)" >&2
	touch $(STAMP)

install: $(STAMP)

# every test (what CI and the README run); the 25 slowest are listed, to keep the suite's length in view
test: $(STAMP)
	$(BIN)/ruff check backend tests migrations
	$(BIN)/python -m pytest -n 2 -q --durations=25

# lint and the fast tests (no browser, service processes or long simulations; SQLite only, the
# PostgreSQL variants are make test's): under 3 minutes on 2 cores
check: lint
	$(BIN)/python -m pytest -n 2 -q -m "not slow and not postgresql"

demo: $(STAMP)
	$(BIN)/trainclimate serve --fleet demo --speedup 300 --new-token operator

bench: $(STAMP)
	$(BIN)/trainclimate bench simulator

lint: $(STAMP)
	$(BIN)/ruff check backend tests migrations
	$(BIN)/ruff format --check backend tests migrations
	$(BIN)/mypy

clean:
	rm -rf $(VENV) out build *.egg-info
