# `make demo` and `make test` set everything up on a fresh machine (Debian, Python 3.11).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
export GRASSD_CACHE_DIR ?= $(CURDIR)/.venv/grassd-cache

.PHONY: setup setup-test demo test bench lint clean firmware
# simulated controllers of `make demo`: model (Python), posix or qemu (the C firmware)
FIRMWARE ?= model

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip

# The project and its run-time dependencies.
$(VENV)/.grassd-installed: pyproject.toml | $(PY)
	$(PY) -m pip install --quiet -e .
	touch $@

# ... plus the test extra (pytest, hypothesis, mitsuba as the reference renderer, ...).
$(VENV)/.grassd-test-installed: pyproject.toml | $(PY)
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(VENV)/.grassd-installed $@

setup: $(VENV)/.grassd-installed
setup-test: $(VENV)/.grassd-test-installed

demo: setup
	$(VENV)/bin/grassd demo --firmware $(FIRMWARE)

# The C controller firmware: the posix port always, the Cortex-M7 image when the ARM
# toolchain is on PATH (firmware/README.md).
firmware:
	$(MAKE) -C firmware posix
	@if command -v arm-none-eabi-gcc >/dev/null; then $(MAKE) -C firmware arm; \
	else echo "firmware: arm-none-eabi-gcc not found, Cortex-M7 image skipped (apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi)"; fi

# pytest workers: most tests wait on daemons, serial lines and servers, so two workers on two
# cores cut the suite from 627 s to 437 s (whole files per worker: module fixtures stay shared).
TEST_WORKERS ?= 2

test: setup-test
	@if command -v cc >/dev/null; then $(MAKE) --no-print-directory firmware; \
	else echo "firmware tier skipped: no C compiler (apt-get install gcc make)"; fi
	$(PY) -m ruff check .
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile tests

bench: setup-test
	$(PY) -m bench

lint: setup-test
	$(PY) -m ruff check .

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache firmware/build
