# One-command set-up: each target creates .venv and installs the pinned stack on first use.
VENV ?= .venv
PY := $(VENV)/bin/python
PYTEST_ARGS ?=

.PHONY: install train test bench clean

$(VENV)/.installed: setup.cfg pyproject.toml constraints.txt
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -c constraints.txt -e ".[test]"
	touch $@

install: $(VENV)/.installed

train: install
	$(VENV)/bin/sb3-memret rollout --controller scripted --condition oracle --episodes 10

test: install
	$(PY) -m pytest $(PYTEST_ARGS)

bench: install
	$(PY) scripts/bench_env.py

clean:
	rm -rf $(VENV) runs
