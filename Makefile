PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup test lint demo bench report clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e ".[test]"
	touch $(STAMP)

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

test: lint
	$(PY) -m pytest -q

demo: $(STAMP)
	$(VENV)/bin/panoptic-bench demo --out reports/demo

bench: $(STAMP)
	$(PY) benchmarks/run_all.py

report: $(STAMP)
	$(VENV)/bin/panoptic-bench demo --out reports/synthetic --report-only
	$(VENV)/bin/panoptic-bench demo --real-scans ../shared/data/semantickitti-train --checkpoint synthetic-ensemble --out reports/real-scans --report-only
	$(VENV)/bin/panoptic-bench demo --real-scans ../shared/data/semantickitti --checkpoint synthetic --out reports/real-scans-3 --report-only
	$(VENV)/bin/panoptic-bench demo --real-scans ../shared/data/semantickitti-train --sequences 05,06 --checkpoint semantickitti-cpu-heldout --out reports/real-scans-heldout --report-only
	$(VENV)/bin/panoptic-bench demo --real-scans ../shared/data/semantickitti-train --checkpoint synthetic --out reports/real-scans-55 --report-only
	$(VENV)/bin/panoptic-bench demo --real-scans ../shared/data/semantickitti --no-checkpoint --out reports/real-scans-simulated --report-only

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache
