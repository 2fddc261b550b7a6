"""Training steps of DeepVO (deepvo_small's settings) eager vs under ``torch.compile`` (inductor).

Run: ``.venv/bin/python benchmarks/compile.py [--rounds 7 --steps 20 --threads 1]``.
Both sides train the same network (same initial weights) with the chordal loss and Adam on the same
batches of 8 windows (seq_len 6, 64x208): forward, loss, backward and the optimiser step, as in a
training epoch. One thread by default, as each of ``make sweep``'s two parallel jobs runs. The first
call of the compiled side (tracing and code generation, or a hit in inductor's on-disk cache) is timed
apart and excluded; then the sides run in interleaved rounds of ``--steps`` steps (alternating which
goes first), and the median step time of each, the median ratio and its spread over rounds are printed,
with the work of a step (floating-point operations counted by ``torch.utils.flop_counter``) and the
rate each side achieves.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from torch.utils.flop_counter import FlopCounterMode

from lossvo import geometry as g
from lossvo.losses import ChordalLoss
from lossvo.models import DeepVO

MODEL = {"out_dim": 6, "height": 64, "width": 208, "width_mult": 0.125, "hidden_size": 128,
         "conv_dropout": 0.0, "channels_last": True}  # fmt: skip


def make_batches(n: int, batch: int = 8, seq_len: int = 6) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """``n`` batches of normalised random frames (batch, seq_len, 3, 64, 208) and pose targets."""
    gen = torch.Generator().manual_seed(0)
    return [
        (torch.randn(batch, seq_len, 3, 64, 208, generator=gen),
         g.se3_exp(0.1 * torch.randn(batch, seq_len - 1, 6, generator=gen, dtype=torch.float64)).float())
        for _ in range(n)
    ]  # fmt: skip


class Side:
    """One network, its forward (eager or compiled) and its optimiser."""

    def __init__(self, compiled: bool) -> None:
        torch.manual_seed(0)
        self.model = DeepVO(**MODEL).train()
        self.forward = torch.compile(self.model) if compiled else self.model
        self.loss = ChordalLoss()
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=1e-3)

    def step(self, frames: torch.Tensor, targets: torch.Tensor) -> None:
        self.optimizer.zero_grad(set_to_none=True)
        self.loss(self.forward(frames), targets)["loss"].backward()
        self.optimizer.step()

    def seconds_per_step(self, batches: list[tuple[torch.Tensor, torch.Tensor]]) -> float:
        start = time.perf_counter()
        for frames, targets in batches:
            self.step(frames, targets)
        return (time.perf_counter() - start) / len(batches)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7, help="interleaved rounds of both sides")
    parser.add_argument("--steps", type=int, default=20, help="training steps per side and round")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    batches = make_batches(args.steps)
    sides = {"eager": Side(compiled=False), "compiled": Side(compiled=True)}
    with FlopCounterMode(display=False) as counter:
        Side(compiled=False).step(*batches[0])
    gflop = counter.get_total_flops() / 1e9
    first = {}
    for name, side in sides.items():
        start = time.perf_counter()
        side.step(*batches[0])
        first[name] = time.perf_counter() - start
    print(f"torch {torch.__version__}, {args.threads} thread(s), {args.rounds} rounds of {args.steps} steps; "
          f"first step: eager {first['eager']:.2f} s, compiled {first['compiled']:.1f} s "
          f"(compilation, or inductor's cache)")  # fmt: skip
    times: dict[str, list[float]] = {name: [] for name in sides}
    for r in range(args.rounds):  # both sides every round, in alternating order: drift hits both
        for name in sorted(sides, reverse=r % 2 == 1):
            times[name].append(sides[name].seconds_per_step(batches))
    print(f"{gflop:.2f} GFLOP a step (forward and backward)")
    for name, values in times.items():
        median = statistics.median(values)
        print(f"{name + ':':10s} median {1000 * median:6.1f} ms a step, {gflop / median:5.1f} GFLOP/s "
              f"(min {1000 * min(values):.1f}, max {1000 * max(values):.1f})")  # fmt: skip
    ratios = [c / e for c, e in zip(times["compiled"], times["eager"], strict=True)]
    print(
        f"ratio compiled / eager: median {statistics.median(ratios):.3f} (min {min(ratios):.3f}, "
        f"max {max(ratios):.3f}, per round: {', '.join(f'{x:.3f}' for x in ratios)})"
    )


if __name__ == "__main__":
    main()
