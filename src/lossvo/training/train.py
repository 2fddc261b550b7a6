"""Training entry point: ``python -m lossvo.train [overrides]``, sweeps with ``-m``.

Examples::

    python -m lossvo.train                                   # chordal loss, embedded synthetic data
    python -m lossvo.train -m loss=euler,quat,chordal        # the study's three-way comparison
    python -m lossvo.train -m loss=euler,quat,chordal seed=0,1,2 hydra/launcher=joblib
    python -m lossvo.train experiment=paper data.root=/data/kitti trainer=gpu

A run writes to ``outputs/runs/<time>/``, a sweep job to ``outputs/multirun/<time>/<num>_<overrides>/``:
the resolved config (``.hydra/``), ``checkpoints/`` (best on the selection metric, ``val/score`` unless
``selection=loss``, and last), ``metrics.csv``,
and, from the best checkpoint evaluated on the test sequences after fitting
(:func:`lossvo.evaluation.results.evaluate_run`), ``results.json``, ``trajectories/NN.txt`` and
``plots/NN.png``.
``+evaluate=false`` skips that evaluation (it is also skipped for ``trainer.fast_dev_run``, which saves no
checkpoint).
Everything (data, network, loss, loggers, callbacks, trainer) is instantiated before training starts,
so a wrong name or argument fails at once with Hydra's or the class's message.
"""

from __future__ import annotations

import logging
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import hydra
import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.errors import InstantiationException
from hydra.types import RunMode
from hydra.utils import get_class, instantiate
from lightning.fabric.utilities.exceptions import MisconfigurationException
from lightning.pytorch.callbacks import Callback, ModelCheckpoint, ProgressBar
from lightning.pytorch.loggers import CSVLogger, Logger, WandbLogger
from lightning.pytorch.utilities.exceptions import SIGTERMException
from omegaconf import DictConfig, ListConfig, OmegaConf, open_dict

from lossvo import weighting
from lossvo.console import USER_ERRORS, hydra_message, one_line, one_line_errors, raise_if_full_error
from lossvo.models import load_flownet
from lossvo.processes import restore_start_method
from lossvo.training import checkpoints
from lossvo.training.callbacks import MetricsHistory
from lossvo.training.config_checks import check_train_config
from lossvo.training.job_folder import (
    LAST_CHECKPOINT,
    InterruptedRun,
    read_status,
    resume_point,
    write_status,
)
from lossvo.training.module import VOModule
from lossvo.training.selection import SCORE_KEY

if TYPE_CHECKING:
    from lossvo.data.datamodules import KittiDataModule
    from lossvo.losses import PoseLoss

log = logging.getLogger("lossvo")

CONFIG_DIR = str(Path(__file__).resolve().parents[1] / "conf")


def _loss_class(target: str) -> type[PoseLoss]:
    """The loss class a loss config's ``_target_`` names (get_class types any class as ``type``)."""
    return cast("type[PoseLoss]", get_class(target))


def _dim_of(target: str) -> int:
    """Head size of a loss class given its ``_target_`` (the model's ``out_dim`` interpolates this)."""
    return int(_loss_class(target).dim)


def _identity_of(target: str) -> ListConfig:
    """The output of a loss class that decodes to no motion (the model's ``head_bias`` interpolates this)."""
    return ListConfig(_loss_class(target)(k=1.0).identity_output().tolist())


def _matched_k(target: str, c: Any, squared: bool = True) -> float | None:
    """``weighting=matched``'s k for a loss class (``weighting.k`` interpolates this)."""
    return weighting.preset_k(target, "matched", c, squared)


def _paper_k(target: str) -> float | None:
    """``weighting=paper``'s k for a loss class."""
    return weighting.preset_k(target, "paper")


PATH_SAFE = str.maketrans({"/": "_", "=": "-", ",": "+", " ": None, "'": None, '"': None,
                           "[": None, "]": None, "{": None, "}": None, "(": None, ")": None})  # fmt: skip
"""Characters of overrides that Hydra's override grammar does not take unquoted (or that would nest
folders), and what they become in a job folder's name."""


def _path_safe(text: str) -> str:
    """A sweep job's folder name from its overrides, e.g. 'loss-euler+seed-0', that can be pasted
    unquoted into an override (``ckpt_path=.../0_loss-euler+seed-0/checkpoints/best.ckpt``)."""
    return str(text).translate(PATH_SAFE)


def _sqlite_storage(path: str) -> str:
    """An SQLite URL for an Optuna study stored at ``path``, whose folder is created first (the sweep
    folder does not exist yet when the sweeper opens its study)."""
    db = Path(path).expanduser().resolve()
    db.parent.mkdir(parents=True, exist_ok=True)
    return f"sqlite:///{db}"


def register_resolvers() -> None:
    """OmegaConf resolvers used by lossvo's configs (idempotent)."""
    resolvers = (("dim_of", _dim_of), ("identity_of", _identity_of), ("matched_k", _matched_k),
                 ("paper_k", _paper_k), ("path_safe", _path_safe),
                 ("sqlite_storage", _sqlite_storage))  # fmt: skip
    for name, fn in resolvers:
        if not OmegaConf.has_resolver(name):
            OmegaConf.register_new_resolver(name, fn)


register_resolvers()


def _instantiate_group(group: DictConfig | None, name: str) -> list[Any]:
    """Instantiate every entry of a dict-of-configs group (callbacks, logger); each needs a _target_."""
    objects = []
    for key, entry in (group or {}).items():
        if entry is None:  # switched off with `callbacks.key=null`
            continue
        if not isinstance(entry, DictConfig) or "_target_" not in entry:
            raise ValueError(f"{name}.{key!s}: expected a config with a _target_, got {entry!r}")
        objects.append(instantiate(entry))
    return objects


def _container(cfg: DictConfig) -> dict[str, Any]:
    return cast("dict[str, Any]", OmegaConf.to_container(cfg, resolve=True))  # a DictConfig: str keys


def build(cfg: DictConfig) -> tuple[KittiDataModule, VOModule, L.Trainer]:
    """Data, module and trainer from a composed config; nothing is trained yet."""
    if cfg.model.get("flownet"):
        # FlowNetS weights were trained on img/255 - 0.5; the dataset statistics would not match them.
        cfg.data.normalization = "flownet"
    datamodule = instantiate(cfg.data, _convert_="all")
    # The FlowNet file initialises the encoder once, here; it is kept out of the module's
    # hyperparameters so that a checkpoint reloads without that file.
    model_cfg = _container(cfg.model)
    flownet = model_cfg.pop("flownet", None)
    module = VOModule(
        model=model_cfg,
        loss=_container(cfg.loss),
        optimizer=_container(cfg.optimizer),
        scheduler=_container(cfg.scheduler) if cfg.get("scheduler") else None,
        monitor=cfg.selection.monitor if cfg.get("selection") else SCORE_KEY,
    )
    if flownet:
        log.info("FlowNetS initialisation: %s", load_flownet(module.model, flownet).summary())
    _sync_batchnorm_where_supported(cfg)
    callbacks: list[Callback] = _instantiate_group(cfg.get("callbacks"), "callbacks")
    loggers: list[Logger] = _instantiate_group(cfg.get("logger"), "logger")
    trainer = instantiate(
        cfg.trainer,
        plugins=[checkpoints.AtomicCheckpointIO()],
        callbacks=callbacks,
        logger=loggers or False,
        enable_progress_bar=any(isinstance(c, ProgressBar) for c in callbacks),
    )
    return datamodule, module, trainer


def _sync_batchnorm_where_supported(cfg: DictConfig) -> None:
    """Sync batch-norm needs CUDA (torch's SyncBatchNorm); off on CPUs, with a log line."""
    accelerator = str(cfg.trainer.get("accelerator", "auto"))
    on_cpu = accelerator == "cpu" or (accelerator == "auto" and not torch.cuda.is_available())
    if cfg.trainer.get("sync_batchnorm") and on_cpu:
        log.info("trainer.sync_batchnorm: off on CPU (torch's SyncBatchNorm needs CUDA)")
        with open_dict(cfg):
            cfg.trainer.sync_batchnorm = False


def _previous_metrics(trainer: L.Trainer) -> bool:
    """Whether a CSV logger of the trainer would find a metrics.csv of an earlier run in its folder."""
    return any(
        isinstance(logger, CSVLogger) and (Path(logger.log_dir) / "metrics.csv").exists()
        for logger in trainer.loggers
    )


def train(cfg: DictConfig) -> dict[str, float]:
    """Seed, build, fit; returns the final callback metrics (floats)."""
    if cfg.get("seed") is not None:  # seed 0 is a seed
        L.seed_everything(cfg.seed, workers=True)
    datamodule, module, trainer = build(cfg)
    if cfg.get("ckpt_path"):
        epoch, step = checkpoints.check_resume(cfg.ckpt_path, module, dict(datamodule.hparams))
        history = Path(cfg.ckpt_path).parent.parent / "metrics.csv"  # the checkpoint's job folder
        if history.is_file():  # read now: the CSV logger starts the file afresh
            trainer.callbacks.append(MetricsHistory.from_file(history, epoch, step))  # type: ignore[attr-defined]
    resolved = _container(cfg)
    with warnings.catch_warnings():
        restored = any(isinstance(c, MetricsHistory) for c in trainer.callbacks)  # type: ignore[attr-defined]
        if restored or not _previous_metrics(trainer):  # nothing is lost: no warning about deleting it
            warnings.filterwarnings(
                "ignore", message=".*Previous log files in this directory will be deleted"
            )
        for logger in trainer.loggers:
            logger.log_hyperparams(resolved)
    try:
        try:
            with warnings.catch_warnings():
                if cfg.get("ckpt_path"):  # a resumed job's folder holds its earlier checkpoints
                    warnings.filterwarnings("ignore", message="Checkpoint directory .* is not empty")
                trainer.fit(module, datamodule=datamodule, ckpt_path=cfg.get("ckpt_path"))
        except (KeyboardInterrupt, SystemExit) as e:
            raise _interrupted(e, trainer.current_epoch) from None
        metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
        # Lightning sets Trainer.fast_dev_run in its setup (_init_debugging_flags) without declaring it.
        fast_dev_run = trainer.fast_dev_run  # type: ignore[attr-defined]
        if cfg.get("evaluate", True) and not fast_dev_run and trainer.is_global_zero:
            evaluate_after_fit(trainer, module, datamodule)
    finally:
        _finish_wandb(trainer)
    return metrics


def _interrupted(error: BaseException, epoch: int) -> BaseException:
    """Lightning ends a fit on SIGINT with ``sys.exit(1)`` (after a KeyboardInterrupt) and on SIGTERM
    with its ``SIGTERMException``: an :class:`InterruptedRun`; any other exit as it was."""
    if isinstance(error, SIGTERMException):
        return InterruptedRun("SIGTERM", epoch)
    if isinstance(error, KeyboardInterrupt) or isinstance(error.__context__, KeyboardInterrupt):
        return InterruptedRun("SIGINT", epoch)
    return error


def evaluate_after_fit(trainer: L.Trainer, module: VOModule, datamodule: KittiDataModule) -> dict:
    """Evaluate the best checkpoint (the last weights if there is none) on the test sequences, writing
    ``results.json``, ``trajectories/`` and ``plots/`` into the job's output folder."""
    from lossvo.evaluation.results import evaluate_run

    out_dir = (
        Path(HydraConfig.get().runtime.output_dir)
        if HydraConfig.initialized()
        else Path(trainer.default_root_dir)
    )
    best = next((c.best_model_path for c in trainer.checkpoint_callbacks if isinstance(c, ModelCheckpoint)
                 and c.monitor and Path(c.best_model_path or "/nonexistent").is_file()), None)  # fmt: skip
    device = trainer.strategy.root_device  # Lightning moves the module back to the CPU after fit
    if best:
        module = checkpoints.load_module(best)
    else:
        log.warning("no best checkpoint: evaluating the last weights")
    module = module.to(device)
    result = evaluate_run(module, datamodule, out_dir, datamodule.evaluated, checkpoint=best)
    log.info("evaluation of %s on %s: %s", best or "the last weights", ", ".join(datamodule.evaluated),
             out_dir / "results.json")  # fmt: skip
    return result


def _finish_wandb(trainer: L.Trainer) -> None:
    """One W&B run per sweep job: close it so the next job in this process starts a new one."""
    if any(isinstance(logger, WandbLogger) for logger in trainer.loggers):
        import wandb

        wandb.finish()


class JobError(Exception):
    """A user error in one job of a sweep: the job fails (Hydra reports it) and the others go on."""


def _user_error(message: str) -> BaseException:
    """A user error, logged as one line: exit status 2, or in a sweep a :class:`JobError` so that the
    sweep's other jobs (or a search's other trials) still run."""
    log.error("%s", message)
    if HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN:
        return JobError(message)
    return SystemExit(2)


@one_line_errors
@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="train")
def main(cfg: DictConfig) -> float | None:
    """Hydra entry point; returns ``cfg.optimized_metric`` for hyperparameter sweepers.

    A user error (a config value, a data file, a checkpoint that does not fit) ends the job in one log
    line with exit status 2, found before anything is built where the config alone tells
    (:func:`~lossvo.training.config_checks.check_train_config`); ``LOSSVO_FULL_ERROR=1`` shows its
    traceback instead. Any other failure writes ``status.json`` with its error and re-raises: Hydra
    reports it, and a sweep's other jobs (finished or still to come) keep their outputs.
    """
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    try:  # config errors: one line, before anything is built
        if cfg.get("weighting") is not None:
            weighting.check_config(cfg.weighting, cfg.loss)
        check_train_config(cfg)
    except ValueError as e:
        raise_if_full_error()
        raise _user_error(one_line(e)) from None
    log.info("output: %s", out_dir)
    restore_start_method()  # a joblib-launched job: let its loader workers and renderer start
    point = resume_point(out_dir) if cfg.get("resume", True) and not cfg.get("ckpt_path") else None
    if point == "completed":
        log.info("already completed (resume=true): %s", out_dir / "status.json")
        return read_status(out_dir).get("metrics", {}).get(cfg.get("optimized_metric", SCORE_KEY))
    if point is not None:
        log.info("resuming the interrupted run from %s", point)
        with open_dict(cfg):
            cfg.ckpt_path = str(point)
    write_status(out_dir, "running")
    try:
        metrics = train(cfg)
    except InterruptedRun as e:
        last = out_dir / LAST_CHECKPOINT
        write_status(out_dir, "interrupted", signal=e.signal_name, epoch=e.epoch,
                     resume_from=str(last) if last.is_file() else None)  # fmt: skip
        log.error("interrupted by %s during epoch %d; run the same command to resume", e.signal_name, e.epoch)
        raise SystemExit(e.exit_code) from None
    except checkpoints.CheckpointError as e:  # ckpt_path is not a checkpoint this run can resume
        write_status(out_dir, "failed", error=f"CheckpointError: {e}")
        raise_if_full_error()
        raise _user_error(f"ckpt_path: {e}") from None
    except InstantiationException as e:
        cause = e.__cause__
        if not isinstance(cause, (*USER_ERRORS, MisconfigurationException)):
            write_status(out_dir, "failed", error=f"{type(e).__name__}: {e}")
            raise
        write_status(out_dir, "failed", error=f"{type(cause).__name__}: {cause}")
        raise_if_full_error()
        raise _user_error(hydra_message(e)) from None  # a config value or _target_ a constructor refused
    except ValueError as e:  # a value the run cannot use: a data file, a data setting the data refutes
        write_status(out_dir, "failed", error=f"{type(e).__name__}: {e}")
        raise_if_full_error()
        raise _user_error(one_line(e)) from None
    except Exception as e:
        write_status(out_dir, "failed", error=f"{type(e).__name__}: {e}")
        log.error("job failed: %s: %s", type(e).__name__, e)
        raise
    write_status(out_dir, "completed", metrics=metrics)
    return metrics.get(cfg.get("optimized_metric", SCORE_KEY))


if __name__ == "__main__":
    main()
