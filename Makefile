# Two commands do everything: `make play` and `make test`. Each sets up .venv first.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: play test bench setup browser services clean

setup: $(STAMP)

# Re-run when the package metadata changes. torch is pinned to the CPU build first
# ("torch==2.13.0"), so that the package's "torch>=2.2" is already met and nothing pulls CUDA.
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q "torch==2.13.0"
	$(PY) -m pip install -q -e ".[dev]"
	@echo "compiling the env step (numba, cached for later runs)"
	$(PY) -c "import numpy as np; from colorgrid.env import BatchEnv; e = BatchEnv(num_envs=1, seed=0); e.reset(); e.step(np.zeros((1, 2), dtype=np.int64))"
	touch $(STAMP)

# Browser tests drive Debian's chromium through playwright (no browser download).
browser:
	@command -v chromium >/dev/null 2>&1 || { \
	  echo "installing Debian chromium for the browser tests"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; }

# The study tests start a PostgreSQL cluster of their own (tests/pg.py) with Debian's initdb and pg_ctl, which
# live in /usr/lib/postgresql/<version>/bin, not on PATH; haproxy puts several play servers behind one address.
services:
	@missing=""; \
	{ { command -v initdb && command -v pg_ctl; } || \
	  ls /usr/lib/postgresql/*/bin/initdb /usr/lib/postgresql/*/bin/pg_ctl; } >/dev/null 2>&1 || missing="postgresql"; \
	command -v haproxy >/dev/null 2>&1 || missing="$${missing:+$$missing }haproxy"; \
	[ -z "$$missing" ] || { \
	  echo "installing Debian's $$missing for the tests"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; }

play: $(STAMP)
	$(VENV)/bin/colorgrid play

# Three tests at a time (pytest-xdist), file by file, the longest files first; the files that start a Ray run one
# after another on one worker (tests/scheduling.py): most of the suite waits on servers, browsers and subprocesses,
# not the CPU, so three workers finish sooner than two on a 2-core machine (docs/PERFORMANCE.md, runs 43-46).
# TEST_WORKERS=0 runs them one at a time in this process.
TEST_WORKERS ?= 3
test: $(STAMP) browser services
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadscope

bench: $(STAMP)
	$(PY) bench/bench_env.py

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info
