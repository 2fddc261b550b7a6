"""Experiment loggers of Lightning, adjusted where they print what does not concern a lossvo run."""

from __future__ import annotations

from typing import Any

from lightning.pytorch import loggers


class WandbLogger(loggers.WandbLogger):
    """Lightning's W&B logger without the ``anonymous`` argument (W&B warns about it on every run)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._wandb_init.pop("anonymous", None)
