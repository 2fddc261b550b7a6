"""FlowVO: shapes, the inputs it builds (scaled flow, the intrinsics layer), its heads, the same start for
every loss, finite gradients from the first step, and its bad arguments."""

from __future__ import annotations

import re

import pytest
import torch

from lossvo.console import UserError
from lossvo.data import synthetic
from lossvo.geometry.camera import intrinsics_channels
from lossvo.losses import ChordalLoss, QuaternionLoss, SixDLoss, SVDLoss
from lossvo.models.flowvo import FlowVO

H, W = 64, 208


def _batch(B: int = 2, P: int = 3) -> tuple[torch.Tensor, torch.Tensor]:
    flow = torch.randn(B, P, 2, H, W, generator=torch.Generator().manual_seed(0)) * 3
    K = torch.from_numpy(synthetic.intrinsics(H, W)).float().expand(B, 3, 3)
    return flow, K


def test_outputs_one_vector_per_pair_translation_first() -> None:
    torch.manual_seed(0)
    bias = [0.1, 0.2, 0.3, 1.0, 0.0, 0.0, 0.0]
    net = FlowVO(7, H, W, head_bias=bias)
    flow, K = _batch()
    out = net(flow, K)
    assert out.shape == (2, 3, 7) and net.feature_shape == (128, 4, 13)
    torch.testing.assert_close(out, torch.tensor(bias).expand(2, 3, 7), atol=0.05, rtol=0)  # identity first


def test_inputs_are_the_scaled_flow_and_the_intrinsics_layer() -> None:
    torch.manual_seed(0)
    net = FlowVO(6, H, W, flow_gain=20.0)
    flow, K = _batch(B=2, P=3)
    x = net.encoder_input(flow, K).view(2, 3, 4, H, W)
    torch.testing.assert_close(x[:, :, 0], flow[:, :, 0] * 20 / W)
    torch.testing.assert_close(x[:, :, 1], flow[:, :, 1] * 20 / H)
    torch.testing.assert_close(x[1, 2, 2:], intrinsics_channels(K[1], H, W))
    pooled = FlowVO(6, H, W, flow_gain=20.0, pool=2)  # each 2x2 block's mean: a quarter of the pixels
    assert pooled.feature_shape == (128, 2, 7)
    torch.testing.assert_close(
        pooled.encoder_input(flow, K).view(2, 3, 4, H // 2, W // 2),
        x.view(2, 3, 4, H // 2, 2, W // 2, 2).mean((4, 6)),
    )
    assert pooled(flow, K).shape == (2, 3, 6)


def test_every_loss_starts_from_the_same_encoder_and_translation_head() -> None:
    """The same seed, heads of every loss's size: one encoder, one translation head."""
    nets, after = [], []
    for loss in (ChordalLoss, QuaternionLoss, SixDLoss, SVDLoss):  # rotation parts of 3, 4, 6 and 9
        torch.manual_seed(3)
        nets.append(FlowVO(loss.dim, H, W))
        after.append(torch.rand(()))  # the caller's stream after the network
    first = nets[0].state_dict()
    shared = [name for name in first if not name.startswith("rotation_head")]
    for net in nets[1:]:
        for name in shared:
            assert torch.equal(net.state_dict()[name], first[name]), name
    assert len({float(a) for a in after}) == 1  # one draw from the caller's stream, whatever the head
    torch.manual_seed(4)
    assert not torch.equal(FlowVO(6, H, W).stem[0].weight, nets[0].stem[0].weight)  # another seed


def test_gradients_are_finite_and_reach_the_stem_from_the_first_step() -> None:
    torch.manual_seed(0)
    net = FlowVO(6, H, W)
    flow, K = _batch()
    net(flow, K).square().sum().backward()
    for name, param in net.named_parameters():
        assert param.grad is not None and torch.isfinite(param.grad).all(), name
    assert net.stem[0].weight.grad.abs().sum() > 0


def test_channels_last_gives_the_same_values() -> None:
    flow, K = _batch()
    outs, grads = [], []
    for channels_last in (False, True):
        torch.manual_seed(0)
        net = FlowVO(6, H, W, channels_last=channels_last)
        out = net(flow, K)
        out.square().sum().backward()
        outs.append(out)
        grads.append(net.stem[0].weight.grad)
    torch.testing.assert_close(outs[0], outs[1], rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(grads[0], grads[1], rtol=1e-3, atol=1e-5)


def test_leaky_heads_pass_gradient_through_units_below_zero() -> None:
    """Every hidden unit of both heads pushed below zero: ReLU heads (slope 0) pass no gradient to their
    hidden layers, so the units cannot recover; leaky heads do. Slope 0 is ReLU exactly."""
    flow, K = _batch()
    grads = {}
    for slope in (0.0, 0.1):
        torch.manual_seed(0)
        net = FlowVO(7, H, W, head_negative_slope=slope)
        for head in (net.translation_head, net.rotation_head):
            torch.nn.init.constant_(head.hidden.bias, -1e3)
        out = net(flow, K)
        out.square().sum().backward()
        grads[slope] = [h.hidden.weight.grad.abs().sum() for h in (net.translation_head, net.rotation_head)]
    assert all(g == 0 for g in grads[0.0])
    assert all(g > 0 for g in grads[0.1])
    torch.manual_seed(0)
    relu = FlowVO(7, H, W)
    x = relu.stages(relu.stem(relu.encoder_input(flow, K))).flatten(1)
    head = relu.rotation_head
    torch.testing.assert_close(head(x), head.out(torch.relu(head.hidden(x))), rtol=0, atol=0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"out_dim": 3}, "model.out_dim: expected an integer >= 4"),
     ({"height": 8}, "model.height: expected an integer >= 16"),
     ({"channels": [32, 64]}, "model.channels: expected 4 integers >= 1, got [32, 64]"),
     ({"flow_gain": 0}, "model.flow_gain: expected a number > 0, got 0"),
     ({"pool": 0}, "model.pool: expected an integer >= 1, got 0"),
     ({"pool": 3}, "model.pool: expected a divisor of the input size (64, 208), got 3"),
     ({"head_dropout": 1.5}, "model.head_dropout: expected a probability in [0, 1), got 1.5"),
     ({"head_negative_slope": 1}, "model.head_negative_slope: expected a slope in [0, 1), got 1"),
     ({"head_negative_slope": -0.1}, "model.head_negative_slope: expected a slope in [0, 1), got -0.1"),
     ({"channels_last": "yes"}, "model.channels_last: expected true or false, got 'yes'")],
)  # fmt: skip
def test_bad_arguments_name_the_key(kwargs: dict, message: str) -> None:
    with pytest.raises(UserError, match=f"^{re.escape(message)}"):
        FlowVO(**({"out_dim": 6, "height": H, "width": W} | kwargs))


def test_inputs_of_the_wrong_shape_say_what_was_expected() -> None:
    net = FlowVO(6, H, W)
    flow, K = _batch()
    with pytest.raises(
        ValueError, match=r"FlowVO expects flow of shape \(B, P, 2, 64, 208\), got \(2, 3, 2, 32, 208\)"
    ):
        net(flow[..., :32, :], K)
    with pytest.raises(ValueError, match=r"FlowVO expects K of shape \(2, 3, 3\), got \(3, 3\)"):
        net(flow, K[0])


def _flowvo_overrides(tiny_kitti, cache) -> list[str]:
    """The tiny experiment with a small FlowVO instead of the tiny DeepVO."""
    from test_train import tiny_overrides

    tiny = [arg for arg in tiny_overrides(tiny_kitti, cache) if not arg.startswith("model.")]
    return [*tiny, "model=flowvo", "model.channels=[8,8,16,16]", "model.hidden=16"]


@pytest.mark.slow
@pytest.mark.parametrize("loss", ["euler", "quat", "chordal"])
def test_model_flowvo_trains_on_the_flow_it_selects(loss: str, tiny_kitti, tmp_path) -> None:
    """``model=flowvo`` alone: data.flow.method follows the network (DIS), the flow is cached, a fit runs."""
    from helpers import fit
    from test_train import compose_train

    overrides = [
        *_flowvo_overrides(tiny_kitti, tmp_path / "cache"),
        f"loss={loss}",
        "+trainer.fast_dev_run=1",
    ]
    cfg = compose_train(overrides, tmp_path / "run")
    assert cfg.data.flow.method == "dis"
    metrics = fit(cfg)
    assert all(torch.isfinite(torch.tensor(v)) for v in metrics.values())
    assert list((tmp_path / "cache").rglob("*.flow-dis-medium-x1.5-s1.npy"))


@pytest.mark.slow
def test_a_flowvo_checkpoint_evaluates_where_no_flow_is_cached(
    tiny_kitti, tmp_path, monkeypatch, capsys
) -> None:
    """``python -m lossvo.eval ... data=kitti`` composes no network, so the chosen data's ``data.flow.method``
    reads none: the flow comes from the checkpoint, is computed into an empty cache, and the results equal
    those of the training run's own evaluation."""
    from helpers import eval_main, fit, scores_of
    from test_train import compose_train

    run = tmp_path / "run"
    fit(compose_train([*_flowvo_overrides(tiny_kitti, tmp_path / "cache"), "trainer.max_epochs=1"], run))
    out = tmp_path / "eval"
    args = [
        f"ckpt_path={run}/checkpoints/best.ckpt",
        "data=kitti",
        f"data.sources.kitti.root={tiny_kitti}",
        "data.splits.test=[02]",
        f"data.frames.cache_dir={tmp_path / 'empty'}",
        f"hydra.run.dir={out}",
    ]
    status, err = eval_main(args, monkeypatch, capsys)
    assert status == 0, err
    assert list((tmp_path / "empty").rglob("02.flow-dis-medium-x1.5-s1.npy"))
    evaluated, trained = scores_of(out), scores_of(run)
    assert evaluated["sequences"] == trained["sequences"]
