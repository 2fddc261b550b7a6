"""Learning-rate schedules across a resume that extends a run: an N-epoch cosine schedule extended to M
epochs continues as if it had been M epochs from the start.
"""

from __future__ import annotations

import logging
from typing import Any

from torch.optim.lr_scheduler import CosineAnnealingLR

log = logging.getLogger("lossvo")


def extend_cosine(scheduler: Any, t_max: Any) -> bool:
    """Give a restored ``CosineAnnealingLR`` the configured length ``t_max`` (epochs); whether it changed."""
    if not isinstance(scheduler, CosineAnnealingLR) or not isinstance(t_max, int) or t_max == scheduler.T_max:
        return False
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
    return True
