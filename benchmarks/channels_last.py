"""DeepVO training step (forward, loss, backward, Adam) in the channels-last vs the contiguous layout.

Run: ``make bench`` or ``.venv/bin/python benchmarks/channels_last.py [--rounds 8 --steps 10 --threads 1]``.
The two sides alternate in repeated rounds (A B A B ...), each timing ``--steps`` steps after a warm-up,
so drift in the machine's speed hits both; prints each round and the median ratio channels_last /
contiguous with its min and max. Default: the CPU network of the default sweep (deepvo_small, 8 windows
of 6 frames at 64x208, one thread as each job of ``make sweep`` gets).
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import torch

from lossvo.losses import ChordalLoss
from lossvo.models import DeepVO


def side(channels_last: bool, args: argparse.Namespace) -> tuple[DeepVO, torch.optim.Optimizer]:
    torch.manual_seed(0)
    size = {"height": args.height, "width": args.width, "width_mult": args.width_mult, "hidden_size": 128}
    model = DeepVO(out_dim=6, **size, conv_dropout=0.0, channels_last=channels_last).to(args.device)
    return model, torch.optim.Adam(model.parameters(), lr=1e-3)


def seconds_per_step(model: DeepVO, optimizer: torch.optim.Optimizer, batch, steps: int) -> float:
    frames, targets = batch
    loss = ChordalLoss()
    if frames.is_cuda:
        torch.cuda.synchronize()
    start = time.perf_counter()
    for _ in range(steps):
        optimizer.zero_grad(set_to_none=True)
        loss(model(frames), targets)["loss"].backward()
        optimizer.step()
    if frames.is_cuda:
        torch.cuda.synchronize()
    return (time.perf_counter() - start) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--seq-len", type=int, default=6)
    parser.add_argument("--height", type=int, default=64)
    parser.add_argument("--width", type=int, default=208)
    parser.add_argument("--width-mult", type=float, default=0.125)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    gen = torch.Generator().manual_seed(1)
    frames = torch.randn(args.batch, args.seq_len, 3, args.height, args.width, generator=gen).to(args.device)
    targets = torch.eye(4).expand(args.batch, args.seq_len - 1, 4, 4).contiguous().to(args.device)
    sides = {"channels_last": side(True, args), "contiguous": side(False, args)}
    for model, optimizer in sides.values():
        seconds_per_step(model, optimizer, (frames, targets), 3)  # warm-up
    machine = platform.processor() or platform.machine()
    print(f"{machine}, torch {torch.__version__}, {args.threads} thread(s), "
          f"batch {args.batch}x{args.seq_len} at {args.height}x{args.width}, {args.device}")  # fmt: skip
    ratios = []
    for r in range(args.rounds):
        a = seconds_per_step(*sides["channels_last"], (frames, targets), args.steps)
        b = seconds_per_step(*sides["contiguous"], (frames, targets), args.steps)
        ratios.append(a / b)
        print(f"round {r + 1}: channels_last {a * 1e3:.1f} ms/step, contiguous {b * 1e3:.1f} ms/step, "
              f"ratio {a / b:.3f}")  # fmt: skip
    print(f"channels_last / contiguous step time: median {statistics.median(ratios):.3f} "
          f"(min {min(ratios):.3f}, max {max(ratios):.3f}, {len(ratios)} rounds)")  # fmt: skip


if __name__ == "__main__":
    main()
