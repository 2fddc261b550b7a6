"""An Optuna study that several workers share: its storage, heartbeats of running trials, a per-trial
seeded TPE sampler, and the search a study was created for (docs/sweep.md)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import optuna
from optuna.distributions import BaseDistribution, distribution_to_json, json_to_distribution
from optuna.exceptions import StorageInternalError, UpdateFinishedTrialError
from optuna.samplers import BaseSampler, TPESampler
from optuna.storages import BaseStorage, RDBStorage
from optuna.storages.journal import JournalFileBackend, JournalStorage
from optuna.study import Study, StudyDirection
from optuna.trial import FrozenTrial, TrialState
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError, SQLAlchemyError

from lossvo.console import UserError, first_line

log = logging.getLogger("lossvo")

SEARCH_ATTR = "lossvo_search"
"""The study's user attribute holding the search it was created for (:func:`check_study`)."""

HEARTBEAT_ATTR = "lossvo_heartbeat"
"""The trial's user attribute holding its worker's last heartbeat, in Unix seconds (:class:`Heartbeats`)."""


def shown_url(url: str) -> str:
    """A storage URL with its password hidden (a URL that does not parse, or a path, as it is)."""
    try:
        return make_url(url).render_as_string(hide_password=True)
    except ArgumentError:
        return url


def open_storage(url: str) -> BaseStorage:
    """The RDB storage at an SQLAlchemy ``url``, or the journal file at a path; created where new. UserError
    naming ``hydra.sweeper.storage.url`` where it cannot be opened."""
    try:
        if "://" not in url:
            return JournalStorage(JournalFileBackend(str(Path(url).expanduser())))
        for _ in range(2):  # workers started together on a new database race to create its tables
            try:
                return RDBStorage(url)
            except (SQLAlchemyError, StorageInternalError):
                time.sleep(1.0)
        return RDBStorage(url)
    except (SQLAlchemyError, StorageInternalError, ImportError, OSError) as e:
        raise UserError(f"hydra.sweeper.storage.url: cannot open {shown_url(url)}: {first_line(e)}") from e


class Heartbeats:
    """The heartbeats of a worker's running trials: the time written into each trial's :data:`HEARTBEAT_ATTR`
    when added and every ``interval`` seconds (a daemon thread) until discarded; a failed write is logged."""

    def __init__(self, interval: float) -> None:
        self.interval = interval
        self._trials: dict[int, optuna.Trial] = {}
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None

    def add(self, trial: optuna.Trial) -> None:
        """Beat for ``trial`` now and every ``interval`` seconds until :meth:`discard`."""
        with self._lock:
            self._trials[trial.number] = trial
            self._beat(trial)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="optuna-heartbeat", daemon=True)
                self._thread.start()

    def discard(self, trial: optuna.Trial) -> None:
        """Stop beating for ``trial``: no beat for it is written after this returns."""
        with self._lock:
            self._trials.pop(trial.number, None)

    def _beat(self, trial: optuna.Trial) -> None:
        try:
            trial.set_user_attr(HEARTBEAT_ATTR, time.time())
        except Exception as e:  # storage unreachable, trial failed by another worker: the thread goes on
            log.warning(f"optuna heartbeat of trial {trial.number}: {first_line(e)}")

    def _run(self) -> None:
        while True:
            time.sleep(self.interval)
            with self._lock:
                for trial in self._trials.values():
                    self._beat(trial)


def fail_stale_trials(study: Study, grace_period: float) -> list[int]:
    """Mark FAIL (and return) the running trials whose last heartbeat is over ``grace_period`` s old."""
    now = time.time()
    failed = []
    for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        beat = trial.user_attrs.get(HEARTBEAT_ATTR)
        if beat is None or now - float(beat) <= grace_period:
            continue
        try:
            study.tell(trial.number, state=TrialState.FAIL, skip_if_finished=True)
        except UpdateFinishedTrialError:  # another worker failed it first
            continue
        log.warning(f"trial {trial.number} failed: its worker sent no heartbeat for {grace_period:g} s")
        failed.append(trial.number)
    return failed


class TrialSeededTPESampler(BaseSampler):
    """Optuna's TPE sampler drawing trial number k from one seeded with ``SeedSequence([seed, k])``: the same
    for a trial number, different across the study's trials, workers and restarts (docs/sweep.md)."""

    def __init__(self, seed: int | None = None, **tpe: Any) -> None:
        self._seed = seed
        self._tpe = tpe
        self._samplers: dict[int, TPESampler] = {}

    def _of(self, trial: FrozenTrial) -> TPESampler:
        if trial.number not in self._samplers:
            seed = self._seed
            if seed is not None:  # SeedSequence([seed, k])'s first word
                seed = int(np.random.SeedSequence([seed, trial.number]).generate_state(1)[0])
            self._samplers[trial.number] = TPESampler(seed=seed, **self._tpe)
        return self._samplers[trial.number]

    def reseed_rng(self) -> None:
        self._seed = None
        self._samplers.clear()

    def infer_relative_search_space(self, study: Study, trial: FrozenTrial) -> dict[str, BaseDistribution]:
        return self._of(trial).infer_relative_search_space(study, trial)

    def sample_relative(
        self, study: Study, trial: FrozenTrial, search_space: dict[str, BaseDistribution]
    ) -> dict[str, Any]:
        return self._of(trial).sample_relative(study, trial, search_space)

    def sample_independent(
        self, study: Study, trial: FrozenTrial, param_name: str, param_distribution: BaseDistribution
    ) -> Any:
        return self._of(trial).sample_independent(study, trial, param_name, param_distribution)

    def before_trial(self, study: Study, trial: FrozenTrial) -> None:
        self._of(trial).before_trial(study, trial)

    def after_trial(
        self, study: Study, trial: FrozenTrial, state: TrialState, values: Sequence[float] | None
    ) -> None:
        self._of(trial).after_trial(study, trial, state, values)
        self._samplers.pop(trial.number, None)


def search_of(
    directions: Sequence[str], space: dict[str, BaseDistribution], fixed: dict[str, str]
) -> dict[str, Any]:
    """The search a sweep runs, as a study records it: directions, space (as JSON) and fixed overrides."""
    return {
        "directions": [d.lower() for d in directions],
        "space": {name: distribution_to_json(space[name]) for name in sorted(space)},
        "fixed": {name: fixed[name] for name in sorted(fixed)},
    }


def _space_text(space: dict[str, str], names: Sequence[str]) -> str:
    return ", ".join(f"{name} in {json_to_distribution(space[name])!r}" for name in names) or "nothing"


def difference(recorded: dict[str, Any], wanted: dict[str, Any]) -> str | None:
    """How the search ``wanted`` differs from the search a study ``recorded`` (one line); None: alike."""
    if recorded["directions"] != wanted["directions"]:
        return f"its direction is {', '.join(recorded['directions'])}, not {', '.join(wanted['directions'])}"
    spaces = recorded["space"], wanted["space"]
    names = _changed(*spaces)
    if names:
        shown = [_space_text(d, [n for n in names if n in d]) for d in spaces]
        return f"it searches {shown[0]}, not {shown[1]}"
    fixed = recorded["fixed"], wanted["fixed"]
    names = _changed(*fixed)
    shown = [" ".join(f"{n}={d[n]}" if n in d else f"no {n}" for n in names) for d in fixed]
    return f"it runs with {shown[0]}, not {shown[1]}" if names else None


def _changed(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    return sorted(name for name in old.keys() | new.keys() if old.get(name) != new.get(name))


def check_study(url: str, name: str, wanted: dict[str, Any], storage: BaseStorage | None = None) -> None:
    """Record the search ``wanted`` in the study ``name`` at ``url`` (created if new; through ``storage``
    if given), or raise UserError where it was created for another search."""
    opened = open_storage(url) if storage is None else storage
    try:
        try:
            study = optuna.load_study(study_name=name, storage=opened)
        except KeyError:  # a new study (load_if_exists: another worker may create it first)
            directions = [StudyDirection[d.upper()] for d in wanted["directions"]]
            study = optuna.create_study(
                storage=opened, study_name=name, directions=directions, load_if_exists=True
            )
        recorded = study.user_attrs.get(SEARCH_ATTR)
        if recorded is None:  # a new study, or one made without this check: its directions are known
            recorded = {**wanted, "directions": [d.name.lower() for d in study.directions]}
        why = difference(recorded, wanted)
        if why is None:
            study.set_user_attr(SEARCH_ATTR, wanted)
    finally:
        if storage is None and isinstance(opened, RDBStorage):  # a journal holds no connection open
            opened.engine.dispose()
    if why is not None:
        raise UserError(f"hydra.sweeper.study_name: the study {name!r} in {shown_url(url)} was created for "
                        f"another search: {why} (choose another study_name or storage)")  # fmt: skip
