"""Training throughput: lossvo's Lightning path vs a bare PyTorch loop, same model and batches.

Run: ``.venv/bin/python benchmarks/training_throughput.py [--rounds 5 --epochs 3 --windows 256]``.
Both train DeepVO (deepvo_small's settings) with the chordal loss and Adam on the same in-memory
uint8 windows (seq_len 6, 64x208, batch 8) through the same DataLoader, normalising each batch the
same way. The Lightning path is lossvo's: ``VOModule`` under a ``Trainer`` that logs every loss key
per epoch to CSV (checkpointing and progress output off, as they are per-epoch costs). The first
epoch of each measurement is a warm-up and is not timed. The two sides run in interleaved rounds
(alternating which goes first), so that machine noise and drift reach both; prints the median rate of
each, the median ratio and its spread over rounds.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time

import lightning as L
import torch
from lightning.pytorch.loggers import CSVLogger
from torch.utils.data import DataLoader, TensorDataset

from lossvo import geometry as g
from lossvo.models import DeepVO
from lossvo.training.module import VOModule

MODEL = {"_target_": "lossvo.models.DeepVO", "out_dim": 6, "height": 64, "width": 208, "width_mult": 0.125,
         "hidden_size": 128, "conv_dropout": 0.0}  # fmt: skip
LOSS = {"_target_": "lossvo.losses.ChordalLoss"}
OPTIMIZER = {"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1e-3}


def make_windows(n: int, seq_len: int = 6) -> TensorDataset:
    """``n`` random uint8 windows (seq_len, 3, 64, 208) with random relative-pose targets."""
    gen = torch.Generator().manual_seed(0)
    frames = torch.randint(0, 256, (n, seq_len, 3, 64, 208), generator=gen, dtype=torch.uint8)
    targets = g.se3_exp(0.1 * torch.randn(n, seq_len - 1, 6, generator=gen, dtype=torch.float64)).float()
    return TensorDataset(frames, targets)


def normalize(frames: torch.Tensor) -> torch.Tensor:
    return frames.float().mul_(1.0 / 255.0).sub_(0.5)


class Windows(L.LightningDataModule):
    def __init__(self, dataset: TensorDataset, batch_size: int) -> None:
        super().__init__()
        self.dataset, self.batch_size = dataset, batch_size

    def train_dataloader(self) -> DataLoader:
        return DataLoader(self.dataset, batch_size=self.batch_size, shuffle=False)

    def on_after_batch_transfer(self, batch, dataloader_idx: int):
        return {"frames": normalize(batch[0]), "targets": batch[1]}


class EpochTimer(L.Callback):
    """Wall time of every training epoch."""

    def __init__(self) -> None:
        self.times: list[float] = []

    def on_train_epoch_start(self, trainer, pl_module) -> None:
        self._start = time.perf_counter()

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        if trainer.strategy.root_device.type == "cuda":
            torch.cuda.synchronize()
        self.times.append(time.perf_counter() - self._start)


def lightning_seconds(dataset: TensorDataset, epochs: int, batch_size: int, device: str) -> float:
    """Seconds for epochs 2..N under lossvo's module and a Lightning Trainer."""
    torch.manual_seed(0)
    module = VOModule(model=MODEL, loss=LOSS, optimizer=OPTIMIZER)
    timer = EpochTimer()
    with tempfile.TemporaryDirectory() as tmp:
        trainer = L.Trainer(
            max_epochs=epochs, accelerator=device, devices=1, logger=CSVLogger(tmp, name="", version=""),
            callbacks=[timer], enable_checkpointing=False, enable_progress_bar=False,
            enable_model_summary=False, num_sanity_val_steps=0, limit_val_batches=0, log_every_n_steps=50,
        )  # fmt: skip
        trainer.fit(module, datamodule=Windows(dataset, batch_size))
    return sum(timer.times[1:])


def bare_seconds(dataset: TensorDataset, epochs: int, batch_size: int, device: str) -> float:
    """Seconds for epochs 2..N of the same training in a plain PyTorch loop."""
    torch.manual_seed(0)
    module = VOModule(model=MODEL, loss=LOSS, optimizer=OPTIMIZER)  # same construction and init
    model, loss = module.model.to(device).train(), module.loss
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    loader = DataLoader(dataset, batch_size=batch_size, shuffle=False)
    times = []
    for _ in range(epochs):
        start = time.perf_counter()
        for frames, targets in loader:
            frames, targets = normalize(frames.to(device)), targets.to(device)
            out = loss(model(frames), targets)
            optimizer.zero_grad(set_to_none=True)
            out["loss"].backward()
            optimizer.step()
        if device == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - start)
    return sum(times[1:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=3, help="per measurement; the first is a warm-up")
    parser.add_argument("--windows", type=int, default=256)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--rounds", type=int, default=5, help="interleaved rounds of both sides")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    dataset = make_windows(args.windows)
    pairs = (args.epochs - 1) * args.windows * (dataset.tensors[0].shape[1] - 1)
    params = sum(
        p.numel() for p in DeepVO(**{k: v for k, v in MODEL.items() if k != "_target_"}).parameters()
    )
    print(f"DeepVO {params / 1e6:.2f}M parameters, {args.windows} windows x 5 pairs, "
          f"batch {args.batch_size}, {args.device}, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads, {args.rounds} rounds")  # fmt: skip
    sides = {"bare": bare_seconds, "lightning": lightning_seconds}
    rates: dict[str, list[float]] = {name: [] for name in sides}
    for r in range(args.rounds):  # both sides every round, in alternating order: drift hits both
        for name in sorted(sides, reverse=r % 2 == 1):
            rates[name].append(pairs / sides[name](dataset, args.epochs, args.batch_size, args.device))
    ratios = [lit / bare for lit, bare in zip(rates["lightning"], rates["bare"], strict=True)]
    for name, label in (("bare", "bare PyTorch loop"), ("lightning", "lossvo (Lightning)")):
        print(f"{label + ':':22s} median {statistics.median(rates[name]):8.1f} pairs/s "
              f"(min {min(rates[name]):.1f}, max {max(rates[name]):.1f})")  # fmt: skip
    print(f"ratio lossvo / bare:   median {statistics.median(ratios):.3f} "
          f"(min {min(ratios):.3f}, max {max(ratios):.3f}, per round: "
          f"{', '.join(f'{x:.3f}' for x in ratios)})")  # fmt: skip


if __name__ == "__main__":
    main()
