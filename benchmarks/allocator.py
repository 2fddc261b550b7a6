"""Training epochs under glibc's default allocator settings vs settings that keep freed memory in the
process, and one job alone vs two side by side: what the study's jobs lose to page faults and to sharing.

Run: ``.venv/bin/python benchmarks/allocator.py [--rounds 3 --batches 150 --experiment mix]``.
Each measurement is ``python -m lossvo.train experiment=<experiment> loss=chordal threads=1`` for one
epoch of ``--batches`` training batches (5 validation batches), the epoch's time read from its log and
the process's minor page faults from ``getrusage``. Four sides in interleaved rounds (the order rotates
each round): ``default`` and ``kept`` (glibc's settings as the study sets them for its jobs,
:data:`lossvo.study.KEPT_MEMORY`) alone, and both again as two processes at once (``x2``: the mean of the
two epochs). Prints each side's median epoch time and faults, and the median ratio to
``default`` with its spread over rounds. Wants an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from lossvo.study import KEPT_MEMORY

EPOCH = re.compile(r"epoch 1/1 \(([0-9.]+) s\)")


def command(args: argparse.Namespace, out: Path) -> list[str]:
    return [
        sys.executable, "-m", "lossvo.train", f"experiment={args.experiment}", "loss=chordal", "seed=0",
        "threads=1", "trainer.max_epochs=1", f"+trainer.limit_train_batches={args.batches}",
        "+trainer.limit_val_batches=5", "logger=csv", f"hydra.run.dir={out}",
    ]  # fmt: skip


def run(args: argparse.Namespace, kept: bool, copies: int) -> tuple[float, float]:
    """The mean epoch time (s) and minor page faults of ``copies`` runs at once."""
    env = {**os.environ, **(KEPT_MEMORY if kept else {})}
    with tempfile.TemporaryDirectory() as tmp:
        outs = [Path(tmp) / f"run{i}" for i in range(copies)]
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_minflt
        quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
        procs = [subprocess.Popen(command(args, out), env=env, **quiet) for out in outs]
        if any(p.wait() for p in procs):
            sys.exit(f"a run failed: {' '.join(command(args, outs[0]))}")
        faults = (resource.getrusage(resource.RUSAGE_CHILDREN).ru_minflt - before) / copies
        times = [float(EPOCH.findall((out / "train.log").read_text())[-1]) for out in outs]
    return statistics.fmean(times), faults


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--batches", type=int, default=150)
    p.add_argument("--experiment", default="mix")
    args = p.parse_args()
    sides = {"default": (False, 1), "kept": (True, 1), "default x2": (False, 2), "kept x2": (True, 2)}
    results: dict[str, list[tuple[float, float]]] = {name: [] for name in sides}
    names = list(sides)
    for r in range(args.rounds):
        for name in names[r % len(names) :] + names[: r % len(names)]:
            start = time.perf_counter()
            epoch, faults = run(args, *sides[name])
            results[name].append((epoch, faults))
            took = time.perf_counter() - start
            line = f"round {r + 1} {name}: epoch {epoch:.1f} s, {faults:,.0f} faults ({took:.0f} s)"
            print(line, flush=True)
    base = [t for t, _ in results["default"]]
    for name, values in results.items():
        ratios = [t / b for (t, _), b in zip(values, base, strict=True)]
        print(f"{name:>11}: epoch {statistics.median(t for t, _ in values):6.1f} s, "
              f"{statistics.median(f for _, f in values):>10,.0f} faults, vs default "
              f"{statistics.median(ratios):.3f}x [{min(ratios):.3f}, {max(ratios):.3f}]")  # fmt: skip


if __name__ == "__main__":
    main()
