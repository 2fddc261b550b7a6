"""What a dataset holds: its sequences, the frames of each and the image size; defaults and checks. The
default size, 160 x 512, is KITTI's 376 x 1241 scaled by about 0.42 (K scaled per axis)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from lossvo.console import UserError
from lossvo.data.sequence import sequence_name
from lossvo.data.synthetic import routes

DEFAULT_HEIGHT = 160
DEFAULT_WIDTH = 512
SEQUENCES = tuple(map(sequence_name, range(11))) + routes.UNSEEN_SEQUENCES
DEFAULT_FRAMES = {
    "00": 240, "01": 120, "02": 240, "03": 120, "04": 100, "05": 200,
    "06": 150, "07": 120, "08": 240, "09": 150, "10": 120, "11": 150, "12": 150,
}  # fmt: skip
"""Frames per sequence when none are given; sequences not listed get FALLBACK_FRAMES."""
FALLBACK_FRAMES = 150
MIN_FRAMES = 2
MIN_SIZE = 32
MAX_SIZE = 4096


def parse_sequences(text: str, label: str = "sequences") -> tuple[str, ...]:
    """'00,07' -> ('00', '07'): comma-separated two-digit sequence numbers, duplicates dropped."""
    names = [s.strip() for s in text.split(",")]
    if not names or any(len(s) != 2 or not s.isdigit() for s in names):
        raise UserError(f"{label}: expected two-digit sequence numbers like 00,07, got {text!r}")
    return tuple(dict.fromkeys(names))


def resolve_frames(
    sequences: Iterable[str], frames: int | Mapping[str, int] | None, prefix: str = ""
) -> dict[str, int]:
    """Frames per sequence: DEFAULT_FRAMES (None), one count for all (int) or a mapping; validated.

    prefix is put before the parameter names in error messages ("--" for the command line).
    """
    text = sequences if isinstance(sequences, str) else ",".join(sequences)
    sequences = parse_sequences(text, f"{prefix}sequences")
    if frames is None:
        counts = {s: DEFAULT_FRAMES.get(s, FALLBACK_FRAMES) for s in sequences}
    elif isinstance(frames, Mapping):
        counts = {s: int(frames[s]) for s in sequences}
    else:
        counts = dict.fromkeys(sequences, int(frames))
    for n in counts.values():
        if n < MIN_FRAMES:
            raise UserError(f"{prefix}frames: must be >= {MIN_FRAMES}, got {n}")
    return counts


def check_size(height: int, width: int, prefix: str = "") -> None:
    """Raise UserError unless MIN_SIZE <= height, width <= MAX_SIZE pixels (prefix: as resolve_frames)."""
    for name, value in (("height", height), ("width", width)):
        if not MIN_SIZE <= value <= MAX_SIZE:
            raise UserError(f"{prefix}{name}: must be between {MIN_SIZE} and {MAX_SIZE} pixels, got {value}")
