"""The training step's operation count and time at a tiny size, this checkout against another one.

Run: ``.venv/bin/python benchmarks/step_ops.py --baseline ../before [--rounds 5 --steps 60]``.
On a GPU every aten operation of a small network's step is a kernel launch, and at a tiny size (compute
negligible) the count and the time per step measure the step's overhead, which a CPU shows too. Each side
trains through lossvo's ``VOModule`` under a Lightning ``Trainer`` (automatic optimisation, the module's
logging, the optimiser as its code configures it) on batches held in memory, one thread: FlowVO at 32x64
(pairs, 20 a batch) and DeepVO (deepvo_small's widths) at 64x64 (6 frames, 8 a batch), each with the euler,
quat and chordal losses. Counted with a ``TorchDispatchMode`` over one epoch: the operations of the
training step (forward, loss, the step's logging or record), the backward pass and the optimiser, per step.
Timed: epochs 2..N (the first is a warm-up), seconds per step. The sides run as separate processes, each
importing lossvo from its checkout's ``src``, in interleaved rounds (order alternating); printed per case:
each side's operations per step and the median ratio of step times (this / baseline) with its spread.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

CASES = [(n, loss) for n in ("flowvo", "deepvo") for loss in ("euler", "quat", "chordal")]
LOSSES = {"euler": "EulerLoss", "quat": "QuaternionLoss", "chordal": "ChordalLoss"}


def side(network: str, loss: str, steps: int, epochs: int) -> dict[str, Any]:
    """One side's counts and time (run in the side's own process)."""
    import lightning as L
    import torch
    from lightning.pytorch.loggers import CSVLogger
    from torch.utils._python_dispatch import TorchDispatchMode
    from torch.utils.data import DataLoader, Dataset

    import lossvo
    from lossvo import geometry as g
    from lossvo.training.module import VOModule

    torch.set_num_threads(1)
    dim = {"euler": 6, "quat": 7, "chordal": 6}[loss]
    if network == "flowvo":
        model = {"_target_": "lossvo.models.FlowVO", "out_dim": dim, "height": 32, "width": 64, "pool": 2,
                 "channels_last": True}  # fmt: skip
        batch_size, pairs = 20, 1
    else:
        model = {"_target_": "lossvo.models.DeepVO", "out_dim": dim, "height": 64, "width": 64,
                 "width_mult": 0.125, "hidden_size": 128, "conv_dropout": 0.0,
                 "channels_last": True}  # fmt: skip
        batch_size, pairs = 8, 5

    class Batches(Dataset):
        def __init__(self) -> None:
            data = torch.Generator().manual_seed(0)
            n = batch_size * steps
            self.targets = g.se3_exp(
                0.05 * torch.randn(n, pairs, 6, generator=data, dtype=torch.float64)
            ).float()
            if network == "flowvo":
                self.inputs = {
                    "flow": 3 * torch.randn(n, pairs, 2, 32, 64, generator=data),
                    "K": torch.tensor([[40.0, 0, 31.5], [0, 40.0, 15.5], [0, 0, 1]]).repeat(n, 1, 1),
                }
            else:
                self.inputs = {"frames": torch.randn(n, pairs + 1, 3, 64, 64, generator=data)}  # fmt: skip

        def __len__(self) -> int:
            return len(self.targets)

        def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
            return {"targets": self.targets[i], **{k: v[i] for k, v in self.inputs.items()}}

    class Phases(L.Callback, TorchDispatchMode):
        """Counts operations per phase of each training step (while ``counting``), and times epochs."""

        def __init__(self, counting: bool) -> None:
            L.Callback.__init__(self)
            TorchDispatchMode.__init__(self)
            self.counting, self.phase = counting, None
            self.counts: collections.Counter[str] = collections.Counter()
            self.steps, self.times, self.start = 0, [], 0.0

        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            if self.phase is not None:
                self.counts[self.phase] += 1
            return func(*args, **(kwargs or {}))

        def on_train_epoch_start(self, trainer, module) -> None:
            self.start = time.perf_counter()

        def on_train_epoch_end(self, trainer, module) -> None:
            self.times.append(time.perf_counter() - self.start)

        def on_train_batch_start(self, trainer, module, batch, batch_idx) -> None:
            self.phase = "step" if self.counting else None

        def on_before_backward(self, trainer, module, loss) -> None:
            self.phase = "backward" if self.counting else None

        def on_before_optimizer_step(self, trainer, module, optimizer) -> None:
            self.phase = "optimizer" if self.counting else None

        def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx) -> None:
            self.phase = None
            self.steps += 1

    def fit(epochs: int, counting: bool) -> Phases:
        torch.manual_seed(0)
        optimizer = {"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1e-3}
        module = VOModule(
            model=model, loss={"_target_": f"lossvo.losses.{LOSSES[loss]}"}, optimizer=optimizer
        )
        phases = Phases(counting)
        with tempfile.TemporaryDirectory() as tmp:
            trainer = L.Trainer(
                max_epochs=epochs, accelerator="cpu", devices=1, logger=CSVLogger(tmp, name="", version=""),
                callbacks=[phases], enable_checkpointing=False, enable_progress_bar=False,
                enable_model_summary=False, num_sanity_val_steps=0, limit_val_batches=0, log_every_n_steps=50,
            )  # fmt: skip
            loader = DataLoader(Batches(), batch_size=batch_size)
            if counting:
                with phases:
                    trainer.fit(module, train_dataloaders=loader)
            else:
                trainer.fit(module, train_dataloaders=loader)
        return phases

    counted = fit(1, counting=True)
    timed = fit(epochs, counting=False)
    per_step = {phase: n / counted.steps for phase, n in counted.counts.items()}
    return {"lossvo": str(Path(lossvo.__file__).parent), "ops": per_step, "total": sum(per_step.values()),
            "seconds_per_step": sum(timed.times[1:]) / (steps * (epochs - 1))}  # fmt: skip


def run_side(src: Path, network: str, loss: str, steps: int, epochs: int) -> dict[str, Any]:
    """:func:`side` in a process that imports lossvo from ``src``."""
    env = {**os.environ, "PYTHONPATH": str(src), "OMP_NUM_THREADS": "1", "PYTHONWARNINGS": "ignore"}
    command = [
        sys.executable,
        __file__,
        "--side",
        network,
        loss,
        "--steps",
        str(steps),
        "--epochs",
        str(epochs),
    ]
    out = subprocess.run(command, env=env, capture_output=True, text=True, check=True)
    result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    if Path(result["lossvo"]).resolve() != (src / "lossvo").resolve():
        raise RuntimeError(f"the side meant to import {src} imported {result['lossvo']}")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, help="another checkout (its src/ is imported)")
    parser.add_argument("--rounds", type=int, default=5, help="interleaved rounds of both sides")
    parser.add_argument("--steps", type=int, default=60, help="steps an epoch")
    parser.add_argument("--epochs", type=int, default=3, help="timed epochs + 1 warm-up")
    parser.add_argument("--cases", nargs="*", default=[f"{n}/{loss}" for n, loss in CASES])
    parser.add_argument("--side", nargs=2, metavar=("NETWORK", "LOSS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.side:
        print(json.dumps(side(*args.side, args.steps, args.epochs)))
        return
    here = Path(__file__).resolve().parent.parent / "src"
    sides = {"this": here, **({"baseline": args.baseline.resolve() / "src"} if args.baseline else {})}
    print(f"{args.rounds} rounds, {args.steps} steps an epoch, {args.epochs - 1} timed epochs, 1 thread; "
          + ", ".join(f"{k}: {v}" for k, v in sides.items()))  # fmt: skip
    header = f"{'case':16s} " + " ".join(f"{k + ' ops/step (step+bwd+opt)':>36s}" for k in sides)
    print(header + ("  time this/baseline: median (min-max)" if len(sides) == 2 else "  ms/step"))
    for case in args.cases:
        network, loss = case.split("/")
        results: dict[str, list[dict[str, Any]]] = {k: [] for k in sides}
        for r in range(args.rounds):
            for name in sorted(sides, reverse=r % 2 == 1):
                results[name].append(run_side(sides[name], network, loss, args.steps, args.epochs))
        cells = []
        for name in sides:
            ops = results[name][0]["ops"]
            parts = "+".join(f"{ops.get(p, 0):.0f}" for p in ("step", "backward", "optimizer"))
            cells.append(f"{results[name][0]['total']:7.0f} ({parts})")
        line = f"{case:16s} " + " ".join(f"{c:>36s}" for c in cells)
        if len(sides) == 2:
            ratios = [a["seconds_per_step"] / b["seconds_per_step"]
                      for a, b in zip(results["this"], results["baseline"], strict=True)]  # fmt: skip
            line += f"  {statistics.median(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f})"
        else:
            line += f"  {1e3 * statistics.median(r['seconds_per_step'] for r in results['this']):.2f}"
        print(line, flush=True)


if __name__ == "__main__":
    main()
