"""Shared test settings and fixtures: deterministic hypothesis runs, the tiny dataset, the shared sweep.

pytest-xdist's controller process loads this file too, before it starts the workers: it imports nothing
heavy (torch, Lightning), so the workers start sooner. Helpers that need those live in ``helpers.py``."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from filelock import FileLock
from hypothesis import HealthCheck, settings

# Property tests draw hypothesis' usual 100 examples; `make test-all` (--hypothesis-profile=thorough) 1,000.
for _name, _examples in (("lossvo", 100), ("thorough", 1000)):
    settings.register_profile(
        _name, deadline=None, derandomize=True, max_examples=_examples,
        suppress_health_check=[HealthCheck.too_slow],
    )  # fmt: skip
settings.load_profile("lossvo")

LONG_FILES = (
    "test_cluster.py", "test_gpu_study_script.py", "test_report_architectures.py", "test_optuna_workers.py",
    "test_sweep.py", "test_resume.py", "test_synthetic.py", "test_bad_input.py", "test_synthetic_layouts.py",
    "test_step.py", "test_gpu_path_script.py", "test_launchers.py", "test_study.py", "test_checkpoints.py",
    "test_fair_comparison.py", "test_distributed.py", "test_cross_dataset.py", "test_routes.py",
    "test_translation_direction.py", "test_lifecycle.py", "test_report.py", "test_packaging.py",
    "test_tum.py", "test_resident.py", "test_axioms.py",
)  # fmt: skip
"""The test files that take longest in the full suite, longest first (their summed test durations with
``-n 2 --durations=0`` on 2 cores): pytest-xdist then hands the longest out first and the workers finish
together on the short ones. The SLURM cluster's lead (its own run, ``make test-cluster``); the shared
sweep's (test_sweep.py) comes well before test_checkpoints.py and test_report.py, which wait for it."""


SLOW_FIXTURES = ("study_sweep", "cluster")
"""Fixtures that make every test using them (directly or through another fixture) ``slow``: the shared sweep
trains four jobs (~1.5 min on 2 cores); the cluster's tests wait on SLURM."""

CLUSTER_FLAG = "LOSSVO_TEST_CLUSTER"
"""With ``LOSSVO_TEST_CLUSTER=1`` the ``cluster`` fixture starts the test cluster itself (as root,
``cluster/cluster.sh up`` installs SLURM, munge and MariaDB with apt-get); without it the cluster's tests
run only where the cluster is already up (``make cluster``) and are skipped elsewhere."""


@pytest.hookimpl(tryfirst=True)  # before ``-m`` deselects by marker
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Tests using a SLOW_FIXTURES fixture marked ``slow``, those using ``cluster`` also ``cluster``; then
    LONG_FILES first, in their order: pytest-xdist hands each worker whole files in collection order, so
    the workers then finish together on the short files."""
    for item in items:
        fixtures = getattr(item, "fixturenames", ())
        if any(name in fixtures for name in SLOW_FIXTURES):
            item.add_marker(pytest.mark.slow)
        if "cluster" in fixtures:
            item.add_marker(pytest.mark.cluster)
    rank = {name: k for k, name in enumerate(LONG_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: each file keeps its order


@pytest.fixture(scope="session", autouse=True)
def threads_per_worker() -> None:
    """Under pytest-xdist, each worker's torch and OpenCV get an equal share of the cores (the library
    default, every core in every worker, oversubscribes them: threads then wait for each other), and so
    do the commands its tests start as subprocesses (``OMP_NUM_THREADS``, which torch reads at start-up;
    a command given its own ``OMP_NUM_THREADS`` or ``threads=`` keeps that)."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers > 1:
        import cv2
        import torch

        share = max(1, (os.cpu_count() or 1) // workers)
        os.environ["OMP_NUM_THREADS"] = str(share)
        torch.set_num_threads(share)
        cv2.setNumThreads(share)


def made_once(factory: pytest.TempPathFactory, name: str, make: Callable[[Path], object]) -> Path:
    """The folder ``name`` in the test session's temporary directory, made by ``make(folder)`` the first
    time it is asked for: once a session, also when pytest-xdist's worker processes share the session
    (a file lock orders them; the others wait for the first one's folder)."""
    base = factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # the session's folder, above each worker's own
    folder, done = base / name, base / f"{name}.done"
    with FileLock(str(base / f"{name}.lock")):
        if not done.is_file():
            shutil.rmtree(folder, ignore_errors=True)
            make(folder)
            done.touch()
    return folder


@pytest.fixture(scope="session")
def tiny_kitti(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny synthetic dataset in the KITTI layout (3 sequences of 10 frames, 64x208), shared by tests.

    Tests that modify a dataset copy it first (see ``kitti_copy``).
    """
    from lossvo.data import synthetic

    def make(root: Path) -> None:
        synthetic.generate(root, ("00", "01", "02"), frames=10, height=64, width=208, progress=False)

    return made_once(tmp_path_factory, "tiny_kitti", make)


@pytest.fixture
def kitti_copy(tiny_kitti, tmp_path):
    """A private, writable copy of ``tiny_kitti``."""
    return shutil.copytree(tiny_kitti, tmp_path / "kitti")


TINY_EXPERIMENT = """# @package _global_
defaults:
  - override /data: kitti
  - override /logger: {logger}
data:
  sources:
    kitti:
      root: {root}
  splits:
    train: ["00", "01"]
    val: ["02"]
    test: {test}
  frames:
    height: 64
    width: 96
    cache_dir: {cache}
  windows:
    seq_len: 3
    batch_size: 4
  loader:
    num_workers: {num_workers}
model:
  width_mult: 0.0625
  hidden_size: 16
trainer:
  max_epochs: 1
{trainer_extra}"""
"""Hydra experiment ``experiment=tiny``: the tiny dataset through the KITTI reader, a very small DeepVO."""


@pytest.fixture(scope="session")
def tiny_sweep_args(tiny_kitti: Path) -> Callable[..., list[str]]:
    """A function writing ``experiment=tiny`` into ``base/conf`` (its cache under ``base``) and returning
    the arguments of ``python -m lossvo.train`` that sweep ARGS over it into ``sweep_dir``."""

    def args_of(base: Path, sweep_dir: Path, args: list[str], test: tuple[str, ...] = ("02",),
                trainer_extra: str = "", logger: str = "csv", num_workers: int = 0) -> list[str]:  # fmt: skip
        conf = base / "conf" / "experiment"
        conf.mkdir(parents=True)
        text = TINY_EXPERIMENT.format(root=tiny_kitti, cache=base / "cache", test=list(test), logger=logger,
                                      num_workers=num_workers, trainer_extra=trainer_extra)  # fmt: skip
        (conf / "tiny.yaml").write_text(text)
        conf_dir = str(base / "conf")
        return ["-m", "--config-dir", conf_dir, "experiment=tiny", f"hydra.sweep.dir={sweep_dir}", *args]

    return args_of


@pytest.fixture(scope="session")
def run_tiny_sweep(tiny_sweep_args: Callable[..., list[str]]) -> Callable[..., subprocess.CompletedProcess]:
    """A function running ``python -m lossvo.train -m experiment=tiny ARGS`` as a subprocess in ``base``
    (config, cache and sweep folders under it), the sweep written to ``sweep_dir``; keywords as
    ``tiny_sweep_args``."""

    def run(base: Path, sweep_dir: Path, args: list[str], **options: object) -> subprocess.CompletedProcess:
        command = [sys.executable, "-m", "lossvo.train", *tiny_sweep_args(base, sweep_dir, args, **options)]
        env = {**os.environ, "WANDB_SILENT": "true", "WANDB_DISABLE_CODE": "true"}
        return subprocess.run(command, capture_output=True, text=True, env=env, cwd=base, timeout=600)

    return run


@pytest.fixture
def run_tiny_sweep_here(tiny_sweep_args: Callable[..., list[str]], monkeypatch: pytest.MonkeyPatch
                        ) -> Callable[..., int]:  # fmt: skip
    """``run_tiny_sweep`` in this process (working directory ``base``): the exit status."""

    from helpers import train_main  # not at the top: the xdist controller loads this file without Lightning

    def run(base: Path, sweep_dir: Path, args: list[str], **options: object) -> int:
        argv = tiny_sweep_args(base, sweep_dir, args, **options)  # makes base
        monkeypatch.chdir(base)
        return train_main(argv, monkeypatch)

    return run


STUDY_LOSSES = ("euler", "quat")
STUDY_SEEDS = (0, 1)
STUDY_SEQUENCES = ("00", "02")
"""The shared sweep's losses, seeds and test sequences."""


@pytest.fixture(scope="session")
def study_sweep(run_tiny_sweep, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One real Hydra multirun trained once a test session, as ``make sweep`` runs it (the joblib
    launcher, two jobs at a time, DataLoader workers inside them), logging to W&B offline: losses x seeds
    on the tiny dataset, STUDY_SEQUENCES as test sequences; the sweep folder. Read-only: tests that
    change a job, or write a report, work on a copy."""

    def make(base: Path) -> None:
        args = [f"loss={','.join(STUDY_LOSSES)}", f"seed={','.join(map(str, STUDY_SEEDS))}",
                "hydra/launcher=joblib", "hydra.launcher.n_jobs=2"]  # fmt: skip
        result = run_tiny_sweep(base, base / "multirun" / "sweep", args, test=STUDY_SEQUENCES, logger="wandb",
                                num_workers=1, trainer_extra="  num_sanity_val_steps: 0\n")  # fmt: skip
        assert result.returncode == 0, result.stderr[-3000:]

    return made_once(tmp_path_factory, "study_sweep", make) / "multirun" / "sweep"


@pytest.fixture(scope="session")
def cluster() -> None:
    """The single-node SLURM cluster of ``cluster/cluster.sh`` (slurmctld, slurmd, slurmdbd on MariaDB,
    munge), up. Without ``LOSSVO_TEST_CLUSTER=1`` it is only used where it already runs (``make cluster``;
    skipped elsewhere, with the reason): a plain ``pytest`` installs nothing. With it, ``cluster.sh up``
    installs and starts it (idempotent: daemons already running are kept), and a cluster that cannot be
    installed or started fails the tests: they were asked for."""
    script = Path(__file__).resolve().parents[1] / "cluster" / "cluster.sh"
    if os.environ.get(CLUSTER_FLAG) != "1":
        if subprocess.run(["bash", str(script), "is-up"], capture_output=True, timeout=60).returncode != 0:
            pytest.skip(f"the test cluster is not up: `make cluster` starts it (root), or {CLUSTER_FLAG}=1 "
                        "has the tests start it (`make test-cluster`)")  # fmt: skip
        return
    if os.geteuid() != 0 and shutil.which("sbatch") is None:
        pytest.fail(f"{CLUSTER_FLAG}=1: SLURM is not installed and installing it needs root")
    if shutil.which("sbatch") is None and shutil.which("apt-get") is None:
        pytest.fail(f"{CLUSTER_FLAG}=1: SLURM is not installed and there is no apt-get to install it")
    try:
        up = subprocess.run(["bash", str(script), "up"], capture_output=True, text=True, timeout=900)
    except subprocess.TimeoutExpired as hung:
        pytest.fail(f"cluster/cluster.sh up did not end within {hung.timeout} s: {hung.stderr!r}")
    if up.returncode != 0:
        pytest.fail(f"the SLURM cluster did not start: {up.stderr.strip()}")
