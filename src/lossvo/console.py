"""Command-line plumbing: one-line argument errors, and printing a result also into a pipe that closes
early (``| head``)."""

from __future__ import annotations

import argparse
import os
import sys
from typing import NoReturn


def emit(text: str) -> None:
    """Print text and a newline to stdout. When the reader has gone (``BrokenPipeError``), the rest of
    the output is discarded quietly, as command-line tools do, instead of ending in a traceback."""
    try:
        print(text)
        sys.stdout.flush()
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # the interpreter's final flush then succeeds


class OneLineParser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line on stderr (no usage block), exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")
