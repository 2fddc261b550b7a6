"""lossvo's Optuna sweeper for Hydra: ``hydra/sweeper=lossvo_optuna`` (``hparams_search=k_search``).

Asks the study for ``n_jobs`` trials at a time (ask-and-tell), launches them as Hydra jobs and tells the
study each job's return value (FAIL for a failed job); heartbeats and stale trials:
:mod:`lossvo.training.shared_study`. Writes ``optimization_results.yaml`` in the sweep folder
(docs/sweep.md). Imports Optuna only when a sweep starts: Hydra imports this module on every command.
"""

# No ``from __future__ import annotations``: OmegaConf reads the config dataclasses' annotations as types,
# and Hydra runs this module before it is in sys.modules. Optional and Dict for the same reason.
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Optional  # noqa: UP035

from hydra.core.config_store import ConfigStore
from hydra.core.plugins import Plugins
from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, ListConfig, OmegaConf

from lossvo.console import UserError, exit_in_one_line

log = logging.getLogger(__name__)


@dataclass
class StorageConf:
    """Where the study lives (``url``: an SQLAlchemy URL, a journal file, or None: in memory) and its
    heartbeats: a running trial without one for ``grace_period`` seconds is failed."""

    url: Optional[str] = None  # noqa: UP045
    heartbeat_interval: float = 60.0
    grace_period: float = 600.0


@dataclass
class LossvoOptunaSweeperConf:
    """``hydra.sweeper`` of ``hydra/sweeper=lossvo_optuna``."""

    _target_: str = "hydra_plugins.lossvo_optuna_sweeper.optuna_sweeper.LossvoOptunaSweeper"
    direction: Any = "minimize"  # or a list: minimize, maximize per returned value
    study_name: Optional[str] = None  # noqa: UP045
    storage: StorageConf = field(default_factory=StorageConf)
    n_trials: int = 20  # trials this worker runs
    n_jobs: int = 1  # trials asked for and launched at once
    max_failure_rate: float = 0.0  # of a batch's trials, above which the sweep ends with the error
    sampler: Any = None  # an Optuna sampler's config (_target_); None: TPE
    params: Optional[Dict[str, str]] = None  # noqa: UP006, UP045 - key: search space (choice, interval, tag(log, ...), range)


ConfigStore.instance().store(
    group="hydra/sweeper", name="lossvo_optuna", node=LossvoOptunaSweeperConf, provider="lossvo"
)


def _items(value: Any) -> list[Any]:
    return list(value) if isinstance(value, (list, tuple, ListConfig)) else [value]


def values_of(returned: Any, n: int) -> list[float]:
    """A job's return value as ``n`` numbers (anything ``float`` takes, not a bool), or UserError."""
    items = _items(returned)
    try:
        if len(items) != n or any(isinstance(v, bool) for v in items):
            raise TypeError
        return [float(v) for v in items]
    except (TypeError, ValueError):
        raise UserError(f"the job returned {returned!r}, not {n} number(s)") from None


class LossvoOptunaSweeper(Sweeper):
    """An Optuna search as a Hydra sweep (module docstring); arguments as :class:`LossvoOptunaSweeperConf`."""

    def __init__(
        self,
        direction: Any,
        study_name: Optional[str],  # noqa: UP045
        storage: DictConfig,
        n_trials: int,
        n_jobs: int,
        max_failure_rate: float,
        sampler: Any,
        params: Optional[DictConfig],  # noqa: UP045
    ) -> None:
        self.directions = [str(item).lower() for item in _items(direction)]  # one name, or a list
        self.study_name = study_name
        self.storage = storage
        self.n_trials = n_trials
        self.n_jobs = max(1, n_jobs)
        self.max_failure_rate = max_failure_rate
        self.sampler = sampler
        self.params = {str(k): str(v) for k, v in (params or {}).items()}
        self.job_idx = 0

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        self.config = config
        self.launcher = Plugins.instance().instantiate_launcher(
            hydra_context=hydra_context, task_function=task_function, config=config
        )

    def sweep(self, arguments: list[str]) -> None:
        from lossvo.training import search_space, shared_study

        try:
            space, fixed = search_space.parse([f"{k}={v}" for k, v in self.params.items()] + list(arguments))
            study = self._open(space, fixed)
        except UserError as e:
            exit_in_one_line(e)
        where = "memory" if self.storage.url is None else shared_study.shown_url(str(self.storage.url))
        log.info(
            f"Study {study.study_name} in {where}, sampler {type(study.sampler).__name__}, "
            f"directions {self.directions}"
        )
        # The sweep's marker before any job, as Hydra's basic sweeper writes it: a worker started meanwhile
        # finds the folder lossvo's (lossvo.output_folders) while a job folder has no config yet.
        assert self.config is not None
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        OmegaConf.save(self.config, sweep_dir / "multirun.yaml")
        heartbeats = shared_study.Heartbeats(self.storage.heartbeat_interval)
        left = self.n_trials
        while left > 0:
            shared_study.fail_stale_trials(study, self.storage.grace_period)
            trials = [study.ask(space) for _ in range(min(self.n_jobs, left))]
            for trial in trials:
                heartbeats.add(trial)
            overrides = [tuple(f"{k}={v}" for k, v in {**trial.params, **fixed}.items()) for trial in trials]
            assert self.launcher is not None
            returns = self.launcher.launch(overrides, initial_job_idx=self.job_idx)
            self.job_idx += len(returns)
            told = [self._tell(study, t, ret, heartbeats) for t, ret in zip(trials, returns, strict=True)]
            failed = [e for e in told if e is not None]
            if len(failed) / len(returns) > self.max_failure_rate:
                log.error(
                    f"{len(failed)} of {len(returns)} trials failed (max_failure_rate "
                    f"{self.max_failure_rate})"
                )
                raise failed[0]
            left -= len(trials)
        self._write_results(study, sweep_dir)

    def _open(self, space: dict[str, Any], fixed: dict[str, str]) -> Any:
        """The study, its search checked against the one recorded under its name (UserError)."""
        import optuna

        from lossvo.training import shared_study

        wrong = [d for d in self.directions if d not in ("minimize", "maximize")]
        if wrong:
            raise UserError(f"hydra.sweeper.direction: expected minimize or maximize (or a list of them), "
                            f"got {wrong[0]!r}")  # fmt: skip
        url = None if self.storage.url is None else str(self.storage.url)
        storage = None if url is None else shared_study.open_storage(url)
        if url is not None and storage is not None and self.study_name is not None:
            wanted = shared_study.search_of(self.directions, space, fixed)
            shared_study.check_study(url, self.study_name, wanted, storage)  # creates the study if new
            return optuna.load_study(study_name=self.study_name, storage=storage, sampler=self.sampler)
        directions: Any = self.directions  # checked above: each minimize or maximize
        return optuna.create_study(
            study_name=self.study_name,
            storage=storage,
            sampler=self.sampler,
            directions=directions,
            load_if_exists=True,
        )

    def _tell(self, study: Any, trial: Any, ret: Any, heartbeats: Any) -> Exception | None:
        """Tell the study a launched trial's result; the error of a failed one (told FAIL), else None."""
        from optuna.trial import TrialState

        heartbeats.discard(trial)
        try:
            values = values_of(ret.return_value, len(self.directions))  # a failed job raises its error here
        except Exception as e:
            study.tell(trial, state=TrialState.FAIL, skip_if_finished=True)
            log.warning(f"trial {trial.number} failed: {e}")
            return e
        study.tell(trial, values, skip_if_finished=True)  # failed meanwhile as stale: stays failed
        return None

    def _write_results(self, study: Any, sweep_dir: Path) -> None:
        """``optimization_results.yaml`` in ``sweep_dir``: the best trial, or the Pareto front."""
        from optuna.trial import TrialState

        results: dict[str, Any] = {"name": "optuna"}
        if not study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)):
            log.warning("no trial of the study has completed: no optimization_results.yaml")
            return
        if len(self.directions) == 1:
            best = study.best_trial
            results.update(best_params=best.params, best_value=best.value)
            log.info(f"Best parameters: {best.params}")
            log.info(f"Best value: {best.value}")
        else:
            results["solutions"] = [{"params": t.params, "values": t.values} for t in study.best_trials]
            log.info(f"Number of Pareto solutions: {len(results['solutions'])}")
        OmegaConf.save(OmegaConf.create(results), sweep_dir / "optimization_results.yaml")
