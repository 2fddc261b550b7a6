"""The test suite's wall time at two checkouts, interleaved: the median ratio of the second to the first.

Run: ``python benchmarks/suite_time.py BASE_DIR NEW_DIR --rounds 3``, each DIR a clone with its own ``.venv``
made there by ``make venv``: a copied venv's bytecode no longer matches its sources' times, and where
``PYTHONDONTWRITEBYTECODE`` is set every import then compiles again (sqlalchemy's import 2.7x slower). Each
round runs ``make test``'s pytest (``-m "not cluster"``, its xdist workers) once in each checkout, in
alternating order, on an otherwise idle machine; prints every run's seconds, pytest's counts, the per-round
ratios NEW / BASE with their median and spread, and the ratio with the order effect taken out (use an even
number of rounds). ruff and mypy, which ``make test`` runs beside the tests, are left out: they do not depend
on the suite.
"""

from __future__ import annotations

import argparse
import math
import re
import statistics
import subprocess
import time
from pathlib import Path

from scipy import stats

COMMAND = [".venv/bin/python", "-m", "pytest", "-m", "not cluster", "-q", "-p", "no:cacheprovider"]


def timed_suite(checkout: Path) -> tuple[float, str]:
    """Seconds of one run of the suite in ``checkout`` and pytest's summary line; an error if it fails."""
    start = time.perf_counter()
    done = subprocess.run(COMMAND, cwd=checkout, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    lines = done.stdout.strip().splitlines()
    summary = re.sub(r"=+", "", lines[-1]).strip() if lines else ""
    if done.returncode != 0:
        failed = [line for line in lines if line.startswith(("FAILED", "ERROR"))]
        raise SystemExit(
            f"{checkout}: the suite failed ({summary or done.stderr.strip()[-300:]})\n" + "\n".join(failed)
        )
    return seconds, summary


def order_balanced(ratios: list[float]) -> str:
    """The ratio with the order effect taken out, where both orders ran: the geometric mean of the two
    orders' geometric means (the run going first in a round can be some per cent slower), and its 90 %
    t-interval; rounds alternate: the 1st, 3rd, ... ran base first, the others new first."""
    groups = [[math.log(r) for r in ratios[start::2]] for start in (0, 1)]
    if min(map(len, groups)) < 2:
        return "order-balanced: needs two rounds in each order"
    effect = (statistics.mean(groups[0]) + statistics.mean(groups[1])) / 2
    error = math.sqrt(sum(statistics.variance(g) / len(g) for g in groups)) / 2
    half = float(stats.t.ppf(0.95, len(ratios) - 2)) * error
    order = (statistics.mean(groups[1]) - statistics.mean(groups[0])) / 2
    return (
        f"order-balanced: {math.exp(effect):.3f} (90 % interval {math.exp(effect - half):.3f}-"
        f"{math.exp(effect + half):.3f}); the run going first: {math.exp(order) - 1:+.1%} its time"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("base", type=Path)
    parser.add_argument("new", type=Path)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    ratios = []
    for number in range(args.rounds):
        order = (args.base, args.new) if number % 2 == 0 else (args.new, args.base)
        seconds = {}
        for checkout in order:
            seconds[checkout], summary = timed_suite(checkout)
            print(f"round {number + 1}: {checkout} {seconds[checkout]:.1f} s ({summary})", flush=True)
        ratios.append(seconds[args.new] / seconds[args.base])
    spread = f"{min(ratios):.3f}-{max(ratios):.3f}"
    rounds = ", ".join(f"{r:.3f}" for r in ratios)
    print(f"new / base: median {statistics.median(ratios):.3f} (rounds {rounds}; spread {spread})")
    print(order_balanced(ratios))


if __name__ == "__main__":
    main()
