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

# Taichi's wheel links libX11 for its window, which grassd never opens: where the system has
# no libX11.so.6, sim/no_display.c (a libX11 that answers "no display") goes into venv $(1)
# and grassd.sim.backend loads it before Taichi (docs/operating/bare-machine.md).
define no_display_lib
	@if ! ldconfig -p 2>/dev/null | grep -q 'libX11\.so\.6 '; then \
	    if command -v $(CC) >/dev/null; then install -d '$(1)/lib/grassd' && \
	        $(CC) -std=c11 -shared -fPIC -O2 -Wall -Wextra -Werror -Wl,-soname,libX11.so.6 \
	            -o '$(1)/lib/grassd/libX11.so.6' sim/no_display.c && \
	        echo "no libX11.so.6 on this machine: Taichi gets $(1)/lib/grassd/libX11.so.6 (no display)"; \
	    else echo "no libX11.so.6 and no C compiler: the renderer cannot load (apt-get install libx11-6)"; fi; fi
endef

# The project and its run-time dependencies.
$(VENV)/.grassd-installed: pyproject.toml sim/no_display.c | $(PY)
	$(PY) -m pip install --quiet -e .
	$(call no_display_lib,$(VENV))
	touch $@

# ... plus the test extra (pytest, hypothesis, mitsuba as the reference renderer, ...).
$(VENV)/.grassd-test-installed: pyproject.toml sim/no_display.c | $(PY)
	$(PY) -m pip install --quiet -e '.[test]'
	$(call no_display_lib,$(VENV))
	touch $(VENV)/.grassd-installed $@

setup: $(VENV)/.grassd-installed
setup-test: $(VENV)/.grassd-test-installed

demo: setup
	$(VENV)/bin/grassd demo --firmware $(FIRMWARE)

# The C controller firmware: the posix port always, the Cortex-M7 image and the Teensy 4.1
# sketch's compile when the ARM toolchain is on PATH (firmware/README.md).
firmware:
	$(MAKE) -C firmware posix
	@if command -v arm-none-eabi-gcc >/dev/null; then $(MAKE) -C firmware arm; \
	else echo "firmware: arm-none-eabi-gcc not found, Cortex-M7 image skipped (apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi)"; fi
	@if [ -n "$$($(MAKE) -s --no-print-directory -C firmware have-teensy)" ]; then $(MAKE) -C firmware teensy; \
	else echo "firmware: Teensy 4.1 sketch compile skipped: no arm-none-eabi-g++ with libstdc++ (apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi libstdc++-arm-none-eabi-newlib)"; fi

# pytest workers: most tests wait on daemons, serial lines and servers, so two workers on two
# cores cut the suite from 627 s to 437 s (whole files per worker: module fixtures stay shared).
TEST_WORKERS ?= 2
# The long tier (marker `long`): end-to-end proofs of a minute or more each (the measurement
# recovering a display's variation, a measurement killed, the fit's recovery of two pixels,
# the daemon on arm64, the Dask worker killed, the installed tree, Taichi's GPU arch against
# its CPU arch), about 7 of the suite's 17 minutes on 2 cores (pytest, 2026-11-29: 568 s
# without, 1005 s with). GRASSD_TEST_LONG=1 runs them too; CI (.ci/run) sets it.
GRASSD_TEST_LONG ?=

test: setup-test
	@if command -v cc >/dev/null; then $(MAKE) --no-print-directory firmware; \
	else echo "firmware tier skipped: no C compiler (apt-get install gcc make)"; fi
	$(PY) -m ruff check .
	@[ -n "$(GRASSD_TEST_LONG)" ] || echo "long tier skipped: its end-to-end proofs take \
	about 7 min more on 2 cores; GRASSD_TEST_LONG=1 make test runs them (CI does)"
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile \
	    $(if $(GRASSD_TEST_LONG),,-m "not long") tests

bench: setup-test
	$(PY) -m bench

lint: setup-test
	$(PY) -m ruff check .

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache firmware/build

# ------------------------------------------------------------------------ install as a service
# `sudo make install`: grassd and its dependencies in a venv of their own at $(OPTDIR) (a plain
# `pip install` of a wheel built from a clean copy of this checkout, or of WHEEL=grassd-*.whl;
# no extras unless EXTRAS=journal), $(BINDIR)/grassd linked to it (the unit's ExecStart), the
# unit, the sysusers.d, tmpfiles.d and udev files, and /etc/grassd/grassd.toml from the
# package's default configuration; an existing configuration is never touched. Without DESTDIR
# it then creates the user, groups and directories and reloads systemd and udev; starting the
# service is yours (`systemctl enable --now grassd`). Another `make install` replaces the venv
# whole (restart the service then); `make install-data` redoes all but the venv.
# `make install DESTDIR=/tmp/root` stages the same tree for a package and runs nothing there:
# the venv already names its final paths (to try it in place, run $(OPTDIR)/bin/python of the
# staging tree, not the scripts). `make uninstall` removes all of it but the configuration and
# the state (/var/lib/grassd); the user grassd stays. PYCOMPILE=no leaves out the .pyc files:
# the service cannot write them (ProtectSystem=strict) and would compile its imports each start.
PREFIX       ?= /usr
BINDIR       ?= $(PREFIX)/bin
UNITDIR      ?= $(PREFIX)/lib/systemd/system
SYSUSERSDIR  ?= $(PREFIX)/lib/sysusers.d
TMPFILESDIR  ?= $(PREFIX)/lib/tmpfiles.d
UDEVRULESDIR ?= $(PREFIX)/lib/udev/rules.d
OPTDIR       ?= /opt/grassd
CONFDIR      := /etc/grassd
WHEEL        ?=
EXTRAS       ?=
PYCOMPILE    ?= yes
# the venv is built here, then renamed to $(OPTDIR): an install that fails leaves the old one
STAGE         = $(DESTDIR)$(OPTDIR).new
INSTALLED     = $(DESTDIR)$(UNITDIR)/grassd.service $(DESTDIR)$(SYSUSERSDIR)/grassd.conf \
                $(DESTDIR)$(TMPFILESDIR)/grassd.conf $(DESTDIR)$(UDEVRULESDIR)/60-grassd-serial.rules

.PHONY: install install-venv install-data uninstall
install:
	@$(MAKE) --no-print-directory install-venv
	@$(MAKE) --no-print-directory install-data

install-venv:
	rm -rf '$(STAGE)'
	$(PYTHON) -m venv '$(STAGE)'
	@set -e; wheel='$(WHEEL)'; tmp=$$(mktemp -d); trap 'rm -rf "$$tmp"' EXIT; \
	if [ -z "$$wheel" ]; then \
	    echo "building the wheel from a clean copy of $(CURDIR)"; mkdir "$$tmp/src"; \
	    tar -C '$(CURDIR)' --exclude-vcs --exclude=./.venv --exclude=./build --exclude=./dist \
	        --exclude='*.egg-info' --exclude=__pycache__ --exclude=./firmware/build \
	        --exclude=./.hypothesis --exclude=./.pytest_cache --exclude=./.ruff_cache -cf - . \
	        | tar -C "$$tmp/src" -xf -; \
	    '$(STAGE)/bin/pip' wheel --quiet --no-deps -w "$$tmp/dist" "$$tmp/src"; \
	    wheel=$$(echo "$$tmp"/dist/grassd-*.whl); \
	fi; \
	echo "pip install $$wheel$(if $(EXTRAS),[$(EXTRAS)]) into $(OPTDIR)"; \
	'$(STAGE)/bin/pip' install --quiet --no-compile "$$wheel$(if $(EXTRAS),[$(EXTRAS)])"
	$(call no_display_lib,$(STAGE))
	@# the scripts and pyvenv.cfg name the venv's final path; the .pyc files too (tracebacks)
	grep -lI -F -- '$(STAGE)' '$(STAGE)'/bin/* '$(STAGE)/pyvenv.cfg' \
	    | xargs -r sed -i 's|$(STAGE)|$(OPTDIR)|g'
	if [ '$(PYCOMPILE)' != no ]; then '$(STAGE)/bin/python' -m compileall -q -j0 \
	    -s '$(STAGE)' -p '$(OPTDIR)' '$(STAGE)/lib' >/dev/null || true; fi
	rm -rf '$(DESTDIR)$(OPTDIR)'
	mv '$(STAGE)' '$(DESTDIR)$(OPTDIR)'

install-data:
	install -d '$(DESTDIR)$(BINDIR)' '$(DESTDIR)$(UNITDIR)' '$(DESTDIR)$(SYSUSERSDIR)' \
	    '$(DESTDIR)$(TMPFILESDIR)' '$(DESTDIR)$(UDEVRULESDIR)'
	ln -sfn '$(OPTDIR)/bin/grassd' '$(DESTDIR)$(BINDIR)/grassd'
	sed 's|/usr/bin/grassd|$(BINDIR)/grassd|' systemd/grassd.service \
	    > '$(DESTDIR)$(UNITDIR)/grassd.service'
	chmod 0644 '$(DESTDIR)$(UNITDIR)/grassd.service'
	install -m 0644 systemd/grassd.sysusers.conf '$(DESTDIR)$(SYSUSERSDIR)/grassd.conf'
	install -m 0644 systemd/grassd.tmpfiles.conf '$(DESTDIR)$(TMPFILESDIR)/grassd.conf'
	install -m 0644 systemd/60-grassd-serial.rules '$(DESTDIR)$(UDEVRULESDIR)/'
	@set -e; conf='$(DESTDIR)$(CONFDIR)/grassd.toml'; new=; \
	if [ -e "$$conf" ]; then echo "kept the existing $(CONFDIR)/grassd.toml"; else \
	    [ -d '$(DESTDIR)$(CONFDIR)' ] || install -d -m 0750 '$(DESTDIR)$(CONFDIR)'; \
	    '$(DESTDIR)$(OPTDIR)/bin/python' -I -c 'import importlib.resources as r, sys; \
	        sys.stdout.write(r.files("grassd.daemon.core.config").joinpath("default.toml").read_text())' \
	        > "$$conf.tmp"; \
	    chmod 0640 "$$conf.tmp"; mv "$$conf.tmp" "$$conf"; new=1; \
	    echo "installed $(CONFDIR)/grassd.toml (the default configuration: edit it)"; \
	fi; \
	if [ -z '$(DESTDIR)' ]; then \
	    if command -v systemd-sysusers >/dev/null; then \
	        systemd-sysusers '$(SYSUSERSDIR)/grassd.conf'; fi; \
	    if command -v systemd-tmpfiles >/dev/null; then \
	        systemd-tmpfiles --create '$(TMPFILESDIR)/grassd.conf' || true; fi; \
	    if [ -n "$$new" ] && getent group grassd >/dev/null; then chgrp grassd "$$conf"; fi; \
	    if [ -d /run/systemd/system ]; then systemctl daemon-reload; fi; \
	    if command -v udevadm >/dev/null; then udevadm control --reload || true; \
	        udevadm trigger --subsystem-match=tty --action=change || true; fi; \
	    echo "next: grassd check-config, then systemctl enable --now grassd (or restart it)"; \
	fi

uninstall:
	@if [ -z '$(DESTDIR)' ] && [ -d /run/systemd/system ]; then \
	    systemctl disable --now grassd.service 2>/dev/null || true; fi
	rm -rf '$(DESTDIR)$(OPTDIR)' '$(STAGE)'
	@# the link only when it is ours (not another package's grassd)
	if [ "$$(readlink '$(DESTDIR)$(BINDIR)/grassd')" = '$(OPTDIR)/bin/grassd' ]; then \
	    rm -f '$(DESTDIR)$(BINDIR)/grassd'; fi
	rm -f $(foreach f,$(INSTALLED),'$(f)')
	@if [ -z '$(DESTDIR)' ]; then \
	    if [ -d /run/systemd/system ]; then systemctl daemon-reload; fi; \
	    if command -v udevadm >/dev/null; then udevadm control --reload || true; fi; fi
	@echo "kept $(CONFDIR) (the configuration) and /var/lib/grassd (the state)"
