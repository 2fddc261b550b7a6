"""lossvo.training.step and the training step of VOModule: the epoch's record on the device, the optimiser's
kernels, compilation, and no host synchronisation inside an epoch."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from lossvo import geometry as g
from lossvo.console import UserError
from lossvo.training.module import VOModule
from lossvo.training.step import (
    StepRecord,
    compile_mode,
    compiled,
    epoch_means,
    first_non_finite,
    optimizer_options,
)

CPU, CUDA = torch.device("cpu"), torch.device("cuda", 0)


@pytest.mark.parametrize(
    ("setting", "cpu", "cuda"),
    [(False, None, None), (None, None, None), ("auto", None, "reduce-overhead"), (True, "default", "default"),
     ("max-autotune", "max-autotune", "max-autotune")],
)  # fmt: skip
def test_compile_mode(setting: Any, cpu: str | None, cuda: str | None) -> None:
    assert compile_mode(setting, CPU) == cpu and compile_mode(setting, CUDA) == cuda


@pytest.mark.parametrize("setting", ["fast", 1, "graphs"])
def test_a_compile_setting_that_does_not_exist_is_one_line(setting: Any) -> None:
    with pytest.raises(
        UserError, match=r"^compile: expected one of true, false, auto, default, reduce-overhead"
    ):
        compile_mode(setting, CPU)


def test_optimizer_kernels() -> None:
    adam = functools.partial(torch.optim.Adam, lr=1e-3)
    assert optimizer_options(adam, CUDA, {"lr": 1e-3}) == {"fused": True}
    assert optimizer_options(adam, CPU, {"lr": 1e-3}) == {
        "foreach": True
    }  # the loop's numbers (tested below)
    assert optimizer_options(adam, CUDA, {"foreach": False}) == {}  # the user's choice stands
    assert optimizer_options(functools.partial(torch.optim.LBFGS), CUDA, {}) == {}  # neither option


def test_foreach_adam_gives_the_per_parameter_loops_numbers_on_a_cpu() -> None:
    """The CPU's foreach kernels keep a sweep's numbers: the same weights, bit for bit, after 10 steps."""
    weights = []
    for options in ({"foreach": False}, optimizer_options(torch.optim.Adam, CPU, {})):
        torch.manual_seed(0)
        model = torch.nn.Sequential(torch.nn.Linear(8, 16), torch.nn.ReLU(), torch.nn.Linear(16, 3))
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-2, **options)
        data = torch.Generator().manual_seed(1)
        for _ in range(10):
            model(torch.randn(32, 8, generator=data)).square().mean().backward()
            optimizer.step()
            optimizer.zero_grad()
        weights.append(torch.cat([p.detach().flatten() for p in model.parameters()]))
    assert torch.equal(*weights)


def test_epoch_means_equal_lightnings_per_step_accumulation() -> None:
    """Lightning's epoch mean of a value logged each step: ``total = total + value * n`` in float32 and the
    sum of n; the record's means are those numbers, bit for bit."""
    generator = np.random.default_rng(0)
    values = generator.normal(size=(97, 5)).astype(np.float32) * np.float32(3.7)
    pairs = generator.integers(1, 41, size=97)
    total, count = torch.zeros(5), torch.tensor(0)
    for row, n in zip(values, pairs, strict=True):
        total = total + torch.from_numpy(row) * int(n)
        count = count + int(n)
    rows = np.concatenate([values, np.ones((97, 1), np.float32), pairs[:, None].astype(np.float32)], axis=1)
    np.testing.assert_array_equal(epoch_means(rows, 5), (total / count).numpy())


def test_the_record_grows_and_finds_the_first_non_finite_step() -> None:
    record = StepRecord(2, ("loss", "trans_loss"), CPU)
    for loss in (1.0, float("nan"), 2.0, float("inf")):
        record.write(torch.tensor([loss, 0.5, 1.0, 8.0]))
    rows = record.rows()
    assert rows.shape == (4, 4) and rows[2, 0] == 2.0
    assert first_non_finite(rows) == 1 and first_non_finite(rows[[0, 2]]) is None


def small_module(network: str, seed: int = 0) -> VOModule:
    """A tiny DeepVO (no dropout: a compiled graph draws its own masks) or FlowVO, and the chordal loss."""
    torch.manual_seed(seed)
    if network == "deepvo":
        model = {"_target_": "lossvo.models.DeepVO", "out_dim": 6, "height": 64, "width": 64,
                 "width_mult": 0.0625, "hidden_size": 16, "conv_dropout": 0.0, "conv6_dropout": 0.0,
                 "lstm_dropout": 0.0, "head_dropout": 0.0}  # fmt: skip
    else:
        model = {"_target_": "lossvo.models.FlowVO", "out_dim": 6, "height": 32, "width": 64,
                 "channels": [8, 8, 16, 16], "hidden": 16, "pool": 2}  # fmt: skip
    optimizer = {"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1e-3}
    return VOModule(model=model, loss={"_target_": "lossvo.losses.ChordalLoss"}, optimizer=optimizer)


def batches(network: str, n: int) -> list[tuple[dict[str, torch.Tensor], torch.Tensor]]:
    data = torch.Generator().manual_seed(1)
    out = []
    for _ in range(n):
        targets = g.se3_exp(0.05 * torch.randn(4, 2, 6, generator=data, dtype=torch.float64)).float()
        if network == "deepvo":
            inputs = {"frames": torch.randn(4, 3, 3, 64, 64, generator=data)}
        else:
            inputs = {
                "flow": 3 * torch.randn(4, 2, 2, 32, 64, generator=data),
                "K": torch.eye(3).repeat(4, 1, 1),
            }
        out.append((inputs, targets))
    return out


def train_losses(module: VOModule, mode: str | None, steps: list) -> list[torch.Tensor]:
    """The record rows of a few training steps (forward, loss, backward, Adam) of ``module``'s losses,
    compiled in ``mode`` (None: eagerly)."""
    step = compiled(module.losses, mode)
    optimizer = torch.optim.Adam(module.parameters(), lr=1e-3, foreach=True)
    rows = []
    for inputs, targets in steps:
        loss, row = step(inputs, targets)
        loss.backward()
        optimizer.step()
        optimizer.zero_grad()
        rows.append(row.detach().clone())
    return rows


@pytest.mark.slow
@pytest.mark.parametrize("network", ["deepvo", "flowvo"])
def test_the_compiled_step_gives_the_eager_steps_losses(network: str) -> None:
    """torch.compile (inductor, on the CPU here) of forward and loss: the same losses and yardsticks as the
    eager step over four steps of training, within float32 rounding."""
    steps = batches(network, 4)
    eager = train_losses(small_module(network).train(), None, steps)
    torch._dynamo.reset()
    compiled_rows = train_losses(small_module(network).train(), "default", steps)
    for a, b in zip(eager, compiled_rows, strict=True):
        torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-7)
    assert not torch.equal(eager[0], eager[-1])  # the steps trained


SYNCING_OPS = {"_local_scalar_dense", "nonzero", "is_nonzero", "equal", "item"}
"""Operations that, on a GPU, wait for the device: a tensor's value read on the host."""


class SyncProbe(L.Callback, TorchDispatchMode):
    """Records the operations of :data:`SYNCING_OPS` run inside a training epoch, with the batch they happened
    in: each step (its forward pass, loss, record, backward) and the transfer and augmentation of every batch
    but the epoch's first, up to the epoch's last step, whose record is then read. Not watched: the
    optimiser's update (its step counters are host tensors by design; on a GPU its fused kernel keeps them
    on the device), validation, and the loader's start of an epoch."""

    def __init__(self) -> None:
        L.Callback.__init__(self)
        TorchDispatchMode.__init__(self)
        self.phase: int | None = None
        self.seen: list[tuple[int, str]] = []
        self.steps = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        name = func.overloadpacket.__name__
        if self.phase is not None and name in SYNCING_OPS:
            self.seen.append((self.phase, name))
        return func(*args, **(kwargs or {}))

    def on_train_batch_start(self, trainer: L.Trainer, pl_module: L.LightningModule, batch: Any,
                             batch_idx: int) -> None:  # fmt: skip
        last = batch_idx + 1 >= trainer.num_training_batches  # the epoch's record is read in this step
        self.phase = None if last else batch_idx

    def on_before_optimizer_step(
        self, trainer: L.Trainer, pl_module: L.LightningModule, optimizer: Any
    ) -> None:
        self.phase = None

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs: Any, batch: Any,
                           batch_idx: int) -> None:  # fmt: skip
        self.steps += 1
        last = batch_idx + 1 >= trainer.num_training_batches
        self.phase = None if last else batch_idx  # the next batch is fetched, moved and augmented now


@pytest.mark.slow
@pytest.mark.parametrize("network", ["deepvo", "flowvo"])
@pytest.mark.parametrize("on_device", ["false", "true"])
def test_a_training_epoch_reads_nothing_back_to_the_host(tiny_kitti: Path, tmp_path: Path, network: str,
                                                         on_device: str, monkeypatch) -> None:  # fmt: skip
    """Two epochs of a real fit with the default augmentation (mirror): inside an epoch (:class:`SyncProbe`),
    no operation that would wait for a GPU (a value read on the host) in the data's path, the network, the
    loss or the record."""
    from helpers import fit
    from lossvo.training import fitting
    from test_flowvo import _flowvo_overrides
    from test_train import compose_train, tiny_overrides

    probe = SyncProbe()
    build = fitting.build

    def build_with_probe(cfg):
        datamodule, module, trainer = build(cfg)
        trainer.callbacks.append(probe)
        return datamodule, module, trainer

    monkeypatch.setattr(fitting, "build", build_with_probe)
    overrides = (_flowvo_overrides if network == "flowvo" else tiny_overrides)(tiny_kitti, tmp_path / "cache")
    mirror = "data.transforms=[{_target_:lossvo.data.transforms.Mirror,p:0.5}]"
    cfg = compose_train([*overrides, "trainer.max_epochs=2", mirror, f"data.loader.on_device={on_device}",
                         "+evaluate=false"], tmp_path / "run")  # fmt: skip
    with probe:
        fit(cfg)
    assert probe.steps >= 4
    assert probe.seen == []
