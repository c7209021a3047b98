# One-command set-up: each target creates .venv and installs the pinned stack on first use.
VENV ?= .venv
PY := $(VENV)/bin/python
PYTEST_ARGS ?=

.PHONY: install train test bench clean

$(VENV)/.installed: setup.cfg pyproject.toml constraints.txt
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -c constraints.txt -e ".[test,openpi]"
	# openpi-client pins numpy<2 but works with numpy 2: install it without its pins
	$(PY) -m pip install --quiet --no-deps openpi-client==0.1.2
	touch $@

install: $(VENV)/.installed

train: install
	$(VENV)/bin/sb3-memret train recall
	$(VENV)/bin/sb3-memret report runs/recall-seed0

test: install
	$(PY) -m pytest $(PYTEST_ARGS)

bench: install
	$(PY) scripts/bench_env.py

clean:
	rm -rf $(VENV) runs
