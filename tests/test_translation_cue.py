"""``loss.translation=cue``: the metric term on windows whose platform gives metric scale a cue, the
scale-given term on the others (the predicted step scaled to the target's length), bit for bit the metric
loss where every window has a cue, finite at zero steps; the training step and the validation score
read the batch's ``metric`` flags."""

from __future__ import annotations

import pytest
import torch
from torch import Tensor

from lossvo import geometry as g
from lossvo.evaluation.trajectories import scale_steps
from lossvo.losses import PoseLoss
from lossvo.training.module import VOModule
from lossvo.training.selection import SelectionScore
from test_losses import LOSSES
from test_translation_direction import moving_targets, predictions, unit

FLAGS = torch.tensor([True, False, True])
"""Windows 0 and 2 from a platform with a metric cue (a car), window 1 from one without."""


@pytest.mark.parametrize("cls", LOSSES)
def test_every_window_with_a_cue_is_the_metric_loss_bit_for_bit(cls: type[PoseLoss]) -> None:
    target = moving_targets().float()
    pred = predictions(cls, target.double()).float().requires_grad_()
    metric, cue = cls(translation="metric")(pred, target), cls(translation="cue")
    for flags in (torch.ones(3, dtype=torch.bool), None):
        out = cue(pred, target, flags)
        assert set(out) == set(metric)
        for key, value in metric.items():
            assert torch.equal(out[key], value), key
        (grad_cue,) = torch.autograd.grad(out["loss"], pred)
        (grad_metric,) = torch.autograd.grad(metric["loss"], pred, retain_graph=True)
        assert torch.equal(grad_cue, grad_metric)


@pytest.mark.parametrize("cls", LOSSES)
def test_a_window_without_a_cue_is_scored_on_its_step_scaled_to_the_targets_length(
    cls: type[PoseLoss],
) -> None:
    loss, target = cls(translation="cue"), moving_targets()
    pred = predictions(cls, target)
    out = loss(pred, target, FLAGS)
    t, t_target = loss.decode_rt(pred)[1], target[..., :3, 3]
    scaled = g.scale_to_length(t, t_target.norm(dim=-1))
    terms = torch.where(FLAGS[:, None], (t - t_target).square().sum(-1), (scaled - t_target).square().sum(-1))
    torch.testing.assert_close(out["trans_loss"], terms.mean(), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(out["trans_err_m"], terms.sqrt().mean(), rtol=1e-12, atol=1e-12)
    # the window without a cue: any length of its predicted steps gives the same loss
    longer = pred.clone()
    longer[1, :, :3] *= 7.0  # t, or rho for SE(3), where t = V(omega) rho scales with rho
    for key in ("loss", "trans_loss", "trans_err_m"):
        torch.testing.assert_close(loss(longer, target, FLAGS)[key], out[key], rtol=1e-12, atol=1e-12)
    longer[0, :, :3] *= 7.0  # a car's window: its length counts
    assert loss(longer, target, FLAGS)["trans_loss"] > 2 * out["trans_loss"]


@pytest.mark.parametrize("cls", LOSSES)
def test_the_scale_given_term_is_zero_at_the_true_direction_and_weighs_a_step_by_its_length(
    cls: type[PoseLoss],
) -> None:
    loss, target = cls(translation="cue"), moving_targets()
    R, t = target[..., :3, :3], target[..., :3, 3]
    none = torch.zeros(3, dtype=torch.bool)
    for length in (0.01, 1.0, 40.0):
        out = loss(loss.encode(g.make_pose(R, unit(t) * length)), target, none)
        torch.testing.assert_close(
            out["trans_loss"], torch.zeros((), dtype=torch.float64), atol=1e-12, rtol=0
        )
    # the opposite direction: |-t^ - t^|^2 = 4 |t^|^2, in m^2 as the metric term
    out = loss(loss.encode(g.make_pose(R, -0.5 * t)), target, none)
    torch.testing.assert_close(out["trans_loss"], (4 * t.square().sum(-1)).mean())


@pytest.mark.parametrize("cls", LOSSES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_zero_steps_have_a_finite_value_and_gradient(cls: type[PoseLoss], dtype: torch.dtype) -> None:
    """A predicted step of zero and a standing target (length 0) in a window without a cue."""
    loss, target = cls(translation="cue"), moving_targets().to(dtype)
    target[1, 0, :3, 3] = 0.0
    pose = target.clone()
    pose[1, :, :3, 3] = 0.0
    pred = loss.encode(pose).requires_grad_()
    out = loss(pred, target, FLAGS)
    (grad,) = torch.autograd.grad(out["loss"], pred)
    assert all(torch.isfinite(v).all() for v in out.values()) and torch.isfinite(grad).all()


def test_flags_of_another_shape_are_refused() -> None:
    loss, target = LOSSES[0](translation="cue"), moving_targets()
    pred = predictions(LOSSES[0], target)
    with pytest.raises(ValueError, match=r"metric: expected shape \(3,\), one flag a window, got \(2,\)"):
        loss(pred, target, torch.ones(2, dtype=torch.bool))


class Network(torch.nn.Module):
    """Outputs (B, L-1, dim) that a test sets: ``INPUTS`` names the batch entry it returns."""

    INPUTS = ("outputs",)

    def forward(self, outputs: Tensor) -> Tensor:
        return outputs


def module(translation: str) -> VOModule:
    loss = {"_target_": "lossvo.losses.ChordalLoss", "translation": translation}
    optimizer = {"_target_": "torch.optim.Adam", "_partial_": True}
    vo = VOModule({"_target_": "torch.nn.Identity"}, loss, optimizer)
    vo.model = Network()
    return vo


def test_the_training_losses_and_the_validation_score_read_the_windows_flags() -> None:
    target = moving_targets().float()
    outputs = predictions(LOSSES[0], target.double()).float()
    cue, metric = module("cue"), module("metric")
    inputs = {"outputs": outputs}
    loss, _ = cue.losses(inputs, target, FLAGS)
    assert torch.equal(loss, cue.loss(outputs, target, FLAGS)["loss"])
    assert not torch.equal(loss, metric.losses(inputs, target, FLAGS)[0])  # the metric loss ignores them
    # the score: the window without a cue scored on its steps scaled to the target's lengths
    decoded = cue.decode(outputs)
    expected = SelectionScore()
    expected.update(torch.where(FLAGS.view(-1, 1, 1, 1), decoded, scale_steps(decoded, target)), target)
    cue.log = cue.log_dict = lambda *args, **kwargs: None  # no trainer to log to
    cue._step({"outputs": outputs, "targets": target, "metric": FLAGS}, "val")
    torch.testing.assert_close(cue.val_score.compute(), expected.compute())
