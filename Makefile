# Lucent — the two commands of the README:
#   make demo   set up (a virtual environment in .venv, the runtime dependencies) and render the
#               main job on an embedded farm
#   make test   set up (also the test and dev extras, chromium, libllvm19) and run the test suite
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
# One stamp a dependency set, keyed by pyproject.toml: an edit to it reinstalls.
SUM := $(shell cksum < pyproject.toml | cut -d' ' -f1)
RUNTIME := $(VENV)/.installed-runtime-$(SUM)
FULL := $(VENV)/.installed-test-$(SUM)

.PHONY: setup setup-runtime demo test lint bench clean

setup-runtime: $(RUNTIME)
setup: $(FULL)

# What the demo (and a worker node) needs: Lucent and its runtime dependencies, nothing else.
$(RUNTIME): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	rm -f $(VENV)/.installed-runtime-*
	touch $@

# What the tests need on top: the test and dev extras, and Debian's chromium and libLLVM 19.
$(FULL): $(RUNTIME)
	$(PY) -m pip install --quiet -e '.[test,dev]'
	@# The dashboard's browser tests drive Debian's chromium (playwright cannot download one
	@# here); installed when missing, as root with apt-get; never fatal (the tests then skip).
	-@if [ ! -x /usr/bin/chromium ] && command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ]; then \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null 2>&1 || \
		{ apt-get update -qq >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null 2>&1; } || \
		echo "chromium could not be installed: tests/dashboard will skip"; fi
	@# Mitsuba 3's fast llvm_ad_rgb variant (the reference renders) needs libLLVM >= 16; Debian 12's
	@# default LLVM 15 aborts Dr.Jit. Without it the bridge uses scalar_rgb (slower, same images).
	-@if [ ! -e /usr/lib/x86_64-linux-gnu/libLLVM-19.so ] && command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ]; then \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null 2>&1 || \
		{ apt-get update -qq >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null 2>&1; } || \
		echo "libllvm19 could not be installed: Mitsuba references use scalar_rgb"; fi
	rm -f $(VENV)/.installed-test-*
	touch $@

# The main job, on the farm: an embedded Redis, worker processes and the API on a free port;
# the Cornell box submitted, waited for and written out; everything stopped.
demo: $(RUNTIME)
	mkdir -p out
	$(VENV)/bin/lucent demo examples/cornell_box.json -o out/cornell_box.png -o out/cornell_box.exr
	@echo "open out/cornell_box.png"

test: $(FULL)
	$(PY) -m pytest $(PYTEST_ARGS)

lint: $(FULL)
	$(VENV)/bin/ruff check renderer worker services tests bench
	$(VENV)/bin/mypy services worker

bench: $(FULL)
	$(PY) bench/cornell_speed.py

clean:
	rm -rf $(VENV) out .pytest_cache
