# lossvo: set-up and everyday commands. `make test` creates the venv on first use.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: venv test test-all lint format bench sweep report clean

venv: $(STAMP)

# torch is pinned and installed first: pip then takes the CPU build lying on this machine's disk,
# instead of resolving an unpinned `torch` to a multi-GB CUDA build. Re-runs when pyproject.toml changes.
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

lint: venv
	$(VENV)/bin/ruff check src tests benchmarks
	$(VENV)/bin/ruff format --check src tests benchmarks

format: venv
	$(VENV)/bin/ruff check --fix src tests benchmarks
	$(VENV)/bin/ruff format src tests benchmarks

test: lint
	$(PY) -m pytest

test-all: lint
	$(PY) -m pytest -m ''

bench: venv
	$(PY) benchmarks/losses.py
	$(PY) benchmarks/data_loading.py

# The study's three-way comparison on the embedded synthetic dataset (rendered on first use), then its
# report (tables, baselines, figures; prints the path of report.md). The three jobs run side by side
# (Hydra's joblib launcher; joblib gives each job cores/3 threads, at least 1): on 2 CPU cores that
# trains ~1.4x faster than one job after another, as a small network uses a second thread poorly.
# The sweep folder is named here, so the report is of this sweep; it is written even when a job failed
# (it lists the failure), and make then exits with the sweep's status.
SWEEP_DIR := outputs/multirun/$(shell date +%Y-%m-%d_%H-%M-%S)
sweep: venv
	$(PY) -m lossvo.train -m loss=euler,quat,chordal hydra/launcher=joblib hydra.launcher.n_jobs=3 \
		hydra.sweep.dir=$(SWEEP_DIR); status=$$?; \
	$(PY) -m lossvo.report $(SWEEP_DIR) || exit $$?; exit $$status

# The report of the newest sweep under outputs/multirun (python -m lossvo.report SWEEP_DIR for another).
report: venv
	$(PY) -m lossvo.report --latest outputs/multirun

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .hypothesis src/*.egg-info
