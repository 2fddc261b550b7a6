"""Several Optuna workers on one study (lossvo.training.shared_study, hparams_search=k_search through
lossvo's sweeper, hydra_plugins.lossvo_optuna_sweeper).

The slow tests start real ``python -m lossvo.train -m hparams_search=k_search`` processes on the tiny dataset
with one study name and storage: SQLite in the sweep folder, a journal file, and MariaDB (the database
server of ``cluster/cluster.sh``; skipped where it cannot run). The quick ones drive the storage, the
heartbeats, the sampler and the study check through Optuna's API."""

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
from optuna.distributions import FloatDistribution, distribution_to_json
from optuna.trial import TrialState

from lossvo.console import UserError
from lossvo.training import shared_study
from lossvo.training.shared_study import HEARTBEAT_ATTR, Heartbeats, TrialSeededTPESampler, open_storage

STUDY = "k_search"
TRIALS = 3
"""Trials each worker runs in the two-worker sweeps."""


def tell_all(study: optuna.Study, trial: optuna.Trial) -> None:
    study.tell(trial, trial.suggest_float("k", 5.0, 2000.0, log=True))


def storage_url(kind: str, folder: Path) -> str:
    """An SQLite URL or a journal file's path in ``folder``."""
    return f"sqlite:///{folder / 'study.db'}" if kind == "sqlite" else str(folder / "study.log")


# -- quick: the sampler, the storage, the heartbeats, the check ------------------------------------


def test_trial_seeded_sampler_draws_reproducibly_and_never_alike_across_workers(tmp_path: Path) -> None:
    """Two workers (two Study objects on one SQLite file) asking in turn: lossvo's sampler gives six
    different trials, the same six again in a new study; Optuna's TPE seeded alike in both workers
    repeats every draw of the other worker."""

    def draws(sampler: Callable[[], optuna.samplers.BaseSampler], name: str) -> list[float]:
        url = f"sqlite:///{tmp_path / 'study.db'}"
        workers = [optuna.create_study(study_name=name, storage=open_storage(url), sampler=sampler(),
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


@pytest.mark.parametrize("kind", ["sqlite", "journal"])
def test_a_trial_whose_worker_stopped_beating_is_failed_after_the_grace_period(kind: str, tmp_path: Path
                                                                              ) -> None:  # fmt: skip
    """A trial whose worker beat once and died is failed by another worker's check once its heartbeat
    is older than the grace period, not before; the live worker's trial, beating every 0.2 s, is not; a
    heartbeat ahead of this clock is not stale; a trial failed once is not failed again."""
    url = storage_url(kind, tmp_path)
    dead = optuna.create_study(study_name=STUDY, storage=open_storage(url))
    orphan = dead.ask()
    Heartbeats(3600.0).add(orphan)  # one beat, the next an hour later: as good as dead
    live = optuna.load_study(study_name=STUDY, storage=open_storage(url))
    mine = live.ask()
    beats = Heartbeats(0.2)
    beats.add(mine)
    assert shared_study.fail_stale_trials(live, grace_period=1.0) == []  # within the grace period
    time.sleep(1.5)
    assert shared_study.fail_stale_trials(live, grace_period=1.0) == [orphan.number]
    assert shared_study.fail_stale_trials(live, grace_period=1.0) == []
    beats.discard(mine)
    ahead = live.ask()
    ahead.set_user_attr(HEARTBEAT_ATTR, time.time() + 60.0)
    time.sleep(1.5)
    assert shared_study.fail_stale_trials(live, grace_period=1.0) == [mine.number]
    trials = optuna.load_study(study_name=STUDY, storage=open_storage(url)).trials
    states = {t.number: t.state for t in trials}
    assert states == {orphan.number: TrialState.FAIL, mine.number: TrialState.FAIL,
                      ahead.number: TrialState.RUNNING}  # fmt: skip


def test_a_storage_that_cannot_be_opened_is_one_line(tmp_path: Path) -> None:
    for url in (f"sqlite:///{tmp_path / 'missing' / 'optuna.db'}", str(tmp_path / "missing" / "optuna.log")):
        with pytest.raises(UserError) as error:
            open_storage(url)
        assert str(error.value).startswith(f"hydra.sweeper.storage.url: cannot open {url}: ")
        assert "\n" not in str(error.value)


def test_a_study_refuses_another_search(tmp_path: Path) -> None:
    """The first check records the search; the same search passes; another direction, search space or
    fixed override is refused in one line that names what differs."""
    url = f"sqlite:///{tmp_path / 'study.db'}"
    search = shared_study.search_of(["minimize"], {"k": FloatDistribution(5.0, 2000.0, log=True)},
                                    {"loss": "euler"})  # fmt: skip
    shared_study.check_study(url, STUDY, search)
    shared_study.check_study(url, STUDY, search)
    k = distribution_to_json(FloatDistribution(1.0, 2000.0, log=True))
    searched = "it searches k in FloatDistribution(high=2000.0, log=True, low=5.0, step=None)"
    others = {
        "its direction is minimize, not maximize": {**search, "directions": ["maximize"]},
        f"{searched}, not k in FloatDistribution(high=2000.0, log=True, low=1.0, step=None)":
            {**search, "space": {"k": k}},
        f"{searched}, not nothing": {**search, "space": {}},
        "it runs with loss=euler, not loss=quat": {**search, "fixed": {"loss": "quat"}},
    }  # fmt: skip
    for why, other in others.items():
        with pytest.raises(UserError) as error:
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
    return optuna.load_study(study_name=STUDY, storage=open_storage(url)).trials


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
@pytest.mark.parametrize("kind", ["sqlite", "journal", pytest.param("mariadb", marks=pytest.mark.cluster)])
def test_two_workers_share_one_study_without_duplicates(kind: str, request: pytest.FixtureRequest,
                                                        tiny_sweep_args, tmp_path: Path) -> None:  # fmt: skip
    """Two workers started together with one study name and storage (SQLite in the sweep folder, a
    journal file, MariaDB): 2 x TRIALS trials, all complete, numbered 0.. without a gap, no parameter set
    twice, one job folder each, completed."""
    urls = {"sqlite": lambda: None, "journal": lambda: str(tmp_path / "optuna.log"),
            "mariadb": lambda: request.getfixturevalue("mariadb_url")}  # fmt: skip
    url = urls[kind]()
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
    assert (tmp_path / "sweep" / "multirun.yaml").is_file()  # the sweep's marker, written before any job


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
    space = "loss.k in FloatDistribution(high=2000.0, log=True, low=5.0, step=None)"
    assert f"it searches nothing, not {space}" in lines[0]
    assert trials_of(url) == [] and not (tmp_path / "sweep").exists()


@pytest.mark.slow
def test_a_bad_search_space_is_refused_in_one_line_naming_the_key(tiny_sweep_args, tmp_path: Path) -> None:
    """A command-line search space that Optuna cannot draw from ends the sweep before any trial: one
    line naming the key, exit status 2, no study and no job folder."""
    args = search_args(tiny_sweep_args, tmp_path, None)
    result = subprocess.run([sys.executable, "-m", "lossvo.train", *args, "loss.k=interval(10, 1)"],
                            cwd=tmp_path, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert result.returncode == 2, result.stderr[-3000:]
    lines = [line for line in (result.stdout + result.stderr).splitlines() if line.strip()]
    assert lines == ["error: loss.k: `low <= high` must hold, but got (low=10.0, high=1.0). "
                     "(in loss.k=interval(10, 1))"]  # fmt: skip
    assert not (tmp_path / "sweep" / "optuna.db").exists()
    assert not [p for p in (tmp_path / "sweep").glob("*") if p.is_dir()]


@pytest.mark.parametrize("direction", ["up", ["minimize", "largest"]])
def test_a_direction_optuna_does_not_know_is_one_line_naming_the_key(direction: object) -> None:
    from omegaconf import OmegaConf

    from hydra_plugins.lossvo_optuna_sweeper.optuna_sweeper import LossvoOptunaSweeper

    sweeper = LossvoOptunaSweeper(direction, None, OmegaConf.create({"url": None}), 1, 1, 0.0, None, None)
    wrong = direction if isinstance(direction, str) else direction[1]
    expected = (
        rf"^hydra\.sweeper\.direction: expected minimize or maximize \(or a list of them\), got '{wrong}'$"
    )
    with pytest.raises(UserError, match=expected):
        sweeper._open({}, {})
