"""The loss-independent validation score that selects checkpoints (config group ``selection``), summed over
every validation frame pair (t, R the target, t^, R^ the prediction; docs/fair-comparison.md):

    score = ( sum |t - t^| / sum |t|  +  sum angle(R^T R^) / sum angle(R) ) / 2
"""

from __future__ import annotations

import torch
from torch import Tensor
from torchmetrics import Metric

from lossvo import geometry as g

SCORE_KEY = "val/score"


def _sums(pred: Tensor, target: Tensor) -> Tensor:
    """(4,) float64 sums over (..., 4, 4) pairs: translation error, rotation error, |t|, angle(R)."""
    pred, target = pred.double(), target.double()
    trans_err = torch.linalg.vector_norm(pred[..., :3, 3] - target[..., :3, 3], dim=-1)
    rot_err = g.so3_geodesic_distance(target[..., :3, :3], pred[..., :3, :3])
    zero_trans = torch.linalg.vector_norm(target[..., :3, 3], dim=-1)
    zero_rot = g.rotation_angle(target[..., :3, :3])
    return torch.stack([x.sum() for x in (trans_err, rot_err, zero_trans, zero_rot)])


def _score(sums: Tensor) -> Tensor:
    """The score (scalar) from the four sums of :func:`_sums`."""
    reference = sums[2:].clamp_min(torch.finfo(sums.dtype).tiny)
    return (sums[:2] / reference).mean()


def selection_score(pred: Tensor, target: Tensor) -> Tensor:
    """Mean of the translation and rotation errors relative to no motion (scalar, float64) of (..., 4, 4)
    relative poses: 0 for a perfect prediction, 1 for the identity everywhere."""
    return _score(_sums(pred, target))


class SelectionScore(Metric):
    """:func:`selection_score` accumulated over batches (and processes)."""

    full_state_update = False
    higher_is_better = False
    sums: Tensor

    def __init__(self) -> None:
        super().__init__()
        self.add_state("sums", default=torch.zeros(4, dtype=torch.float64), dist_reduce_fx="sum")

    def update(self, pred: Tensor, target: Tensor) -> None:
        """Add a batch of decoded predictions and targets, (..., 4, 4) each."""
        self.sums += _sums(pred.detach(), target.detach()).to(self.sums.device)

    def compute(self) -> Tensor:
        return _score(self.sums).float()
