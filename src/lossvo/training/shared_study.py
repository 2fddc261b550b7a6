"""An Optuna study that several workers share (``hparams_search=k_search`` run by two or more processes
with the same study name and storage), through Hydra's Optuna sweeper.

- :class:`SharedStorage`: the study's RDB storage (SQLite on one machine, MariaDB, MySQL or PostgreSQL
  across machines). Each worker records a heartbeat of the trials it asked for and has not yet told;
  before it asks for a trial, it marks FAIL the study's running trials whose heartbeat is older than the
  grace period (their worker was killed), so that the study goes on without them.
- :class:`TrialSeededTPESampler`: TPE whose draws for trial number k come from a sampler seeded with
  ``SeedSequence([seed, k])``: the storage hands every trial of a study its own number, so no two trials
  draw from the same random stream, whichever worker asks for them and however often a worker restarts.
- :class:`StudyCheck`: a Hydra callback that, before the sweep starts, records the search (directions,
  search space, fixed overrides) in a new study and refuses, in one line with exit status 2, a search that
  differs from the one recorded under the study's name, or a storage that cannot be opened.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from hydra.experimental.callback import Callback
from hydra_plugins.hydra_optuna_sweeper._impl import create_params_from_overrides
from omegaconf import DictConfig, ListConfig, OmegaConf
from optuna.distributions import BaseDistribution, distribution_to_json, json_to_distribution
from optuna.exceptions import DuplicatedStudyError, StorageInternalError
from optuna.samplers import BaseSampler, TPESampler
from optuna.storages import RDBStorage
from optuna.storages._rdb import models
from optuna.study import Study, StudyDirection
from optuna.trial import FrozenTrial, TrialState
from sqlalchemy import func
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError, SQLAlchemyError

from lossvo.console import exit_in_one_line, first_line

log = logging.getLogger("lossvo")

SEARCH_ATTR = "lossvo_search"
"""The study's user attribute holding the search it was created for (:func:`search_of`)."""


class SharedStorage(RDBStorage):
    """Optuna's RDB storage at ``url`` with heartbeats for a study several workers share.

    A trial this process creates gets a heartbeat at once and then every ``heartbeat_interval`` seconds
    (a daemon thread) until it is finished. Before creating a trial, the study's running trials whose last
    heartbeat is more than ``grace_period`` seconds old are marked FAIL: their worker is gone. A worker
    stalled for longer than ``grace_period`` (suspended, cut off from the database) loses its trial the
    same way, so ``grace_period`` is minutes, not seconds.
    """

    def __init__(self, url: str, heartbeat_interval: int = 60, grace_period: int = 600,
                 engine_kwargs: dict[str, Any] | None = None) -> None:  # fmt: skip
        for attempt in range(3):  # workers started together on a new database race to create its tables
            try:
                super().__init__(url, engine_kwargs, heartbeat_interval=heartbeat_interval,
                                 grace_period=grace_period)  # fmt: skip
                break
            except (SQLAlchemyError, StorageInternalError):
                if attempt == 2:
                    raise
                time.sleep(1.0)
        self._mine: set[int] = set()
        self._lock = threading.Lock()
        self._beating: threading.Thread | None = None

    def __repr__(self) -> str:
        return f"{type(self).__name__}({shown_url(self.url)})"

    def _create_new_trial(self, study_id: int, template_trial: FrozenTrial | None = None) -> FrozenTrial:
        # Optuna's create_new_trial and its caching wrapper both create trials through this method.
        for trial_id in self.fail_stale_trials(study_id):
            number = self.get_trial(trial_id).number
            log.warning(f"trial {number} failed: its worker sent no heartbeat for {self.grace_period} s")
        trial = super()._create_new_trial(study_id, template_trial)
        self.record_heartbeat(trial._trial_id)
        with self._lock:
            self._mine.add(trial._trial_id)
            if self._beating is None:
                self._beating = threading.Thread(target=self._beat, name="optuna-heartbeat", daemon=True)
                self._beating.start()
        return trial

    def _get_stale_trial_ids(self, study_id: int) -> list[int]:
        # Optuna 2.10 compares ``timedelta.seconds`` with the grace period: a heartbeat written by another
        # worker just after this one read the database's clock is then a day old. Here: total seconds.
        assert self.grace_period is not None
        session = self.scoped_session()
        try:
            now = session.execute(func.now()).scalar().replace(tzinfo=None)
            beats = (
                session.query(models.TrialModel.trial_id, models.TrialHeartbeatModel.heartbeat)
                .join(
                    models.TrialHeartbeatModel,
                    models.TrialHeartbeatModel.trial_id == models.TrialModel.trial_id,
                )
                .filter(models.TrialModel.study_id == study_id, models.TrialModel.state == TrialState.RUNNING)
                .all()
            )
            session.commit()
        finally:
            session.close()
        return [trial_id for trial_id, beat in beats if (now - beat).total_seconds() > self.grace_period]

    def _beat(self) -> None:
        """Record a heartbeat of this process's unfinished trials every ``heartbeat_interval`` seconds."""
        assert self.heartbeat_interval is not None
        while True:
            time.sleep(self.heartbeat_interval)
            with self._lock:
                mine = sorted(self._mine)
            for trial_id in mine:
                try:
                    if self.get_trial(trial_id).state.is_finished():
                        with self._lock:
                            self._mine.discard(trial_id)
                    else:
                        self.record_heartbeat(trial_id)
                except (SQLAlchemyError, StorageInternalError) as e:  # the next beat tries again
                    log.warning(f"optuna heartbeat of trial id {trial_id}: {e}")


def _seed_of(seed: int | None, number: int) -> int | None:
    """The seed of trial number ``number``'s sampler: ``SeedSequence([seed, number])``'s first word."""
    if seed is None:
        return None
    return int(np.random.SeedSequence([seed, number]).generate_state(1)[0])


class TrialSeededTPESampler(BaseSampler):
    """Optuna's TPE sampler (keyword arguments as :class:`optuna.samplers.TPESampler`'s) whose draws for
    trial number k come from a TPE sampler seeded with ``SeedSequence([seed, k])``: reproducible for a
    trial number, and different for every trial of a study, also across workers and restarts (a worker
    seeded once would repeat its first draws after a restart, and two workers seeded alike would draw the
    same parameters). ``seed=None``: unseeded."""

    def __init__(self, seed: int | None = None, **tpe: Any) -> None:
        self._seed = seed
        self._tpe = tpe
        self._samplers: dict[int, TPESampler] = {}

    def _of(self, trial: FrozenTrial) -> TPESampler:
        if trial.number not in self._samplers:
            self._samplers[trial.number] = TPESampler(seed=_seed_of(self._seed, trial.number), **self._tpe)
        return self._samplers[trial.number]

    def reseed_rng(self) -> None:
        self._seed = None
        self._samplers.clear()

    def infer_relative_search_space(self, study: Study, trial: FrozenTrial) -> dict[str, BaseDistribution]:
        return self._of(trial).infer_relative_search_space(study, trial)

    def sample_relative(self, study: Study, trial: FrozenTrial, search_space: dict[str, BaseDistribution]
                        ) -> dict[str, Any]:  # fmt: skip
        return self._of(trial).sample_relative(study, trial, search_space)

    def sample_independent(self, study: Study, trial: FrozenTrial, param_name: str,
                           param_distribution: BaseDistribution) -> Any:  # fmt: skip
        return self._of(trial).sample_independent(study, trial, param_name, param_distribution)

    def after_trial(self, study: Study, trial: FrozenTrial, state: TrialState,
                    values: Sequence[float] | None) -> None:  # fmt: skip
        self._of(trial).after_trial(study, trial, state, values)
        self._samplers.pop(trial.number, None)


# -- the search a study was created for ------------------------------------------------------------


def shown_url(url: str) -> str:
    """A storage URL with its password hidden (a URL that does not parse as it is)."""
    try:
        return make_url(url).render_as_string(hide_password=True)
    except ArgumentError:
        return url


def storage_url(sweeper: DictConfig) -> str | None:
    """The URL of the sweeper's storage (a URL, or a storage config with ``url``); None: in memory."""
    storage = sweeper.get("storage")
    if storage is None:
        return None
    return str(storage.url if isinstance(storage, DictConfig) else storage)


def directions_of(sweeper: DictConfig) -> list[str]:
    """The sweeper's directions as names (``minimize``, ``maximize``), as the sweeper reads them."""
    given = sweeper.direction
    items = list(given) if isinstance(given, ListConfig) else [given]
    return [str(getattr(item, "name", item)) for item in items]


def search_of(sweeper: DictConfig, task_overrides: Sequence[str]) -> dict[str, Any]:
    """The search a sweep runs, as the sweeper reads it from ``hydra.sweeper.params`` and the command
    line's overrides: its directions, its search space (JSON of each distribution) and its fixed
    overrides."""
    params = [f"{name}={value}" for name, value in (sweeper.get("params") or {}).items()]
    space, fixed = create_params_from_overrides([*params, *task_overrides])
    return {
        "directions": directions_of(sweeper),
        "space": {name: distribution_to_json(d) for name, d in sorted(space.items()) if name not in fixed},
        "fixed": {name: str(value) for name, value in sorted(fixed.items())},
    }


def _space_text(space: dict[str, str], names: Sequence[str]) -> str:
    return ", ".join(f"{name} in {json_to_distribution(space[name])!r}" for name in names) or "nothing"


def difference(recorded: dict[str, Any], wanted: dict[str, Any]) -> str | None:
    """How the search ``wanted`` differs from the search a study ``recorded`` (one line); None: alike."""
    if recorded["directions"] != wanted["directions"]:
        return f"its direction is {', '.join(recorded['directions'])}, not {', '.join(wanted['directions'])}"
    old, new = recorded["space"], wanted["space"]
    if old != new:
        names = sorted(name for name in old.keys() | new.keys() if old.get(name) != new.get(name))
        return (f"it searches {_space_text(old, [n for n in names if n in old])}, "
                f"not {_space_text(new, [n for n in names if n in new])}")  # fmt: skip
    old, new = recorded["fixed"], wanted["fixed"]
    if old != new:
        names = sorted(name for name in old.keys() | new.keys() if old.get(name) != new.get(name))
        shown = [(f"{n}={old[n]}" if n in old else f"no {n}", f"{n}={new[n]}" if n in new else f"no {n}")
                 for n in names]  # fmt: skip
        return f"it runs with {' '.join(o for o, _ in shown)}, not {' '.join(n for _, n in shown)}"
    return None


def check_study(url: str, name: str, wanted: dict[str, Any]) -> None:
    """Record the search ``wanted`` in the study ``name`` at ``url`` (created if new), or raise
    ValueError (one line) where the study was created for another search or the storage cannot be
    opened."""
    try:
        storage = SharedStorage(url)
    except (SQLAlchemyError, StorageInternalError, ImportError) as e:
        raise ValueError(f"hydra.sweeper.storage.url: cannot open {shown_url(url)}: {first_line(e)}") from e
    try:
        try:
            study_id = storage.create_new_study(name)
        except DuplicatedStudyError:
            study_id = storage.get_study_id_from_name(name)
        if all(d == StudyDirection.NOT_SET for d in storage.get_study_directions(study_id)):
            storage.set_study_directions(study_id, [StudyDirection[d.upper()] for d in wanted["directions"]])
        recorded = storage.get_study_user_attrs(study_id).get(SEARCH_ATTR)
        if recorded is None:  # a new study, or one made without this check: its directions are known
            directions = [d.name.lower() for d in storage.get_study_directions(study_id)]
            recorded = {**wanted, "directions": directions}
        why = difference(recorded, wanted)
        if why is None:
            storage.set_study_user_attr(study_id, SEARCH_ATTR, wanted)
    finally:
        storage.engine.dispose()
    if why is not None:
        raise ValueError(f"hydra.sweeper.study_name: the study {name!r} in {shown_url(url)} was created for "
                         f"another search: {why} (choose another study_name or storage)")  # fmt: skip


class StudyCheck(Callback):
    """Hydra callback: before a sweep with a study name and storage starts, :func:`check_study`. A study
    created for another search ends the command in one line with exit status 2 (``LOSSVO_FULL_ERROR=1``:
    its traceback, exit status 1); Hydra turns exceptions of callbacks into warnings, so the exit is
    this callback's."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        sweeper = config.hydra.sweeper
        url, name = storage_url(sweeper), sweeper.get("study_name")
        if url is None or name is None:
            return
        overrides = OmegaConf.to_container(config.hydra.overrides.task)
        assert isinstance(overrides, list)
        try:
            check_study(url, str(name), search_of(sweeper, [str(item) for item in overrides]))
        except ValueError as e:
            exit_in_one_line(e)
