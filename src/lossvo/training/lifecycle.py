"""A run's life in its job folder, in one place: start, resume, skip, stop, fail and finish.

:func:`job` wraps the body of ``python -m lossvo.train``; ``status.json`` is always true. The contract, case
by case: docs/training.md.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Mapping
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, NoReturn

from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from lightning.pytorch.utilities import rank_zero_only
from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from lossvo import folder_lock, output_folders
from lossvo.atomic import write_text_atomic
from lossvo.code_version import code_version
from lossvo.console import (
    JobFailedError,
    UserError,
    full_error,
    one_line,
    remove_refused,
    user_error_line,
    user_message,
)
from lossvo.evaluation import job_folder
from lossvo.evaluation.job_folder import LAST_CHECKPOINT, METRICS, STATUS, Event, Status
from lossvo.machine import machine
from lossvo.training import gpu_jobs
from lossvo.training.config_checks import check_added_keys, check_train_config, dotted_keys
from lossvo.training.slurm import slurm_job
from lossvo.training.stopping import SIGNALS, InterruptedRun

log = logging.getLogger("lossvo")

UNREAD_CHECKPOINT = Path("checkpoints") / "interrupted.ckpt"
"""The weights at a stop, which no run reads (a resume continues from ``last.ckpt``): removed on resuming."""

RUN_KEYS = ("data", "model", "loss", "weighting", "selection", "seed", "optimizer", "threads")
"""Config keys that define a run: a folder whose recorded config differs in one is refused."""

NOT_DEFINING = ("data.frames.cache_dir", "data.loader.num_workers")
"""Keys under :data:`RUN_KEYS` that say where the data lies or how it is loaded (so do the sources' roots)."""


def _first_process() -> bool:
    """Whether this is rank 0, the process that writes and holds the folder."""
    return getattr(rank_zero_only, "rank", 0) == 0


def event(name: str, **details: Any) -> Event:
    """One event of the run's history, now, with the SLURM job if any."""
    now = datetime.now(timezone.utc).isoformat(timespec="seconds")
    return Event(name, now, **details, **slurm_job())


def _defining(cfg: DictConfig | ListConfig) -> dict[str, Any]:
    """The run-defining entries of a config as dotted keys, resolved where they resolve."""
    try:
        container = OmegaConf.to_container(cfg, resolve=True)
    except OmegaConfBaseException:
        container = OmegaConf.to_container(cfg, resolve=False)
    assert isinstance(container, dict)
    leaves = dotted_keys({key: container.get(key) for key in RUN_KEYS})
    return {
        k: v
        for k, v in leaves
        if not isinstance(v, Mapping)
        and not k.startswith(NOT_DEFINING)
        and not (k.startswith("data.sources.") and k.endswith(".root"))
    }


def killed(out_dir: Path) -> Event:
    """The history entry of a process that ended without a word, timed at its files' latest change."""
    files = (out_dir / STATUS, out_dir / METRICS, out_dir / LAST_CHECKPOINT)
    last = max((f.stat().st_mtime for f in files if f.is_file()), default=None)
    when = None if last is None else datetime.fromtimestamp(last, timezone.utc).isoformat(timespec="seconds")
    return Event("killed", when)


def config_drift(recorded: DictConfig | ListConfig, requested: DictConfig) -> list[str]:
    """The run-defining keys whose values differ between two configs."""
    theirs, ours = _defining(recorded), _defining(requested)
    return sorted(k for k in theirs.keys() | ours.keys() if theirs.get(k) != ours.get(k))


def job_label() -> str:
    """``"job 3/9 (loss=quat seed=0)"`` for a sweep's job, ``"run"`` for a single run; the total is Optuna's
    ``n_trials`` or the basic sweeper's expansion of ``multirun.yaml``, where known."""
    if not _sweeping():
        return "run"
    hydra_cfg = HydraConfig.get()
    total = hydra_cfg.sweeper.get("n_trials")
    if not isinstance(total, int):
        try:
            task = list(OmegaConf.load(Path(hydra_cfg.sweep.dir) / "multirun.yaml").hydra.overrides.task)
            total = gpu_jobs.sweep_jobs(task, hydra_cfg.sweeper.get("params"))
        except OSError:  # no multirun.yaml (another launcher): the job number alone
            total = None
    number = f"{hydra_cfg.job.num + 1}/{total}" if total else f"{hydra_cfg.job.num + 1}"
    return f"job {number} ({' '.join(hydra_cfg.overrides.task)})"


def save_config(out_dir: Path, cfg: DictConfig) -> None:
    """``.hydra/``'s files as Hydra writes them, once the run is accepted (``hydra.output_subdir: null``)."""
    hydra_cfg = HydraConfig.get()
    folder = out_dir / ".hydra"
    files = {
        "config.yaml": cfg,
        "hydra.yaml": OmegaConf.create({"hydra": hydra_cfg}),
        "overrides.yaml": hydra_cfg.overrides.task,
    }
    for name, content in files.items():
        write_text_atomic(folder / name, OmegaConf.to_yaml(content))


@dataclass
class Run:
    """A job folder and what this process does in it (``completed``: the status of a completed run, which
    is skipped; ``resume_from``: the ``last.ckpt`` to continue; ``guarded``: whether this process holds
    the folder's lock)."""

    cfg: DictConfig
    out_dir: Path
    label: str
    fresh: bool
    completed: Status | None = None
    resume_from: Path | None = None
    started: bool = False
    guarded: bool = False
    threads: int | None = None
    history: list[Event] = field(default_factory=list)

    def start(self, resumed: Mapping[str, Any] | None = None, threads: int | None = None) -> None:
        """Claim the folder; ``resumed``: where a resumed run continues (``{"epoch": N, ...}``)."""
        self.threads = threads
        name = "started" if resumed is None else "resumed"
        self.history.append(event(name, code=code_version(), machine=machine(), **(resumed or {})))
        if _first_process():
            save_config(self.out_dir, self.cfg)
            if resumed is not None:
                (self.out_dir / UNREAD_CHECKPOINT).unlink(missing_ok=True)
        self.write("running")
        self.started = True

    def write(self, status: str, **extra: Any) -> None:
        """``status.json`` (the first process's), with ``extra`` fields of its ``Status``."""
        if _first_process():
            job_folder.write_status(self.out_dir, Status(status, tuple(self.history), self.threads, **extra))

    def optimized_metric(self) -> float | None:
        """``cfg.optimized_metric``'s value in the folder's ``status.json`` (a completed run's), or None."""
        status = job_folder.read_status(self.out_dir)
        value = (status.metrics or {}).get(self.cfg.get("optimized_metric")) if status else None
        return None if value is None else float(value)


def _accept(run: Run) -> None:
    """Check the config and the folder, and set what the run does. Raises UserError (one line)."""
    cfg, out_dir = run.cfg, run.out_dir
    check_train_config(cfg)
    check_added_keys(cfg, list(HydraConfig.get().overrides.task))
    if run.fresh:
        return
    recorded = out_dir / ".hydra" / "config.yaml"
    if not cfg.get("resume", True):
        raise UserError(f"{out_dir}: holds a run already (resume=false starts afresh only in a new folder: "
                        f"another hydra.run.dir or hydra.sweep.dir)")  # fmt: skip
    if recorded.exists():
        drift = config_drift(OmegaConf.load(recorded), cfg)
        if drift:
            raise UserError(f"{out_dir}: holds a run of another configuration ({', '.join(drift)} differ "
                            f"from {recorded}): use a new folder")  # fmt: skip
    recorded_status = job_folder.read_status(out_dir)
    status = recorded_status.state if recorded_status else None
    run.history = list(recorded_status.history) if recorded_status else []
    if status == "running" and run.guarded:  # the lock was free: the process that said so is gone
        run.history.append(killed(out_dir))
    last = out_dir / LAST_CHECKPOINT
    if status == "completed" and not cfg.get("ckpt_path"):
        run.completed = recorded_status
    elif not cfg.get("ckpt_path") and status in ("interrupted", "running", "failed") and last.is_file():
        run.resume_from = last


def _sweeping() -> bool:
    return HydraConfig.get().mode == RunMode.MULTIRUN


def _end(run: Run, error: Exception, cleanup: Callable[[Run, Exception], None]) -> NoReturn:
    """In an ``except`` block: a user error ends the job in one line (printed before ``cleanup`` may remove
    the folder its log is in) with exit status 2, or in a sweep a :class:`~lossvo.console.JobFailedError`
    so that its other jobs still run; any other (or any with ``LOSSVO_FULL_ERROR=1``) is raised as it is."""
    message = user_message(error, run.out_dir)
    if message is None or full_error():
        cleanup(run, error)
        raise error
    user_error_line(log, f"{run.label}: {message}" if _sweeping() else message)
    cleanup(run, error)
    if _sweeping():
        raise JobFailedError(run.label, message, str(HydraConfig.get().sweep.dir)) from None
    raise SystemExit(2) from None


def _remove_made(run: Run) -> None:
    """What a fresh run made before it was refused (its lock and log) goes, with the folder if it made it."""
    if run.fresh and output_folders.was_empty(run.out_dir):
        made = {folder_lock.LOCK, f"{HydraConfig.get().job.name}.log"}
        remove_refused(run.out_dir, made, keep_folder=output_folders.existed(run.out_dir))


def _failed(run: Run, error: BaseException) -> None:
    """Record a failure in ``status.json`` where it can be written. Before the run started, a sweep job's
    folder records it for the report; a single run's goes (:func:`_remove_made`)."""
    if not run.started and not _sweeping():
        _remove_made(run)
    elif not run.started and run.fresh:
        run.start()
    if not run.started:
        return
    line = user_message(error, run.out_dir)
    message = line if line is not None else f"{type(error).__name__}: {one_line(error)}"
    run.history.append(event("failed", error=message))
    try:
        run.write("failed", error=message)
    except OSError as e:
        log.error("could not write %s: %s", run.out_dir / STATUS, e.strerror or e)


def _interrupted(run: Run, stop: InterruptedRun) -> None:
    """Record a stop in ``status.json`` and say how to resume."""
    if run.started:
        last = run.out_dir / LAST_CHECKPOINT
        stage = "evaluation" if stop.epoch is None else None
        stopped = {"signal": stop.signal_name, "epoch": stop.epoch, "stage": stage}
        run.history.append(event("stopped", **stopped))
        run.write("interrupted", **stopped, resume_from=str(last) if last.is_file() else None)
    log.error("%s: interrupted by %s; run the same command to resume", run.label, stop)  # "SIGINT during ..."


@contextmanager
def _held(run: Run) -> Iterator[None]:
    """The folder's lock, held by the first process; another live process there ends this one in one line."""
    if not _first_process():
        yield
        return
    job = slurm_job()
    details = f", SLURM job {job['slurm_job']}" if job else ""
    with ExitStack() as stack:
        try:
            run.guarded = stack.enter_context(folder_lock.held(run.out_dir, details))
        except folder_lock.FolderInUseError as e:  # another process's folder: nothing of it goes
            _end(run, e, lambda *_: None)
        except OSError as e:  # a full or read-only disk before the run starts
            _end(run, e, lambda run, _: _remove_made(run))
        yield


@contextmanager
def job(cfg: DictConfig) -> Iterator[Run]:
    """The run in this Hydra job's output folder, from its checks to its final ``status.json``; the body
    builds and trains when ``run.completed`` is None, calling :meth:`Run.start` once all is built."""
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    fresh = not (out_dir / ".hydra").exists() and not (out_dir / STATUS).exists()
    run = Run(cfg, out_dir, job_label(), fresh)
    with _held(run):
        try:
            _accept(run)
        except UserError as e:
            _end(run, e, _failed)
        if run.completed is not None:
            log.info("%s: already completed (resume=true): %s%s", run.label, out_dir / STATUS, _longer(run))
            yield run
            return
        try:
            with SIGNALS.installed():
                yield run
                run.history.append(event("completed"))
                run.write("completed", metrics=job_folder.read_metrics(run.out_dir).final())
        except (InterruptedRun, KeyboardInterrupt) as e:
            stop = e if isinstance(e, InterruptedRun) else InterruptedRun("SIGINT")
            _interrupted(run, stop)
            raise SystemExit(stop.exit_code) from None
        except Exception as e:
            if user_message(e, out_dir) is None:
                log.error("%s failed: %s: %s", run.label, type(e).__name__, e)
            _end(run, e, _failed)


def _longer(run: Run) -> str:
    """What to do where a completed run is asked for more epochs than it trained; empty otherwise."""
    recorded = run.out_dir / ".hydra" / "config.yaml"
    if not recorded.is_file():
        return ""
    trained = OmegaConf.select(OmegaConf.load(recorded), "trainer.max_epochs", default=None)
    asked = OmegaConf.select(run.cfg, "trainer.max_epochs", default=None)
    if not (isinstance(trained, int) and isinstance(asked, int) and asked > trained):
        return ""
    return (
        f"; it trained {trained} epochs, and trainer.max_epochs={asked} does not extend it (its schedule "
        "ended there): train the longer run in another folder (hydra.run.dir=... or hydra.sweep.dir=...)"
    )
