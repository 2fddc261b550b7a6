"""The LightningModule: a VO network trained with one pose loss.

The module is built from plain config dictionaries (Hydra ``_target_`` style), and those dictionaries
are its hyperparameters: a checkpoint holds only primitives and reloads with torch's default
``weights_only`` loading, and ``VOModule.load_from_checkpoint(path)`` rebuilds the same network and
loss without Hydra. Every key the loss returns is logged per epoch as ``train/<key>`` and
``val/<key>`` (``loss``, ``trans_loss``, ``rot_loss``, ``trans_err_m``, ``rot_err_rad``; ``s_t``, ``s_r``
under the learned weighting), and validation also logs the loss-independent selection score
``val/score`` (:mod:`lossvo.training.selection`; for a loss with ``translation="direction"`` on the
predicted steps scaled to the target step lengths, as evaluation scores them). Checkpoints also record
the training data (:mod:`lossvo.evaluation.checkpoints`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import lightning as L
import torch
from hydra.utils import instantiate
from torch import Tensor

from lossvo import models
from lossvo.evaluation.trajectories import scale_steps
from lossvo.losses import PoseLoss
from lossvo.training import random_streams
from lossvo.training.schedules import extend_cosine
from lossvo.training.selection import SCORE_KEY, SelectionScore


class NonFiniteLossError(FloatingPointError):
    """The loss went NaN or infinite; the message names the step, the batch and the term."""


class VOModule(L.LightningModule):
    """A visual-odometry network and its pose loss.

    Args:
        model: config of the network (``_target_`` and arguments), e.g. :class:`lossvo.models.DeepVO`;
            it maps the batch entries its ``INPUTS`` names (``("frames",)`` if it names none: frames
            (B, L, 3, H, W)) to outputs (B, L-1, loss.dim).
        loss: config of a :class:`lossvo.losses.PoseLoss`.
        optimizer: config of a partial optimiser (``_partial_: true``), called with the parameters.
        scheduler: optional config of a partial LR scheduler, called with the optimiser; stepped per
            epoch and given the ``monitor`` metric when it needs one (ReduceLROnPlateau).
        monitor: the selection metric (``selection.monitor``): ``val/score`` or ``val/loss``.
    """

    def __init__(
        self,
        model: dict[str, Any],
        loss: dict[str, Any],
        optimizer: dict[str, Any],
        scheduler: dict[str, Any] | None = None,
        monitor: str = SCORE_KEY,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.loss: PoseLoss = instantiate(loss)
        self.model = instantiate(model)
        self.val_score = SelectionScore()
        self.data: dict[str, Any] | None = None  # the training data's description, from a checkpoint
        self._resumed_rng: dict[str, Any] | None = None  # random streams of a checkpoint to resume

    def forward(self, batch: Mapping[str, Tensor]) -> Tensor:
        """Network output (B, L-1, dim) for a batch of windows (:mod:`lossvo.data.datamodules`), of which
        it reads the entries the network names (:func:`lossvo.models.apply`)."""
        return models.apply(self.model, batch)

    def decode(self, pred: Tensor) -> Tensor:
        """Relative poses (..., 4, 4) from network outputs (..., dim)."""
        return self.loss.decode(pred)

    # -- checkpoints ----------------------------------------------------------------------------------

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """Record the training data's description (``checkpoint["data"]``, see
        :mod:`lossvo.evaluation.checkpoints`) when the datamodule gives one, the CPU thread count
        (``checkpoint["threads"]``), and the random streams (``checkpoint["rng"]``), which a resumed fit
        restores (Lightning restores the rest)."""
        datamodule = getattr(self.trainer, "datamodule", None)
        describe = getattr(datamodule, "description", None)
        if callable(describe):
            checkpoint["data"] = describe()
        elif self.data is not None:
            checkpoint["data"] = self.data
        checkpoint["threads"] = torch.get_num_threads()
        checkpoint["rng"] = random_streams.collect()

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        self.data = checkpoint.get("data")
        self._resumed_rng = checkpoint.get("rng")

    def on_train_start(self) -> None:
        """On resuming a fit: the random streams as they were when the checkpoint was written, and a
        schedule whose length grew (``trainer.max_epochs`` raised) continued at its current epoch."""
        if self._resumed_rng:
            random_streams.restore(self._resumed_rng)
            self._resumed_rng = None
        for config in self.trainer.lr_scheduler_configs:
            extend_cosine(config.scheduler, (self.hparams["scheduler"] or {}).get("T_max"))

    # -- steps ----------------------------------------------------------------------------------------

    def _step(self, batch: Mapping[str, Tensor], batch_idx: int, stage: str) -> Tensor:
        targets = batch["targets"]  # epoch means weight each batch by its frame pairs
        pred = self(batch)
        out = self.loss(pred, targets)
        if stage == "train":
            self._check_finite(out, pred, batch_idx)
        self.log_dict(
            {f"{stage}/{key}": value for key, value in out.items()},
            on_step=False, on_epoch=True, batch_size=targets.shape[0] * targets.shape[1], sync_dist=True,
        )  # fmt: skip
        if stage == "train":
            self.log("loss", out["loss"], on_step=True, on_epoch=False, prog_bar=True, logger=False)
        if stage == "val":
            decoded = self.decode(pred.detach().float())
            if self.loss.translation == "direction":  # no metric scale: the target's, as evaluation
                decoded = scale_steps(decoded, targets)
            self.val_score.update(decoded, targets)
            self.log(SCORE_KEY, self.val_score, on_step=False, on_epoch=True)
        return out["loss"]

    def training_step(self, batch: Mapping[str, Tensor], batch_idx: int) -> Tensor:
        return self._step(batch, batch_idx, "train")

    def validation_step(self, batch: Mapping[str, Tensor], batch_idx: int) -> Tensor:
        return self._step(batch, batch_idx, "val")

    def test_step(self, batch: Mapping[str, Tensor], batch_idx: int) -> Tensor:
        return self._step(batch, batch_idx, "test")

    def _check_finite(self, out: dict[str, Tensor], pred: Tensor, batch_idx: int) -> None:
        """Stop the run at the first non-finite loss, naming the step, batch, term and its cause."""
        if torch.isfinite(out["loss"]):
            return
        terms = [k for k in ("trans_loss", "rot_loss") if not torch.isfinite(out[k])]
        cause = (
            "the network output is non-finite"
            if not torch.isfinite(pred).all()
            else "the network output is finite, so the loss computation overflowed"
        )
        raise NonFiniteLossError(
            f"non-finite loss at epoch {self.current_epoch}, global step {self.global_step}, "
            f"batch {batch_idx}: "
            f"{', '.join(terms) or 'loss'} = {', '.join(f'{out[k].item()}' for k in terms or ['loss'])} "
            f"({cause}; try a lower learning rate, gradient clipping or loss.k)"
        )

    # -- optimisation ---------------------------------------------------------------------------------

    def configure_optimizers(self) -> Any:
        optimizer = instantiate(self.hparams["optimizer"])(params=self.parameters())
        if not self.hparams["scheduler"]:
            return optimizer
        scheduler = instantiate(self.hparams["scheduler"])(optimizer=optimizer)
        return {
            "optimizer": optimizer,
            "lr_scheduler": {"scheduler": scheduler, "interval": "epoch", "monitor": self.hparams["monitor"]},
        }
