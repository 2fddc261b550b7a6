# lossvo: set-up and everyday commands. `make test` creates the venv on first use.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: venv test test-all test-cluster lint format bench sweep sweep-paper study report clean cluster cluster-down

venv: $(STAMP)

# torch is pinned and installed first: pip then takes the CPU build lying on this machine's disk,
# instead of resolving an unpinned `torch` to a multi-GB CUDA build. Re-runs when pyproject.toml changes.
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

RUFF := $(VENV)/bin/ruff check src tests benchmarks && $(VENV)/bin/ruff format --check src tests benchmarks
MYPY := $(VENV)/bin/mypy

lint: venv
	$(RUFF)
	$(MYPY)

format: venv
	$(VENV)/bin/ruff check --fix src tests benchmarks
	$(VENV)/bin/ruff format src tests benchmarks

# ruff first; then the type checker beside the tests (without its cache, mypy spends ~45 s of one core
# reading torch and Lightning), its report printed after theirs. Fails when either fails.
BESIDE_MYPY = $(RUFF) || exit 1; $(MYPY) > $(VENV)/mypy.log 2>&1 & mypy=$$!; \
	$(PY) -m pytest $(1); tests=$$?; wait $$mypy; typed=$$?; \
	cat $(VENV)/mypy.log; [ $$tests -eq 0 ] && [ $$typed -eq 0 ]

# `make test` (CI: .ci/run) runs every test but the cluster's, the `slow` ones included (the shared sweep,
# launchers, DDP, the wheel, signals, subprocesses, training runs). The quick loop while editing leaves those
# out. Each pytest-xdist worker gives torch and OpenCV, and the commands its tests start (OMP_NUM_THREADS),
# its share of the cores (tests/conftest.py): all of them in every worker oversubscribes.
#   .venv/bin/python -m pytest -m "not slow"
# `make test-cluster` (CI: after `make test`): the tests marked `cluster` (sweeps, requeues, time limits and
# DDP through a real single-node SLURM; an Optuna study on its MariaDB), which start the cluster first
# (LOSSVO_TEST_CLUSTER=1: as root, `cluster/cluster.sh up` installs SLURM, munge and MariaDB with apt-get).
# A plain `pytest` runs them only where the cluster is already up (`make cluster`) and skips them elsewhere.
# `make test-all`: every test with the thorough hypothesis profile (1,000 examples a property, not 100).
test: venv
	$(call BESIDE_MYPY,-m "not cluster")

test-cluster: venv
	LOSSVO_TEST_CLUSTER=1 $(PY) -m pytest -m cluster

test-all: venv
	$(call BESIDE_MYPY,--hypothesis-profile=thorough)

bench: venv
	$(PY) benchmarks/losses.py
	$(PY) benchmarks/data_loading.py
	$(PY) benchmarks/channels_last.py

# The study's comparison on the embedded synthetic dataset (rendered on first use), across architectures:
# DeepVO on frames (deepvo_small) and FlowVO on optical flow and intrinsics (flowvo) x euler, quat and chordal
# x seeds 0, 1, 2, with calibrated weights (weighting=matched) and one loss-independent selection score
# (selection=score), then the sweep's report, grouped by architecture (prints the path of report.md). Two
# jobs run side by side (Hydra's joblib launcher, one thread each): on 2 CPU cores that trains ~1.5x faster
# than one job after another, as a small network uses a second thread poorly. The sweep folder is named here,
# so the report is of this sweep; it is written even when a job failed (it lists the failure), and make then
# exits with the sweep's status. `make sweep-paper`: the study's own setting, the same seeds with its
# weights (weighting=paper) and each loss's own val/loss for selection (selection=loss).
SWEEP_DIR := outputs/multirun/$(shell date +%Y-%m-%d_%H-%M-%S)
SEEDS     ?= 0,1,2
MODELS    ?= deepvo_small,flowvo
SWEEP      = $(PY) -m lossvo.train -m model=$(MODELS) loss=euler,quat,chordal seed=$(SEEDS) hydra/launcher=joblib \
	hydra.launcher.n_jobs=2 hydra.sweep.dir=$(SWEEP_DIR)
REPORT     = status=$$?; $(PY) -m lossvo.report $(SWEEP_DIR) || exit $$?; exit $$status

sweep: venv
	$(SWEEP); $(REPORT)

sweep-paper: venv
	$(SWEEP) weighting=paper selection=loss; $(REPORT)

# The study that can decide its claims: seeds 0-9 x MODELS x euler, quat and chordal (60 jobs), then its report
# (python -m lossvo.study). It first prints its plan and how long it will take, measured here (a few training
# steps of each network); on a GPU (torch.cuda.is_available()) the jobs train with trainer=gpu, as many at
# once as the GPU's free memory and the cores allow; elsewhere two at once on the CPU, as `make sweep`. With
# too few seeds to decide a claim (7 for three losses; `make study SEEDS=0,1,2`) it says so, and runs.
# `python -m lossvo.study --dry-run` prints the plan alone.
# `make study EXPERIMENTS=mix`: the camera arm (experiment=mix) beside the architectures, in the same folder.
EXPERIMENTS ?= none
study: SEEDS = 0,1,2,3,4,5,6,7,8,9
study: venv
	$(PY) -m lossvo.study --seeds $(SEEDS) --models $(MODELS) --experiments $(EXPERIMENTS)

# The report of the newest sweep under outputs/multirun (python -m lossvo.report SWEEP_DIR for another).
report: venv
	$(PY) -m lossvo.report --latest outputs/multirun

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .hypothesis src/*.egg-info

# A single-node SLURM cluster on this machine (root: Debian's slurm-wlm, slurmdbd, munge, MariaDB), which the
# cluster tests use (`make test-cluster` starts it itself); `make cluster-down` stops its daemons.
cluster:
	bash cluster/cluster.sh up

cluster-down:
	bash cluster/cluster.sh down
