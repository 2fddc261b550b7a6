"""The command line, ``python -m lossvo.data.synthetic --out DIR [--layout L] [--sequences 00,07] ...``
(``--help``); bad values end in one line on stderr and exit status 2, before anything is written."""

from __future__ import annotations

import argparse
import logging
import sys
import time
from collections.abc import Iterable
from pathlib import Path

from lossvo.console import OneLineParser, UserError, one_line_main, raise_if_full_error
from lossvo.data.synthetic import layouts, routes, writer

DESCRIPTION = (
    "Synthetic dataset: a procedural town rendered along car-like routes, in the KITTI odometry layout or "
    "another dataset's (TUM RGB-D, EuRoC, TartanAir, MIMIR)."
)


def _seed(text: str) -> int:
    """``--seed``: an integer >= 0 (numpy's generators take no negative seed)."""
    try:
        seed = int(text)
    except ValueError:
        seed = -1
    if seed < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return seed


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m lossvo.data.synthetic", description=DESCRIPTION)
    p.add_argument("--out", type=Path, required=True, help="dataset root to write")
    p.add_argument(
        "--layout",
        default="kitti",
        choices=layouts.LAYOUTS,
        help="the dataset layout to write (default: kitti)",
    )
    p.add_argument(
        "--sequences",
        default=",".join(writer.SEQUENCES),
        help="comma-separated, e.g. 00,07 (default: 00..12)",
    )
    p.add_argument("--frames", type=int, help="frames per sequence (default: 100-240 by sequence)")
    p.add_argument(
        "--scale",
        type=float,
        default=1.0,
        help="times the layout's default size (kitti 160x512, tum/tartanair 640x480, "
        "euroc 752x480, mimir 720x540; default: 1)",
    )
    p.add_argument("--height", type=int, help="pixels (default: the layout's, kitti 160, times --scale)")
    p.add_argument("--width", type=int, help="pixels (default: the layout's, kitti 512, times --scale)")

    p.add_argument(
        "--seed", type=_seed, default=0, help="an integer >= 0; same seed, same bytes (default: 0)"
    )
    p.add_argument(
        "--workers", type=int, help="processes (default: one per core; one below 10 million pixels in all)"
    )
    example = "11=stop_and_go:2+expressway"
    p.add_argument(
        "--mix",
        action="append",
        default=[],
        metavar="NN=FAMILY[:W][+FAMILY[:W]]",
        help=f"route families of a sequence, e.g. {example} (repeatable)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


def parse_mix(text: str) -> tuple[str, dict[str, float]]:
    """'11=stop_and_go:2+expressway' -> ('11', {'stop_and_go': 2.0, 'expressway': 1.0}); UserError."""
    sequence, sep, body = text.partition("=")
    if not sep or not body:
        raise UserError(f"--mix: expected NN=FAMILY[:WEIGHT][+FAMILY[:WEIGHT]], got {text!r}")
    mix = {}
    for item in body.split("+"):
        name, _, weight = item.partition(":")
        try:
            mix[name.strip()] = float(weight) if weight else 1.0
        except ValueError:
            raise UserError(f"--mix {text}: the weight of {name!r} is not a number: {weight!r}") from None
    try:
        routes.check_mix(mix)
    except UserError as err:
        raise UserError(f"--mix {text}: {err}") from None
    return writer.parse_sequences(sequence, "--mix")[0], mix


@one_line_main
def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the exit status (2 and a one-line message for bad values)."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        counts = writer.resolve_frames(args.sequences, args.frames, prefix="--")
        height, width = writer.frame_size(args.layout, args.height, args.width, args.scale, prefix="--")
        if args.workers is not None and args.workers < 1:
            raise UserError(f"--workers: must be >= 1, got {args.workers}")
        spec = routes.route_spec(mixes=dict(parse_mix(m) for m in args.mix))
        if args.out.exists() and not args.out.is_dir():
            raise UserError(f"--out: {args.out} is a file, expected a folder")
    except UserError as err:
        raise_if_full_error()
        parser.error(str(err))
    progress = not args.quiet
    if progress:  # the writer's line per sequence, on stderr as the final one
        writer.log.addHandler(logging.StreamHandler(sys.stderr))
        writer.log.setLevel(logging.INFO)

    start = time.perf_counter()
    try:
        out = writer.generate(
            args.out, counts, counts, height, width, args.seed, progress, args.workers, spec, args.layout
        )
    except OSError as err:  # a folder it may not write to, a full disk
        raise_if_full_error()
        parser.error(f"--out: cannot write {err.filename or args.out}: {err.strerror or err}")
    if progress:
        size = dataset_size(out, counts, args.layout)

        elapsed = time.perf_counter() - start
        print(f"synthetic: wrote {out} in {elapsed:.1f} s, {size / 1e6:.0f} MB", file=sys.stderr)
    return 0


def dataset_size(root: Path, sequences: Iterable[str], layout: str = "kitti") -> int:
    """Bytes on disk of the given sequences' files."""
    paths = [root / p for s in sequences for p in layouts.sequence_paths(layout, s)]
    return sum(f.stat().st_size for p in paths for f in [p, *p.rglob("*")] if f.is_file())
