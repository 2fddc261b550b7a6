"""Loss forward + backward time per batch (B=32, T=6), vectorised vs a per-pair Python loop.

Run: ``make bench`` or ``.venv/bin/python benchmarks/losses.py [--batch 32 --steps 6]``.
Prints, per loss, the vectorised time per batch and per frame pair, the time of the same formula
evaluated one pair at a time in a Python loop (how earlier implementations wrote it), and the ratio.
"""

from __future__ import annotations

import argparse
import platform

import torch
from torch.utils import benchmark

from lossvo import geometry as g
from lossvo.losses import (
    ChordalLoss,
    EulerLoss,
    GeodesicLoss,
    PoseLoss,
    QuaternionLoss,
    SixDLoss,
    SVDLoss,
    SymMatrixQuatLoss,
)


def make_batch(loss: PoseLoss, B: int, T: int, device: str) -> tuple[torch.Tensor, torch.Tensor]:
    """A random prediction (B, T, dim) and random relative-pose targets (B, T, 4, 4), float32."""
    gen = torch.Generator().manual_seed(0)
    target = g.se3_exp(0.3 * torch.randn(B, T, 6, generator=gen, dtype=torch.float64)).float()
    pred = torch.randn(B, T, loss.dim, generator=gen)
    return pred.to(device).requires_grad_(), target.to(device)


def vectorised_step(loss: PoseLoss, pred: torch.Tensor, target: torch.Tensor) -> None:
    pred.grad = None
    loss(pred, target)["loss"].backward()


def loop_step(loss: PoseLoss, pred: torch.Tensor, target: torch.Tensor) -> None:
    """The same mean loss, one frame pair at a time."""
    pred.grad = None
    B, T = pred.shape[:2]
    total = sum(loss(pred[b, t], target[b, t])["loss"] for b in range(B) for t in range(T))
    (total / (B * T)).backward()


def time_ms(fn, *args, min_run_time: float) -> float:
    timer = benchmark.Timer("fn(*args)", globals={"fn": fn, "args": args})
    return timer.blocked_autorange(min_run_time=min_run_time).median * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--steps", type=int, default=6)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--min-run-time", type=float, default=1.0, help="seconds per measurement")
    args = parser.parse_args()
    B, T = args.batch, args.steps
    print(
        f"torch {torch.__version__}, {platform.processor() or platform.machine()}, "
        f"{torch.get_num_threads()} threads, device {args.device}, B={B}, T={T} ({B * T} pairs)"
    )
    print(f"{'loss':<16}{'ms/batch':>10}{'µs/pair':>10}{'loop ms/batch':>15}{'loop / vectorised':>19}")
    for cls in (EulerLoss, QuaternionLoss, ChordalLoss, GeodesicLoss, SixDLoss, SVDLoss, SymMatrixQuatLoss):
        loss = cls()
        pred, target = make_batch(loss, B, T, args.device)
        fast = time_ms(vectorised_step, loss, pred, target, min_run_time=args.min_run_time)
        slow = time_ms(loop_step, loss, pred, target, min_run_time=args.min_run_time)
        print(
            f"{cls.__name__:<16}{fast:>10.3f}{fast * 1e3 / (B * T):>10.2f}{slow:>15.2f}{slow / fast:>18.1f}x"
        )


if __name__ == "__main__":
    main()
