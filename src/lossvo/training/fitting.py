"""A training run from a composed config: build everything (before the run claims its folder, so that a
mistake leaves no run behind), fit, then evaluate the best checkpoint on the test sequences.
"""

from __future__ import annotations

import logging
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import lightning as L
import torch
from hydra.utils import instantiate
from lightning.pytorch.callbacks import Callback, ModelCheckpoint, ProgressBar
from lightning.pytorch.loggers import Logger, WandbLogger
from omegaconf import DictConfig, open_dict

from lossvo.console import UserError, one_line
from lossvo.evaluation.checkpoints import load_network
from lossvo.evaluation.job_folder import RESULTS
from lossvo.evaluation.results import evaluate_run
from lossvo.models import load_flownet
from lossvo.training import checkpoints, slurm
from lossvo.training.config_checks import instantiate_checked, resolved_config
from lossvo.training.lifecycle import Run
from lossvo.training.loggers import continue_history
from lossvo.training.module import VOModule
from lossvo.training.selection import SCORE_KEY
from lossvo.training.stopping import SIGNALS, InterruptedRun

if TYPE_CHECKING:
    from lossvo.data.datamodules import VODataModule

log = logging.getLogger("lossvo")


def _instantiate_group(group: DictConfig | None, name: str) -> list[Any]:
    """Every entry of a dict-of-configs group (callbacks, logger) built; a null entry or result left out."""
    objects = []
    for key, entry in (group or {}).items():
        if entry is None:
            continue
        if not isinstance(entry, DictConfig) or "_target_" not in entry:
            raise UserError(f"{name}.{key!s}: expected a config with a _target_, got {entry!r}")
        built = instantiate(entry)
        if built is not None:
            objects.append(built)
    return objects


def _load_flownet(module: VOModule, path: str) -> None:
    """FlowNetS weights into the encoder; any problem with the file is one line naming the key."""
    try:
        report = load_flownet(module.model, path)
    except (OSError, UserError) as e:
        raise UserError(f"model.flownet: {one_line(e)}") from None
    log.info("FlowNetS initialisation: %s", report.summary())


def build(cfg: DictConfig) -> tuple[VODataModule, VOModule, L.Trainer]:
    """Data (set up for fitting), module and trainer from a composed config; nothing is trained yet."""
    if cfg.model.get("flownet"):
        # FlowNetS weights were trained on img/255 - 0.5; the dataset statistics would not match them.
        cfg.data.frames.normalization = "flownet"
    datamodule = instantiate(cfg.data, _convert_="all")
    # The FlowNet file initialises the encoder here, kept out of the hyperparameters: checkpoints need none.
    model_cfg = resolved_config(cfg.model)
    flownet = model_cfg.pop("flownet", None)
    module = VOModule(
        model=model_cfg,
        loss=resolved_config(cfg.loss),
        optimizer=resolved_config(cfg.optimizer),
        scheduler=resolved_config(cfg.scheduler) if cfg.get("scheduler") else None,
        monitor=cfg.selection.monitor if cfg.get("selection") else SCORE_KEY,
        compile=cfg.get("compile", False),
    )
    if flownet:
        _load_flownet(module, flownet)
    _sync_batchnorm_where_supported(cfg)
    callbacks: list[Callback] = _instantiate_group(cfg.get("callbacks"), "callbacks")
    loggers: list[Logger] = _instantiate_group(cfg.get("logger"), "logger")
    trainer: L.Trainer = instantiate_checked(
        cfg.trainer,
        "trainer",
        plugins=[checkpoints.AtomicCheckpointIO(), *slurm.lightning_environment()],
        callbacks=callbacks,
        logger=loggers or False,
        enable_progress_bar=any(isinstance(c, ProgressBar) for c in callbacks),
    )
    datamodule.setup("fit")  # reads the data and builds the cache: data errors now, before the run starts
    return datamodule, module, trainer


def _sync_batchnorm_where_supported(cfg: DictConfig) -> None:
    """Sync batch-norm needs CUDA (torch's SyncBatchNorm); off on CPUs, with a log line."""
    accelerator = str(cfg.trainer.get("accelerator", "auto"))
    on_cpu = accelerator == "cpu" or (accelerator == "auto" and not torch.cuda.is_available())
    if cfg.trainer.get("sync_batchnorm") and on_cpu:
        log.info("trainer.sync_batchnorm: off on CPU (torch's SyncBatchNorm needs CUDA)")
        with open_dict(cfg):
            cfg.trainer.sync_batchnorm = False


def train(cfg: DictConfig, run: Run) -> dict[str, float]:
    """Seed, build, start the run, fit, evaluate the best checkpoint; returns the final callback metrics."""
    if cfg.get("threads") is not None:
        torch.set_num_threads(cfg.threads)
    if cfg.get("seed") is not None:  # seed 0 is a seed
        L.seed_everything(cfg.seed, workers=True, verbose=False)
    datamodule, module, trainer = build(cfg)
    ckpt_path = cfg.get("ckpt_path") or run.resume_from
    epoch, step = -1, 0
    if ckpt_path:
        try:
            epoch, step = checkpoints.check_resume(ckpt_path, module, datamodule.description())
        except checkpoints.CheckpointError as e:
            key = "ckpt_path" if cfg.get("ckpt_path") else "resume"
            raise checkpoints.CheckpointError(f"{key}: {e}") from None
    resumed = _resume_point(trainer, str(ckpt_path), epoch, step) if ckpt_path else None
    run.start(resumed, threads=torch.get_num_threads())
    log.info("%s: %s%s", run.label, run.out_dir, f" (resuming from {ckpt_path})" if ckpt_path else "")
    continue_history(run.out_dir, Path(ckpt_path).parent.parent if ckpt_path else run.out_dir, epoch, step)
    for logger in trainer.loggers:
        logger.log_hyperparams(resolved_config(cfg))
    try:
        try:
            with warnings.catch_warnings():
                # a resumed run's folder holds its earlier checkpoints, by design
                warnings.filterwarnings("ignore", message="Checkpoint directory .* is not empty")
                trainer.fit(module, datamodule=datamodule, ckpt_path=ckpt_path)
        except (KeyboardInterrupt, SystemExit, InterruptedRun) as e:
            raise SIGNALS.stop(e, trainer.current_epoch + 1) from None
        # Lightning sets Trainer.fast_dev_run in its setup without declaring it.
        fast_dev_run = trainer.fast_dev_run  # type: ignore[attr-defined]
        if cfg.get("evaluate", True) and not fast_dev_run and trainer.is_global_zero:
            mirror = bool(cfg.get("mirror_average", True))
            try:
                evaluate_after_fit(trainer, module, datamodule, run.out_dir, mirror)
            except (KeyboardInterrupt, InterruptedRun) as e:
                raise SIGNALS.stop(e) from None
        return {key: float(value) for key, value in trainer.callback_metrics.items()}
    finally:
        if any(isinstance(logger, WandbLogger) for logger in trainer.loggers):
            import wandb  # one W&B run per sweep job: the next job in this process starts a new one

            wandb.finish()


def _resume_point(trainer: L.Trainer, source: str, epoch: int, step: int) -> dict[str, Any]:
    """Where a run continues a checkpoint of ``epoch`` (0-based) at global ``step``: ``{"epoch": N}`` (from
    1), or ``{"stage": "evaluation"}`` when the checkpoint ends the training."""
    max_epochs, max_steps = trainer.max_epochs, trainer.max_steps
    trained = (max_epochs is not None and 0 <= max_epochs <= epoch + 1) or 0 <= max_steps <= step
    return {"stage": "evaluation", "source": source} if trained else {"epoch": epoch + 2, "source": source}


def evaluate_after_fit(
    trainer: L.Trainer,
    module: VOModule,
    datamodule: VODataModule,
    out_dir: Path,
    mirror_average: bool = True,
) -> None:
    """Evaluate the best checkpoint (else the last weights) on the test sequences into ``out_dir``."""
    monitored = [c for c in trainer.checkpoint_callbacks if isinstance(c, ModelCheckpoint) and c.monitor]
    best = next(
        (c.best_model_path for c in monitored if c.best_model_path and Path(c.best_model_path).is_file()),
        None,
    )
    device = trainer.strategy.root_device  # Lightning moves the module back to the CPU after fit
    network: torch.nn.Module = load_network(best, device) if best else module.to(device)
    if not best:
        log.warning("no best checkpoint: evaluating the last weights")
    evaluate_run(
        network,
        datamodule,
        out_dir,
        datamodule.evaluated,
        checkpoint=best,
        threads=torch.get_num_threads(),
        mirror_average=mirror_average,
    )
    log.info(
        "evaluation of %s on %s: %s",
        best or "the last weights",
        ", ".join(datamodule.evaluated),
        out_dir / RESULTS,
    )
