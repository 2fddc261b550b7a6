"""Printing a command's result to standard output, also into a pipe that closes early (``| head``)."""

from __future__ import annotations

import os
import sys


def emit(text: str) -> None:
    """Print text and a newline to stdout. When the reader has gone (``BrokenPipeError``), the rest of
    the output is discarded quietly, as command-line tools do, instead of ending in a traceback."""
    try:
        print(text)
        sys.stdout.flush()
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # the interpreter's final flush then succeeds
