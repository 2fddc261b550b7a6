"""A sweep folder -> the study's tables and figures: ``python -m lossvo.report SWEEP_DIR [--out DIR]``.

Prints the path of ``report.md``; bad input is a one-line error, exit status 2. See docs/report.md.
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from lossvo.console import OneLineParser, UserError, emit, one_line_main
from lossvo.report.claims import CLAIMED_LOSS
from lossvo.report.document import make_report
from lossvo.report.jobs import job_dirs, latest_sweep, load_job
from lossvo.report.statistics import MARGIN

log = logging.getLogger("lossvo")


def parser() -> argparse.ArgumentParser:
    """The command line's parser."""
    out = OneLineParser(prog="python -m lossvo.report", description=__doc__.splitlines()[0])
    out.add_argument(
        "sweep_dir",
        type=Path,
        help="a sweep folder (outputs/multirun/<time>), or with --latest the folder holding sweeps",
    )
    out.add_argument("--out", type=Path, default=None, help="output folder (default SWEEP_DIR/report)")
    out.add_argument("--latest", action="store_true", help="report the newest sweep under SWEEP_DIR")
    out.add_argument("--no-baselines", action="store_true", help="skip the zero / mean / ORB baselines")
    out.add_argument("--no-figures", action="store_true", help="write the tables only")
    out.add_argument(
        "--margin",
        type=float,
        default=MARGIN,
        help=f"equivalence margin δ, a fraction in (0, 1) (default {MARGIN:g}: within ±{100 * MARGIN:g} %%)",
    )
    out.add_argument(
        "--claimed-loss",
        default=CLAIMED_LOSS,
        metavar="CLASS",
        help=f"the loss class (of loss._target_) whose configurations the claims are about "
        f"(default {CLAIMED_LOSS})",
    )
    out.add_argument(
        "--jobs",
        type=int,
        default=None,
        help="sequences computed in parallel for the baselines (default: CPU count)",
    )
    return out


def check_writable(out: Path, given: bool) -> None:
    """UserError, before any work, where ``out`` (``given`` by ``--out``) cannot be written."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as e:
        cause = e.strerror or type(e).__name__
        hint = "give a writable folder" if given else "write the report elsewhere with --out DIR"
        raise UserError(
            f"{'--out: ' if given else ''}{out}: cannot write the report there ({cause}): {hint}"
        ) from None


@one_line_main
def main(argv: Sequence[str] | None = None) -> int:
    """``python -m lossvo.report``; returns the exit status."""
    command = parser()
    args = command.parse_args(argv)
    if args.jobs is not None and args.jobs < 1:
        command.error(f"--jobs: expected an integer >= 1, got {args.jobs}")
    if not 0 < args.margin < 1:
        command.error(f"--margin: expected a fraction between 0 and 1 (0.05: ±5 %), got {args.margin:g}")
    if not args.claimed_loss.isidentifier():
        command.error(f"--claimed-loss: expected a loss class name (ChordalLoss), got {args.claimed_loss!r}")
    if args.out is not None and args.out.exists() and not args.out.is_dir():
        command.error(f"--out: {args.out} is a file, expected a folder")
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
    start = time.perf_counter()
    sweep = latest_sweep(args.sweep_dir) if args.latest else args.sweep_dir
    jobs = [load_job(p) for p in job_dirs(sweep)]  # a folder that is no sweep is refused first
    check_writable(args.out if args.out is not None else sweep / "report", args.out is not None)
    path = make_report(
        sweep, args.out, not args.no_baselines, not args.no_figures, args.jobs, args.margin, args.claimed_loss
    )
    log.info("report written in %.1f s", time.perf_counter() - start)
    for job in jobs:
        if not job.included:
            log.warning("left out %s: %s", job.path.name, job.skip)
    emit(str(path))
    if not any(job.included for job in jobs):
        raise UserError(
            f"{sweep}: no job has results to report ({len(jobs)} left out, each named above): {path}"
        )
    return 0
