"""The LightningModule: a VO network trained with one pose loss, built from plain config dictionaries (its
hyperparameters, so ``VOModule.load_from_checkpoint(path)`` needs no Hydra). Logging: docs/training.md.
"""

from __future__ import annotations

import logging
import math
import random
from collections.abc import Mapping
from typing import Any

import lightning as L
import numpy as np
import torch
from hydra.utils import instantiate
from torch import Tensor
from torch.optim.lr_scheduler import CosineAnnealingLR

from lossvo import models
from lossvo.data.datamodules import VODataModule
from lossvo.evaluation.checkpoints import Description, describe
from lossvo.evaluation.trajectories import scale_steps
from lossvo.losses import PoseLoss
from lossvo.training.selection import SCORE_KEY, SelectionScore
from lossvo.training.step import (
    StepRecord,
    check_compile,
    compile_mode,
    compiled,
    epoch_means,
    first_non_finite,
    optimizer_options,
    step_row,
)

log = logging.getLogger("lossvo")


def collect_rng() -> dict[str, Any]:
    """The random streams (Python, NumPy, torch CPU and CUDA) as ``weights_only`` checkpoint primitives,
    so that a resumed run draws what an uninterrupted one would (Lightning does not)."""
    version, internal, gauss = random.getstate()
    kind, keys, pos, has_gauss, cached = np.random.get_state(legacy=True)  # noqa: NPY002 (the global stream)
    return {
        "python": [version, list(internal), gauss],
        "numpy": [kind, torch.from_numpy(np.asarray(keys, dtype=np.int64)), pos, has_gauss, cached],
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
    }


def restore_rng(states: dict[str, Any]) -> None:
    """Set the streams to ``states`` (from :func:`collect_rng`); CUDA only where the devices match."""
    version, internal, gauss = states["python"]
    random.setstate((version, tuple(internal), gauss))
    kind, keys, pos, has_gauss, cached = states["numpy"]
    np.random.set_state((kind, np.asarray(keys, dtype=np.uint32), pos, has_gauss, cached))  # noqa: NPY002
    torch.set_rng_state(states["torch"])
    cuda = states.get("cuda") or []
    if cuda and torch.cuda.is_available() and len(cuda) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all(cuda)


def extend_cosine(scheduler: Any, t_max: Any) -> None:
    """Give a restored ``CosineAnnealingLR`` the configured length ``t_max`` (epochs): an N-epoch schedule
    extended to M continues as if it had been M epochs from the start."""
    if not isinstance(scheduler, CosineAnnealingLR) or not isinstance(t_max, int) or t_max == scheduler.T_max:
        return
    old = scheduler.T_max
    scheduler.T_max = t_max
    # The chained update multiplies the current rate, which is eta_min at the end of the old schedule:
    # restart from the closed form at the current epoch.
    lrs = scheduler._get_closed_form_lr()
    for group, lr in zip(scheduler.optimizer.param_groups, lrs, strict=True):
        group["lr"] = lr
    scheduler._last_lr = list(lrs)
    log.info(
        "cosine schedule extended from %d to %d epochs: learning rate %s at epoch %d",
        old,
        t_max,
        ", ".join(f"{lr:.3g}" for lr in lrs),
        scheduler.last_epoch,
    )


class NonFiniteLossError(FloatingPointError):
    """The loss went NaN or infinite; the message names the first such step, its batch and term."""


class VOModule(L.LightningModule):
    """A visual-odometry network and its pose loss.

    Args:
        model: config of the network; it maps the batch entries it names to outputs (B, L-1, loss.dim).
        loss: config of a :class:`lossvo.losses.PoseLoss`.
        optimizer, scheduler: configs of a partial optimiser and (optional) LR scheduler, stepped per epoch.
        monitor: the selection metric (``selection.monitor``): ``val/score`` or ``val/loss``.
        compile: :func:`lossvo.training.step.compile_mode`'s setting; checkpoints omit it.
    """

    def __init__(
        self,
        model: dict[str, Any],
        loss: dict[str, Any],
        optimizer: dict[str, Any],
        scheduler: dict[str, Any] | None = None,
        monitor: str = SCORE_KEY,
        compile: bool | str | None = False,
    ) -> None:
        super().__init__()
        self.save_hyperparameters(ignore=["compile"])
        check_compile(compile)
        self.compile_setting = compile
        self.loss: PoseLoss = instantiate(loss)
        self.model = instantiate(model)
        self.val_score = SelectionScore()
        self.data: dict[str, Any] | None = None  # the training data's description, from a checkpoint
        self._resumed_rng: dict[str, Any] | None = None  # random streams of a checkpoint to resume
        self._mode: str | None = None  # the torch.compile mode of the training losses (None: eager)
        self._train_losses = self.losses  # compiled in on_fit_start where ``compile`` says so
        self._record: StepRecord | None = None  # the current epoch's step rows
        self._epoch_start = 0  # the global step of the epoch's first step

    def forward(self, batch: Mapping[str, Tensor]) -> Tensor:
        """Network output (B, L-1, dim) for a batch of windows."""
        return models.apply(self.model, batch)

    def decode(self, pred: Tensor) -> Tensor:
        """Relative poses (..., 4, 4) from network outputs (..., dim)."""
        return self.loss.decode(pred)

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """Record how the network is trained (its data description) and the random streams."""
        datamodule = getattr(self.trainer, "datamodule", None)
        describe(checkpoint, datamodule.description() if isinstance(datamodule, VODataModule) else self.data)
        checkpoint["rng"] = collect_rng()

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        self.data = Description.of(checkpoint).data
        self._resumed_rng = checkpoint.get("rng")

    def on_fit_start(self) -> None:
        """The training losses compiled for the training device where ``compile`` says so."""
        self._mode = compile_mode(self.compile_setting, self.device)
        self._train_losses = compiled(self.losses, self._mode)

    def on_train_start(self) -> None:
        """On resuming: the checkpoint's random streams, and a cosine schedule that grew continued."""
        if self._resumed_rng:
            restore_rng(self._resumed_rng)
            self._resumed_rng = None
        for config in self.trainer.lr_scheduler_configs:
            extend_cosine(config.scheduler, (self.hparams["scheduler"] or {}).get("T_max"))

    def losses(
        self, inputs: Mapping[str, Tensor], targets: Tensor, metric: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        """The training loss (scalar) of a batch and its record row; targets (B, L-1, 4, 4), metric (B,)."""
        pred = self(inputs)
        out = self.loss(pred, targets, metric)
        return out["loss"], step_row(out, pred, targets.shape[0] * targets.shape[1])

    def training_step(self, batch: Mapping[str, Tensor], batch_idx: int) -> Tensor:
        if self._record is None:  # the first step after an epoch closed early (max_steps)
            self.on_train_epoch_start()
        assert self._record is not None
        if self._mode is not None:
            torch.compiler.cudagraph_mark_step_begin()  # the previous step's graph outputs are done with
        inputs = {name: batch[name] for name in models.inputs_of(self.model)}
        loss, row = self._train_losses(inputs, batch["targets"], batch.get("metric"))
        if self._mode is not None:
            loss = loss.clone()  # Lightning holds it past the step; a CUDA graph's output is overwritten
        self._record.write(row)
        if self.trainer.progress_bar_callback is not None:  # a terminal's bar reads it (a host copy)
            self.log("loss", loss.detach().clone(), on_step=True, on_epoch=False, prog_bar=True, logger=False)
        if self._last_step(batch_idx):
            self._close_epoch()
        return loss

    def on_train_epoch_start(self) -> None:
        """A fresh record for the epoch's steps."""
        batches = self.trainer.num_training_batches  # inf for a loader without a length
        capacity = int(batches) if math.isfinite(batches) else 1024
        self._record = StepRecord(capacity, self.loss.output_keys(), self.device)
        self._epoch_start = self.global_step

    def on_train_epoch_end(self) -> None:
        if self._record is not None and self._record.steps:  # an epoch cut short of its last batch
            self._close_epoch()

    def _last_step(self, batch_idx: int) -> bool:
        """Whether this is the epoch's last training step."""
        trainer = self.trainer
        return (
            trainer.is_last_batch
            or batch_idx + 1 >= trainer.num_training_batches
            or (trainer.max_steps > 0 and self.global_step + 1 >= trainer.max_steps)
        )

    def _close_epoch(self) -> None:
        """Read the epoch's record (one copy to the host): stop at a non-finite loss, else log the means."""
        assert self._record is not None
        record, self._record = self._record, None
        rows = record.rows()
        bad = first_non_finite(rows)
        if bad is not None:
            raise self._non_finite(
                dict(zip(record.keys, rows[bad].tolist(), strict=False)), bool(rows[bad, -2]), bad
            )
        means = epoch_means(rows, len(record.keys))
        if self.trainer.world_size > 1:  # every process's steps: totals summed across them
            means = self._across_processes(means, int(rows[:, -1].sum()))
        values = {f"train/{key}": float(value) for key, value in zip(record.keys, means, strict=True)}
        self.log_dict(values, on_step=False, on_epoch=True, batch_size=1)

    def _across_processes(self, means: np.ndarray, pairs: int) -> np.ndarray:
        """Means over every process's frame pairs from this process's ``means`` over its ``pairs``."""
        local = torch.tensor(
            [*(means.astype(np.float64) * pairs), pairs], dtype=torch.float64, device=self.device
        )
        total = self.trainer.strategy.reduce(local, reduce_op="sum").cpu().numpy()
        return (total[:-1] / max(total[-1], 1.0)).astype(np.float32)

    def _non_finite(self, terms: dict[str, float], pred_finite: bool, step: int) -> NonFiniteLossError:
        """The error for the epoch's ``step``-th step (0-based), whose loss terms are ``terms``."""
        bad = [k for k in ("trans_loss", "rot_loss") if not np.isfinite(terms[k])] or ["loss"]
        cause = (
            "the network output is finite, so the loss computation overflowed"
            if pred_finite
            else "the network output is non-finite"
        )
        return NonFiniteLossError(
            f"non-finite loss at epoch {self.current_epoch}, global step {self._epoch_start + step}, "
            f"batch {step}: {', '.join(bad)} = {', '.join(f'{terms[k]}' for k in bad)} "
            f"({cause}; try a lower learning rate, gradient clipping or loss.k)"
        )

    def _step(self, batch: Mapping[str, Tensor], stage: str) -> Tensor:
        """A validation or test step: the loss's terms logged per epoch, the selection score updated."""
        targets = batch["targets"]  # epoch means weight each batch by its frame pairs
        metric = batch.get("metric")
        pred = self(batch)
        out = self.loss(pred, targets, metric)
        self.log_dict(
            {f"{stage}/{key}": value for key, value in out.items()},
            on_step=False,
            on_epoch=True,
            batch_size=targets.shape[0] * targets.shape[1],
            sync_dist=True,
        )
        if stage == "val":
            decoded = self.decode(pred.detach().float())
            if self.loss.translation == "direction":  # no metric scale: the target's, as evaluation
                decoded = scale_steps(decoded, targets)
            elif self.loss.translation == "cue" and metric is not None:  # the target's where no cue
                scaled = scale_steps(decoded, targets)
                decoded = torch.where(metric.view(-1, 1, 1, 1), decoded, scaled)
            self.val_score.update(decoded, targets)
            self.log(SCORE_KEY, self.val_score, on_step=False, on_epoch=True)
        return out["loss"]

    def validation_step(self, batch: Mapping[str, Tensor], batch_idx: int) -> Tensor:
        return self._step(batch, "val")

    def test_step(self, batch: Mapping[str, Tensor], batch_idx: int) -> Tensor:
        return self._step(batch, "test")

    def configure_optimizers(self) -> Any:
        config = self.hparams["optimizer"]
        factory = instantiate(config)
        optimizer = factory(params=self.parameters(), **optimizer_options(factory, self.device, config))
        if not self.hparams["scheduler"]:
            return optimizer
        scheduler = instantiate(self.hparams["scheduler"])(optimizer=optimizer)
        return {
            "optimizer": optimizer,
            "lr_scheduler": {"scheduler": scheduler, "interval": "epoch", "monitor": self.hparams["monitor"]},
        }
