# Lucent — the two commands of the README:
#   make demo   set up (a virtual environment in .venv) and render the main job
#   make test   set up and run the test suite
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-$(shell cksum < pyproject.toml | cut -d' ' -f1)

.PHONY: setup demo test lint bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
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
	rm -f $(VENV)/.installed-*
	touch $@

# The main job, on the farm: an embedded Redis, worker processes and the API on a free port;
# the Cornell box submitted, waited for and written out; everything stopped.
demo: $(STAMP)
	mkdir -p out
	$(VENV)/bin/lucent demo examples/cornell_box.json -o out/cornell_box.png -o out/cornell_box.exr
	@echo "open out/cornell_box.png"

test: $(STAMP)
	$(PY) -m pytest $(PYTEST_ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check renderer worker services tests bench

bench: $(STAMP)
	$(PY) bench/cornell_speed.py

clean:
	rm -rf $(VENV) out .pytest_cache
