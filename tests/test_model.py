"""DeepVO: shapes, pair order, initialisation, dropout, recurrent state, FlowNetS loading, checkpoints."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest
import torch

from lossvo import losses
from lossvo.console import UserError
from lossvo.models import DeepVO, LoadReport, load_flownet

SMALL = {"width_mult": 0.0625, "hidden_size": 16}


def small(out_dim: int = 6, height: int = 64, width: int = 128, **kwargs) -> DeepVO:
    torch.manual_seed(0)
    return DeepVO(out_dim, height, width, **{**SMALL, **kwargs})


def frames(B: int = 2, L: int = 4, height: int = 64, width: int = 128, seed: int = 1) -> torch.Tensor:
    return torch.randn(B, L, 3, height, width, generator=torch.Generator().manual_seed(seed))


# -- shapes and batching ------------------------------------------------------------------------------


@pytest.mark.parametrize("out_dim", [6, 7, 9])
@pytest.mark.parametrize(("height", "width"), [(64, 208), (128, 416)])
def test_output_shape_and_one_encoder_call(out_dim: int, height: int, width: int) -> None:
    model = small(out_dim, height, width)
    calls: list[tuple[int, ...]] = []
    model.encoder.register_forward_hook(lambda m, args, out: calls.append(tuple(args[0].shape)))
    out = model(frames(3, 5, height, width))
    assert out.shape == (3, 4, out_dim)
    assert calls == [(3 * 4, 6, height, width)]  # one batched call on all B * (L-1) pairs
    assert model.feature_shape == (64, -(-height // 64), -(-width // 64))
    assert model.lstm_input_size == 64 * (height // 64) * -(-width // 64)


def test_lstm_input_size_matches_encoder_output() -> None:
    model = DeepVO(6, 64, 208, width_mult=0.25, hidden_size=8)
    assert model.feature_shape == (256, 1, 4) and model.lstm_input_size == 1024
    feats = model.encoder(torch.zeros(1, 6, 64, 208))
    assert tuple(feats.shape[1:]) == model.feature_shape
    odd = DeepVO(6, 100, 130, **SMALL)  # not multiples of 64: ceil
    assert tuple(odd.encoder(torch.zeros(1, 6, 100, 130)).shape[1:]) == odd.feature_shape == (64, 2, 3)


def test_parameter_names_follow_flownet() -> None:
    keys = set(small().state_dict())
    for name in ("conv1", "conv2", "conv3", "conv3_1", "conv4", "conv4_1", "conv5", "conv5_1", "conv6"):
        for suffix in ("0.weight", "1.weight", "1.bias", "1.running_mean", "1.running_var"):
            assert f"encoder.{name}.{suffix}" in keys
        assert f"encoder.{name}.0.bias" not in keys  # BN convs have no bias, as in FlowNetS-BN
    no_bn = set(small(batch_norm=False).state_dict())
    assert "encoder.conv1.0.bias" in no_bn and "encoder.conv1.1.weight" not in no_bn


def test_pairs_are_consecutive_frames_in_order() -> None:
    model = small().eval()
    x = frames(2, 4)
    out = model(x)
    with torch.no_grad():
        feats = torch.stack(
            [model.encoder(torch.cat((x[:, k], x[:, k + 1]), dim=1)).flatten(1) for k in range(3)], dim=1
        )
        manual = model.head(model.lstm(feats)[0])
    torch.testing.assert_close(out, manual)
    swapped = x.clone()
    swapped[:, [1, 2]] = x[:, [2, 1]]
    assert not torch.allclose(model(swapped)[:, 0], out[:, 0])  # pair 0 sees frame 1


# -- initialisation and training behaviour ------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize(
    "loss_cls",
    [losses.EulerLoss, losses.QuaternionLoss, losses.ChordalLoss, losses.SixDLoss, losses.SVDLoss,
     losses.SymMatrixQuatLoss],
)  # fmt: skip
def test_initial_output_is_near_identity_motion(loss_cls: type[losses.PoseLoss]) -> None:
    ident = loss_cls().identity_output()
    torch.testing.assert_close(loss_cls().decode(ident.double()), torch.eye(4, dtype=torch.float64))
    model = small(loss_cls.dim, hidden_size=256, head_bias=ident.tolist()).eval()
    out = model(frames(2, 4))
    assert (out - ident).abs().max() < 0.1
    poses = loss_cls().decode(out)
    torch.testing.assert_close(poses, torch.eye(4).expand_as(poses), atol=0.1, rtol=0)


def test_gradients_reach_every_parameter() -> None:
    model = small(7).train()
    loss = losses.QuaternionLoss()(model(frames(2, 4)), torch.eye(4).expand(2, 3, 4, 4))["loss"]
    loss.backward()
    for name, param in model.named_parameters():
        assert param.grad is not None, name
        assert torch.isfinite(param.grad).all(), name
        assert param.grad.abs().sum() > 0, name


def test_eval_disables_dropout() -> None:
    model = small(head_dropout=0.5, conv_dropout=0.2)
    x = frames(2, 4)
    model.eval()
    with torch.no_grad():
        torch.testing.assert_close(model(x), model(x), rtol=0, atol=0)
        model.train()
        assert not torch.equal(model(x), model(x))


@pytest.mark.slow
def test_forward_with_state_carries_over_chunks() -> None:
    model = small().eval()
    x = frames(2, 7)
    k = 3
    with torch.no_grad():
        full, (h, c) = model.forward_with_state(x)
        first, state = model.forward_with_state(x[:, : k + 1])  # pairs 0..k-1
        second, end = model.forward_with_state(x[:, k:], state)  # pairs k..L-2
        fresh = model(x[:, k:])
    assert h.shape == c.shape == (model.lstm_layers, 2, model.hidden_size)
    torch.testing.assert_close(torch.cat((first, second), dim=1), full)
    torch.testing.assert_close(end[0], h)
    torch.testing.assert_close(end[1], c)
    assert not torch.allclose(fresh, second)  # without the state, the LSTM starts over


# -- argument and input checks ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"out_dim": 0}, "model.out_dim"),
        ({"out_dim": 6.0}, "model.out_dim"),
        ({"height": 32}, r"model.height: expected an integer >= 64 .*conv6.*got 32"),
        ({"width": True}, "model.width"),
        ({"width_mult": 0.0}, r"model.width_mult: expected a number in \(0, 16\]"),
        ({"width_mult": float("nan")}, "model.width_mult"),
        ({"hidden_size": 0}, "model.hidden_size"),
        ({"lstm_layers": 0}, "model.lstm_layers"),
        ({"conv_dropout": 1.0}, r"model.conv_dropout: expected a probability in \[0, 1\)"),
        ({"conv6_dropout": -0.1}, "model.conv6_dropout"),
        ({"lstm_dropout": 2}, "model.lstm_dropout"),
        ({"head_dropout": "0.5"}, "model.head_dropout"),
        ({"batch_norm": 1}, "model.batch_norm"),
        ({"flownet": 3}, "model.flownet"),
    ],
)
def test_bad_arguments(kwargs: dict, match: str) -> None:
    args = {"out_dim": 6, "height": 64, "width": 128, **SMALL, **kwargs}
    with pytest.raises(UserError, match=match):
        DeepVO(**args)


@pytest.mark.parametrize(
    "shape",
    [(4, 3, 64, 128), (2, 4, 1, 64, 128), (2, 1, 3, 64, 128), (2, 4, 3, 64, 130), (2, 4, 3, 128, 64)],
)
def test_bad_input_shape(shape: tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match=r"expects frames of shape \(B, L >= 2, 3, 64, 128\), got") as err:
        small()(torch.zeros(shape))
    assert str(shape) in str(err.value)


def test_integer_frames_are_rejected() -> None:
    with pytest.raises(ValueError, match="floating-point"):
        small()(torch.zeros(1, 2, 3, 64, 128, dtype=torch.uint8))


def test_state_dict_reloads_with_weights_only(tmp_path: Path) -> None:
    model = small(9).eval()
    with torch.no_grad():  # move running stats off their defaults
        model.train()(frames(2, 3))
    model.eval()
    torch.save(model.state_dict(), tmp_path / "m.pt")
    fresh = DeepVO(9, 64, 128, **SMALL)
    fresh.load_state_dict(torch.load(tmp_path / "m.pt", weights_only=True))
    fresh.eval()
    x = frames(2, 4)
    torch.testing.assert_close(fresh(x), model(x), rtol=0, atol=0)


# -- FlowNetS weights ---------------------------------------------------------------------------------

DECODER_KEYS = {
    "deconv5.0.weight": (512, 1024, 4, 4),
    "deconv2.0.weight": (194, 64, 4, 4),
    "predict_flow6.weight": (2, 1024, 3, 3),
    "predict_flow2.weight": (2, 194, 3, 3),
    "upsampled_flow6_to_5.weight": (2, 2, 4, 4),
}


@pytest.fixture(scope="module")
def flownet_file(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, torch.Tensor]]:
    """A FlowNetPytorch-style flownets_bn checkpoint with random values (encoder keys + some decoder)."""
    torch.manual_seed(2)
    reference = DeepVO(6, 64, 64, hidden_size=4)  # width_mult 1: FlowNetS shapes
    state: dict[str, torch.Tensor] = {}
    for key, value in reference.encoder.state_dict().items():
        state[key] = value.clone() if key.endswith("num_batches_tracked") else torch.randn_like(value).abs()
    state.update({k: torch.randn(s) for k, s in DECODER_KEYS.items()})
    path = tmp_path_factory.mktemp("flownet") / "flownets_bn_EPE2.459.pth.tar"
    torch.save({"epoch": 1, "arch": "flownets_bn", "state_dict": state, "div_flow": 20}, path)
    return path, state


@pytest.fixture(scope="module")
def full_width_model() -> DeepVO:
    torch.manual_seed(3)
    return DeepVO(6, 64, 64, hidden_size=4)


def test_load_flownet(flownet_file, full_width_model: DeepVO) -> None:
    path, state = flownet_file
    report = load_flownet(full_width_model, path)
    encoder_keys = list(full_width_model.encoder.state_dict())
    assert isinstance(report, LoadReport)
    assert sorted(report.loaded) == sorted(encoder_keys)
    assert report.missing == [] and report.mismatched == []
    assert sorted(report.unexpected) == sorted(DECODER_KEYS)
    assert (
        report.summary()
        == f"{len(encoder_keys)} loaded, 0 missing, {len(DECODER_KEYS)} unexpected, 0 mismatched"
    )
    for key, value in full_width_model.encoder.state_dict().items():
        torch.testing.assert_close(value, state[key], rtol=0, atol=0)
    out = full_width_model.eval()(torch.zeros(1, 2, 3, 64, 64))
    assert torch.isfinite(out).all()


def test_load_flownet_bare_state_dict_with_mismatch_warns(
    tmp_path: Path, flownet_file, full_width_model
) -> None:
    _, state = flownet_file
    part = {k: v for k, v in state.items() if k.startswith("conv1.")}
    part["conv2.0.weight"] = torch.zeros(128, 64, 3, 3)  # 3x3 instead of 5x5
    torch.save(part, tmp_path / "part.pth")
    before = full_width_model.encoder.conv2[0].weight.detach().clone()
    with pytest.warns(
        UserWarning, match=r"conv2.0.weight: file \(128, 64, 3, 3\) vs model \(128, 64, 5, 5\)"
    ):
        report = load_flownet(full_width_model, tmp_path / "part.pth")
    assert report.mismatched == [("conv2.0.weight", (128, 64, 3, 3), (128, 64, 5, 5))]
    assert sorted(report.loaded) == sorted(k for k in part if k.startswith("conv1."))
    assert "conv2.0.weight" not in report.missing and "conv2.0.weight" not in report.loaded
    assert "conv6.1.running_var" in report.missing
    assert not any(k.endswith("num_batches_tracked") for k in report.missing)
    torch.testing.assert_close(full_width_model.encoder.conv2[0].weight, before, rtol=0, atol=0)


def test_flownet_constructor_argument(tmp_path: Path, flownet_file) -> None:
    _, state = flownet_file
    torch.save(
        {"state_dict": {k: state[k] for k in ("conv1.0.weight", "conv1.1.weight")}}, tmp_path / "f.pth"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing mismatches: no warning
        model = DeepVO(6, 64, 64, hidden_size=4, flownet=str(tmp_path / "f.pth"))
    torch.testing.assert_close(model.encoder.conv1[0].weight, state["conv1.0.weight"], rtol=0, atol=0)


def test_flownet_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.pth.tar"
    with pytest.raises(FileNotFoundError, match=r"nope\.pth\.tar"):
        load_flownet(small(), path)
    with pytest.raises(FileNotFoundError, match=r"nope\.pth\.tar"):
        DeepVO(6, 64, 128, **SMALL, flownet=path)


def test_flownet_unreadable_or_empty(tmp_path: Path) -> None:
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(UserError, match=r"junk.pth could not be loaded"):
        load_flownet(small(), tmp_path / "junk.pth")
    torch.save({"epoch": 3, "arch": "flownets"}, tmp_path / "nostate.pth")
    with pytest.raises(UserError, match=r"nostate\.pth holds no state dict"):
        load_flownet(small(), tmp_path / "nostate.pth")


def test_flownet_nothing_matches(tmp_path: Path) -> None:
    torch.save({"state_dict": {k: torch.zeros(s) for k, s in DECODER_KEYS.items()}}, tmp_path / "dec.pth")
    with pytest.raises(UserError, match=r"dec.pth: nothing matches the encoder"):
        load_flownet(small(), tmp_path / "dec.pth")


def test_flownet_needs_full_width(flownet_file) -> None:
    path, _ = flownet_file
    model = DeepVO(6, 64, 64, width_mult=0.25, hidden_size=4)
    with pytest.raises(
        UserError, match=r"nothing matches.*different shapes.*width_mult=1 \(model has width_mult=0.25\)"
    ):
        load_flownet(model, path)


def test_channels_last_gives_the_same_outputs_and_gradients() -> None:
    x = frames(2, 4)
    outputs, grads = [], []
    for channels_last in (False, True):
        no_dropout = {"conv_dropout": 0.0, "conv6_dropout": 0.0, "lstm_dropout": 0.0, "head_dropout": 0.0}
        model = small(channels_last=channels_last, **no_dropout).train()  # batch statistics on
        out = model(x)
        out.square().sum().backward()
        outputs.append(out)
        grads.append(model.encoder.conv1[0].weight.grad)
    torch.testing.assert_close(outputs[0], outputs[1], atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(grads[0], grads[1], atol=1e-5, rtol=1e-4)
    assert small(channels_last=True).encoder.conv2[0].weight.is_contiguous(memory_format=torch.channels_last)
