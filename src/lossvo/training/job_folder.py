"""A job folder's state across runs: ``status.json``, and what a run started in that folder does.

``status.json`` is ``{"status": "running" | "completed" | "failed" | "interrupted", ...}``: the metrics
of a completed job, the error of a failed one, the signal and epoch of an interrupted one. Started again
in the same folder (a requeued cluster job, or a sweep re-run with the same ``hydra.sweep.dir``), a job
with ``resume=true`` (the default) skips itself if it completed and continues from ``checkpoints/
last.ckpt`` if it was interrupted or killed (status still "running"); otherwise it starts afresh.
"""

from __future__ import annotations

import json
import signal
from pathlib import Path
from typing import Any

from lightning.pytorch.utilities import rank_zero_only

from lossvo.atomic import write_text_atomic

LAST_CHECKPOINT = Path("checkpoints") / "last.ckpt"


class InterruptedRun(Exception):  # noqa: N818 (a run, not an error)
    """A fit stopped by SIGINT or SIGTERM.

    Args:
        signal_name: ``"SIGINT"`` or ``"SIGTERM"``; epoch: the epoch (0-based) that was running.
    """

    def __init__(self, signal_name: str, epoch: int) -> None:
        super().__init__(f"{signal_name} during epoch {epoch}")
        self.signal_name, self.epoch = signal_name, epoch

    @property
    def exit_code(self) -> int:
        """128 + the signal number, as a shell reports a process ended by that signal."""
        return 128 + int(getattr(signal, self.signal_name))


def write_status(out_dir: Path, status: str, **details: Any) -> None:
    """Write ``status.json`` atomically; in a multi-process (DDP) run, only the first process does."""
    if getattr(rank_zero_only, "rank", 0) != 0:  # set by Lightning from the launcher's environment
        return
    write_text_atomic(out_dir / "status.json", json.dumps({"status": status, **details}, indent=2) + "\n")


def read_status(out_dir: Path) -> dict[str, Any]:
    """The job folder's ``status.json``, or ``{}`` if there is none (or it is unreadable)."""
    try:
        status = json.loads((out_dir / "status.json").read_text())
    except (OSError, ValueError):
        return {}
    return status if isinstance(status, dict) else {}


def resume_point(out_dir: Path) -> str | Path | None:
    """What a run started in ``out_dir`` with ``resume=true`` does: ``"completed"`` (skip it), the
    ``last.ckpt`` to continue from (interrupted or killed), or None (start afresh)."""
    status = read_status(out_dir).get("status")
    if status == "completed":
        return "completed"
    last = out_dir / LAST_CHECKPOINT
    if status in ("interrupted", "running") and last.is_file():
        return last
    return None
