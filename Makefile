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
