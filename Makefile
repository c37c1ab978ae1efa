# The two commands of the README: `make demo` and `make test`.
# Both set up .venv (machine python3, 3.11) when it is missing or stale.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test test-fast lint setup colcon clean browser

setup: $(STAMP) browser

# Debian's chromium and its driver for the dashboard's browser tests (test/dashboard): installed
# when missing and we are root (CI is); otherwise a one-line note. Idempotent, quiet.
browser:
	@if [ ! -x /usr/bin/chromium ] || [ ! -x /usr/bin/chromedriver ]; then \
	  if [ "$$(id -u)" = 0 ]; then \
	    echo 'installing chromium and chromium-driver (apt-get) for the dashboard browser tests'; \
	    apt-get update -qq >/dev/null && \
	    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null; \
	  else \
	    echo 'note: /usr/bin/chromium or /usr/bin/chromedriver missing (apt-get install chromium chromium-driver as root): the dashboard browser tests will fail'; \
	  fi; \
	fi

$(STAMP): requirements.txt requirements-colcon.txt setup.py package.xml examples/heater_kinds/pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -r requirements.txt -r requirements-colcon.txt
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps -e .
	# the example package of user kinds (docs/extending.md; test/examples)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps -e examples/heater_kinds
	@touch $(STAMP)

# Byte-compile the package first: this environment sets PYTHONDONTWRITEBYTECODE, so without
# cached .pyc files every node process would compile ~100 modules again at start-up (0.5 s of
# CPU each). Up-to-date files are skipped; a stale .pyc is ignored by Python (mtime check).
COMPILE := $(BIN)/python -m compileall -q tank_control >/dev/null
# pytest keeps the test modules it rewrote for its assertions in __pycache__ only when bytecode
# may be written: each worker otherwise rewrites all of them at every run (about 6 s of its
# collection's 10; bench/RESULTS.md, "Test suite").
PYTEST_CACHE := PYTHONDONTWRITEBYTECODE=

demo: $(STAMP)
	@$(COMPILE)
	$(BIN)/python -m tank_control.demo

# One worker more than cores (pytest-xdist), a test file to one worker: the DDS tests spend much
# of their time waiting on the graph and the wall clock (3 workers on the 2-core CI machine:
# 10 min 40 s against 12 min with 2, bench/RESULTS.md "Test suite"; every session, so every
# worker, claims a ROS_DOMAIN_ID of its own). TEST_WORKERS=0 runs in one process. The longest
# files go first (test/conftest.py, test/durations.json), so that the workers finish together;
# `make test PYTEST_ARGS=--record-durations` times them anew.
TEST_WORKERS ?= $(shell echo $$(( $$(nproc 2>/dev/null || echo 1) + 1 )))

test: $(STAMP) browser
	@$(COMPILE)
	$(PYTEST_CACHE) $(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder \
		--durations=40 $(PYTEST_ARGS) test

# The edit loop: the tests that need no ROS graph (test/conftest.py, --no-graph) and are not
# marked slow; `make test` still runs everything.
test-fast: $(STAMP)
	@$(COMPILE)
	$(PYTEST_CACHE) $(BIN)/python -m pytest -q -n $(TEST_WORKERS) --no-graph -m 'not slow' --durations=10 test

# The static checks alone, for the edit loop (make test runs them too: test/package/test_static.py).
lint: $(STAMP)
	$(BIN)/python -m ruff check tank_control
	$(BIN)/python -m mypy tank_control

# A colcon workspace build of this package (ament_python), into build/colcon/.
colcon: $(STAMP)
	$(BIN)/colcon --log-base build/colcon/log build --base-paths . \
	  --build-base build/colcon/build --install-base build/colcon/install

clean:
	rm -rf $(VENV) build/ install/ log/ *.egg-info .mypy_cache .ruff_cache
