# Two commands for a newcomer (see README.md):
#   make demo   set up a venv, install, run the main job (writes out/)
#   make test   set up a venv, install, run the test suite
# A second run reuses .venv; it reinstalls only when setup.py or package.xml change.

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
OUT    ?= out
PYTEST_ARGS ?=

.PHONY: all venv demo test bench clean

all: test

$(STAMP): setup.py package.xml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "tissue_sim_ros needs Python >= 3.11, found " + sys.version.split()[0])'
	@test -x $(PY) || $(PYTHON) -m venv $(VENV) || { echo "could not create a venv: on Debian/Ubuntu run 'apt-get install python3-venv'"; exit 1; }
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[ros,test]'
	@touch $@

venv: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/tissue-sim demo --out $(OUT)

test: $(STAMP)
	$(PY) -m pytest -q $(PYTEST_ARGS) test

bench: $(STAMP)
	$(VENV)/bin/tissue-sim bench solver --out $(OUT)/bench

clean:
	rm -rf $(VENV) build install log *.egg-info $(OUT)
