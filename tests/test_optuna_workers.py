"""Several Optuna workers on one study (lossvo.training.shared_study, hparams_search=k_search).

The slow tests start real ``python -m lossvo.train -m hparams_search=k_search`` processes on the tiny dataset
with one study name and storage: SQLite in the sweep folder, and MariaDB (the database server of
``cluster/cluster.sh``; skipped where it cannot run). The quick ones drive the storage, the sampler and the
study check through Optuna's API."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import uuid
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path

import optuna
import pytest
from optuna.storages import RDBStorage
from optuna.trial import TrialState

from lossvo.training import shared_study
from lossvo.training.shared_study import SharedStorage, TrialSeededTPESampler

STUDY = "k_search"
TRIALS = 3
"""Trials each worker runs in the two-worker sweeps."""


def tell_all(study: optuna.Study, trial: optuna.Trial) -> None:
    study.tell(trial, trial.suggest_float("k", 5.0, 2000.0, log=True))


# -- quick: the sampler, the storage, the check ----------------------------------------------------


def test_trial_seeded_sampler_draws_reproducibly_and_never_alike_across_workers(tmp_path: Path) -> None:
    """Two workers (two Study objects on one SQLite file) asking in turn: lossvo's sampler gives six
    different trials, the same six again in a new study; Optuna's TPE seeded alike in both workers
    repeats every draw of the other worker."""

    def draws(sampler: Callable[[], optuna.samplers.BaseSampler], name: str) -> list[float]:
        url = f"sqlite:///{tmp_path / 'study.db'}"
        workers = [optuna.create_study(study_name=name, storage=SharedStorage(url), sampler=sampler(),
                                       load_if_exists=True) for _ in range(2)]  # fmt: skip
        for _ in range(3):
            for study in workers:
                tell_all(study, study.ask())
        return [t.params["k"] for t in workers[0].trials]

    ours = draws(lambda: TrialSeededTPESampler(seed=0), "ours")
    assert len(ours) == 6 and len(set(ours)) == 6
    assert draws(lambda: TrialSeededTPESampler(seed=0), "again") == ours
    assert draws(lambda: TrialSeededTPESampler(seed=1), "other seed") != ours
    alike = draws(lambda: optuna.samplers.TPESampler(seed=0), "alike")
    assert len(set(alike)) == 3  # what a seed per worker, not per trial, gives


def test_a_trial_whose_worker_stopped_beating_is_failed_before_the_next_trial(tmp_path: Path) -> None:
    """A trial created without a live worker (one heartbeat, then nothing) is marked FAIL by the next
    worker's ask once the grace period has passed, not before; a heartbeat newer than the database's clock
    (another worker's, written just after it was read) is not stale."""
    url = f"sqlite:///{tmp_path / 'study.db'}"
    dead = optuna.create_study(study_name=STUDY, storage=RDBStorage(url, heartbeat_interval=1))
    orphan = dead.ask()
    dead._storage.record_heartbeat(orphan._trial_id)
    storage = SharedStorage(url, heartbeat_interval=1, grace_period=2)
    live = optuna.create_study(study_name=STUDY, storage=storage, load_if_exists=True)
    tell_all(live, live.ask())
    assert live.trials[0].state == TrialState.RUNNING  # within the grace period
    with storage.engine.begin() as connection:  # the orphan's heartbeat a minute in the future
        connection.exec_driver_sql("UPDATE trial_heartbeats SET heartbeat = datetime('now', '+60 seconds')")
    assert storage._get_stale_trial_ids(live._study_id) == []
    with storage.engine.begin() as connection:
        connection.exec_driver_sql("UPDATE trial_heartbeats SET heartbeat = datetime('now', '-3 seconds')")
    tell_all(live, live.ask())
    states = [t.state for t in live.trials]
    assert states == [TrialState.FAIL, TrialState.COMPLETE, TrialState.COMPLETE]
    # the live worker's own trials kept beating and were not failed
    assert storage._get_stale_trial_ids(live._study_id) == []


def test_a_study_refuses_another_search(tmp_path: Path) -> None:
    """The first check records the search; the same search passes; another direction, search space or
    fixed override is refused in one line that names what differs."""
    url = f"sqlite:///{tmp_path / 'study.db'}"
    search = {"directions": ["minimize"], "space": {"k": optuna.distributions.distribution_to_json(
        optuna.distributions.LogUniformDistribution(5.0, 2000.0))}, "fixed": {"loss": "euler"}}  # fmt: skip
    shared_study.check_study(url, STUDY, search)
    shared_study.check_study(url, STUDY, search)
    k = optuna.distributions.distribution_to_json(optuna.distributions.LogUniformDistribution(1.0, 2000.0))
    searched = "it searches k in LogUniformDistribution(high=2000.0, low=5.0)"
    others = {
        "its direction is minimize, not maximize": {**search, "directions": ["maximize"]},
        f"{searched}, not k in LogUniformDistribution(high=2000.0, low=1.0)": {**search, "space": {"k": k}},
        f"{searched}, not nothing": {**search, "space": {}},
        "it runs with loss=euler, not loss=quat": {**search, "fixed": {"loss": "quat"}},
    }  # fmt: skip
    for why, other in others.items():
        with pytest.raises(ValueError) as error:
            shared_study.check_study(url, STUDY, other)
        assert why in str(error.value) and "\n" not in str(error.value)
        assert str(error.value).startswith(
            f"hydra.sweeper.study_name: the study 'k_search' in {url} was created"
        )


# -- slow: real workers ----------------------------------------------------------------------------


@pytest.fixture(scope="session")
def mariadb_url(cluster: None) -> Iterator[str]:
    """A new MariaDB database for this session (dropped at its end) on the server of the test cluster; its
    SQLAlchemy URL."""
    database = f"lossvo_optuna_test_{uuid.uuid4().hex[:8]}"
    sql = (f"CREATE DATABASE {database}; CREATE USER IF NOT EXISTS 'lossvo'@'localhost' IDENTIFIED BY "
           f"'lossvo'; GRANT ALL ON {database}.* TO 'lossvo'@'localhost';")  # fmt: skip
    subprocess.run(["mariadb", "-uroot", "-e", sql], check=True)
    yield f"mysql+pymysql://lossvo:lossvo@localhost/{database}"
    subprocess.run(["mariadb", "-uroot", "-e", f"DROP DATABASE IF EXISTS {database}"], check=True)


def start_worker(args: list[str], base: Path, log: str) -> subprocess.Popen:
    """``python -m lossvo.train ARGS`` started in ``base`` (its own process group), output to ``base/LOG``."""
    with (base / log).open("w") as out:
        return subprocess.Popen([sys.executable, "-m", "lossvo.train", *args], cwd=base, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)  # fmt: skip


def finished(proc: subprocess.Popen, base: Path, log: str) -> str:
    """A worker's output once it has exited with status 0."""
    status = proc.wait(timeout=600)
    output = (base / log).read_text()
    assert status == 0, output[-3000:]
    return output


def trials_of(url: str) -> list[optuna.trial.FrozenTrial]:
    return optuna.load_study(study_name=STUDY, storage=url).trials


def check_no_duplicates(trials: list[optuna.trial.FrozenTrial]) -> None:
    params = Counter(tuple(sorted(t.params.items())) for t in trials)
    assert max(params.values()) == 1, params
    assert sorted(t.number for t in trials) == list(range(len(trials)))


def search_args(tiny_sweep_args, base: Path, storage: str | None, grace: int = 10) -> list[str]:
    """The k_search over the tiny dataset in ``base/sweep``, one thread a worker, ``storage`` or SQLite,
    heartbeats every second, the grace period ``grace`` seconds."""
    args = ["hparams_search=k_search", f"hydra.sweeper.n_trials={TRIALS}", "threads=1",
            "hydra.sweeper.storage.heartbeat_interval=1",
            f"hydra.sweeper.storage.grace_period={grace}"]  # fmt: skip
    if storage is not None:
        args.append(f"hydra.sweeper.storage.url={storage}")
    return tiny_sweep_args(base, base / "sweep", args)


@pytest.mark.slow
@pytest.mark.parametrize(
    "rdb", [False, pytest.param(True, marks=pytest.mark.cluster)], ids=["sqlite", "mariadb"]
)
def test_two_workers_share_one_study_without_duplicates(rdb: bool, request: pytest.FixtureRequest,
                                                        tiny_sweep_args, tmp_path: Path) -> None:  # fmt: skip
    """Two workers started together with one study name and storage: 2 x TRIALS trials, all complete,
    numbered 0.. without a gap, no parameter set twice, one job folder each, completed."""
    url = request.getfixturevalue("mariadb_url") if rdb else None
    args = search_args(tiny_sweep_args, tmp_path, url)
    workers = [start_worker(args, tmp_path, f"worker{k}.log") for k in range(2)]
    for k, worker in enumerate(workers):
        finished(worker, tmp_path, f"worker{k}.log")
    trials = trials_of(url or f"sqlite:///{tmp_path / 'sweep' / 'optuna.db'}")
    assert len(trials) == 2 * TRIALS and all(t.state == TrialState.COMPLETE for t in trials)
    check_no_duplicates(trials)
    jobs = [p for p in (tmp_path / "sweep").iterdir() if (p / "status.json").is_file()]
    assert len(jobs) == 2 * TRIALS
    assert {json.loads((j / "status.json").read_text())["status"] for j in jobs} == {"completed"}
    assert "best_value" in (tmp_path / "sweep" / "optimization_results.yaml").read_text()


@pytest.mark.slow
def test_a_killed_workers_trial_is_failed_and_the_study_goes_on(tiny_sweep_args, tmp_path: Path) -> None:
    """A worker killed (SIGKILL) while its first trial trains leaves that trial RUNNING; a worker started
    after the grace period marks it FAIL before its own first trial and runs its trials: the study holds
    the failed trial and the new ones, without duplicates, and its result is written."""
    args = search_args(tiny_sweep_args, tmp_path, None, grace=5)
    url = f"sqlite:///{tmp_path / 'sweep' / 'optuna.db'}"
    killed = start_worker(args, tmp_path, "killed.log")
    deadline = time.monotonic() + 300
    while not any(p.is_file() and json.loads(p.read_text()).get("status") == "running"
                  for p in (tmp_path / "sweep").glob("*/status.json")):  # fmt: skip
        assert killed.poll() is None and time.monotonic() < deadline, (tmp_path / "killed.log").read_text()
        time.sleep(0.2)
    os.killpg(killed.pid, signal.SIGKILL)
    killed.wait(timeout=60)
    assert [t.state for t in trials_of(url)] == [TrialState.RUNNING]
    time.sleep(6)  # the grace period (5 s) after the killed worker's last heartbeat
    output = finished(start_worker(args, tmp_path, "next.log"), tmp_path, "next.log")
    assert "trial 0 failed: its worker sent no heartbeat for 5 s" in output
    trials = trials_of(url)
    assert [t.state for t in trials] == [TrialState.FAIL] + [TrialState.COMPLETE] * TRIALS
    check_no_duplicates(trials)
    assert "best_value" in (tmp_path / "sweep" / "optimization_results.yaml").read_text()


@pytest.mark.slow
def test_a_search_under_a_study_name_used_for_another_is_refused_in_one_line(
    tiny_sweep_args, tmp_path: Path
) -> None:
    """A worker searching another space under the study's name (a command-line search-space override) is
    refused before its sweep starts: one line, exit status 2, no trial and no job folder."""
    url = f"sqlite:///{tmp_path / 'study.db'}"
    shared_study.check_study(url, STUDY, {"directions": ["minimize"], "space": {}, "fixed": {}})
    args = search_args(tiny_sweep_args, tmp_path, url)
    result = subprocess.run([sys.executable, "-m", "lossvo.train", *args, "loss=euler"], cwd=tmp_path,
                            capture_output=True, text=True, timeout=300)  # fmt: skip
    assert result.returncode == 2, result.stderr[-3000:]
    lines = [line for line in (result.stdout + result.stderr).splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: hydra.sweeper.study_name: the study 'k_search'"), (
        lines
    )
    assert "it searches nothing, not loss.k in LogUniformDistribution(high=2000.0, low=5.0)" in lines[0]
    assert trials_of(url) == [] and not (tmp_path / "sweep").exists()
