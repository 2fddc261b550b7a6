"""Training throughput: lossvo's Lightning path vs a bare PyTorch loop, same model and batches.

Run: ``.venv/bin/python benchmarks/training_throughput.py [--epochs 3 --windows 256 --device cpu]``.
Both train DeepVO (deepvo_small's settings) with the chordal loss and Adam on the same in-memory
uint8 windows (seq_len 6, 64x208, batch 8) through the same DataLoader, normalising each batch the
same way. The Lightning path is lossvo's: ``VOModule`` under a ``Trainer`` that logs every loss key
per epoch to CSV (checkpointing and progress output off, as they are per-epoch costs). The first
epoch of each is a warm-up and is not timed. Prints frame pairs per second and the ratio.
"""

from __future__ import annotations

import argparse
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
        return normalize(batch[0]), batch[1]


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
    parser.add_argument("--epochs", type=int, default=3, help="the first is a warm-up")
    parser.add_argument("--windows", type=int, default=256)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    dataset = make_windows(args.windows)
    pairs = (args.epochs - 1) * args.windows * (dataset.tensors[0].shape[1] - 1)
    params = sum(
        p.numel() for p in DeepVO(**{k: v for k, v in MODEL.items() if k != "_target_"}).parameters()
    )
    print(f"DeepVO {params / 1e6:.2f}M parameters, {args.windows} windows x 5 pairs, "
          f"batch {args.batch_size}, {args.device}, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads")  # fmt: skip
    bare = pairs / bare_seconds(dataset, args.epochs, args.batch_size, args.device)
    lightning = pairs / lightning_seconds(dataset, args.epochs, args.batch_size, args.device)
    print(f"bare PyTorch loop:      {bare:8.1f} pairs/s")
    print(f"lossvo (Lightning):     {lightning:8.1f} pairs/s")
    print(f"ratio lossvo / bare:    {lightning / bare:8.3f}")


if __name__ == "__main__":
    main()
