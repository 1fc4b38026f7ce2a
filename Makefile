# The README's commands. Everything runs inside .venv, created on first use.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
# CPU machines get the CPU build of torch; a torch already importable in the venv (e.g. CUDA) is kept.
TORCH_SPEC ?= torch==2.13.0

.PHONY: install demo test test-all lint docs bench bench-ratios clean

$(VENV)/.installed: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -c "import torch" 2>/dev/null || $(PY) -m pip install --quiet "$(TORCH_SPEC)"
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $@

install: $(VENV)/.installed

demo: install  ## the main job: the paper's 2d1level experiment with its defaults
	$(VENV)/bin/rmpfusion-run experiment=2d1level

test: install  ## the fast test suite (pyproject deselects the tests marked slow)
	$(PY) -m pytest

test-all: install  ## every test, the slow ones too: multiruns, kill/resume runs, plugin pip installs (what CI runs)
	$(PY) -m pytest -m 'slow or not slow'

lint: install  ## ruff (lint, then the format check) and mypy over the package; settings in pyproject.toml
	$(VENV)/bin/ruff check rmpfusion tools tests docs/_ext
	$(VENV)/bin/ruff format --check rmpfusion tools tests docs/_ext
	$(VENV)/bin/mypy

docs: install  ## the documentation site, strictly: any warning (a broken link or reference) fails the build
	$(VENV)/bin/sphinx-build -W --keep-going -n -q -b html docs docs/_build/html
	@echo "docs: docs/_build/html/index.html"

bench: install  ## the whole performance table; its ratios checked against, then stored as, this machine kind's baseline
	$(PY) -m tools.bench --check --store-baseline

bench-ratios: install  ## what CI prints: the test-vector tree beside RMPflow's numpy (about a minute), checked, not stored
	$(PY) -m tools.bench --only reference --no-export --check

clean:
	rm -rf $(VENV) .pytest_cache docs/_build docs/reference
