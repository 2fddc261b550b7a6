"""Output folders lossvo may write into: those it creates, and those that carry its own marker. A Hydra
callback checks ``hydra.run.dir`` / ``hydra.sweep.dir`` before Hydra writes there; a folder that already
existed is never removed by a refused run."""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, ParamSpec, TypeVar

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from lossvo.console import UserError, disk_error, exit_in_one_line, remove_refused

_P = ParamSpec("_P")
_R = TypeVar("_R")

RUN_MARKERS = (".hydra/config.yaml", "status.json", "results.json", "run.lock")
"""Files of a run or an evaluation folder of lossvo's (``run.lock``: a job that has just started)."""

SWEEP_MARKERS = ("multirun.yaml", "optuna.db", ".submitit")
"""Entries of a sweep folder of lossvo's besides job folders (Hydra's, Optuna's, the SLURM launcher's)."""

_EXISTED: dict[str, bool] = {}
"""The output folders that existed before this process's run began (real paths) -> whether each was empty."""


def existed(folder: Path) -> bool:
    """Whether ``folder`` existed before this process's run began (:class:`OutputFolderCheck`)."""
    return os.path.realpath(folder) in _EXISTED


def was_empty(folder: Path) -> bool:
    """Whether ``folder`` did not exist, or was empty, before this process's run began."""
    return _EXISTED.get(os.path.realpath(folder), True)


def _is_ours(folder: Path, sweep: bool) -> bool:
    if any((folder / marker).is_file() for marker in RUN_MARKERS):
        return True
    return sweep and (
        any((folder / marker).exists() for marker in SWEEP_MARKERS)
        or any(any((p / marker).is_file() for marker in RUN_MARKERS) for p in folder.iterdir())
    )


def check_output_folder(folder: Path, key: str, sweep: bool = False) -> None:
    """``UserError`` naming ``key`` where ``folder`` is a file, or holds files and no marker of lossvo's;
    an existing folder is remembered (:func:`existed`)."""
    what = "sweep" if sweep else "run"
    if folder.exists() and not folder.is_dir():
        raise UserError(
            f"{key}: {folder} is a file: give a folder (a new one, or a {what} folder of lossvo's)"
        )
    if not folder.is_dir():
        return
    empty = _EXISTED[os.path.realpath(folder)] = not any(folder.iterdir())
    if not empty and not _is_ours(folder, sweep):
        raise UserError(
            f"{key}: {folder} holds files that lossvo did not write (no {what} of lossvo's in it): give a "
            f"new folder, or a {what} folder of lossvo's to resume"
        )


class OutputFolderCheck(Callback):
    """:func:`check_output_folder` on ``hydra.run.dir`` or ``hydra.sweep.dir`` before Hydra writes there."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config, "hydra.run.dir", False)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config, "hydra.sweep.dir", True)

    @staticmethod
    def _check(config: DictConfig, key: str, sweep: bool) -> None:
        folder = Path(str(config.hydra.sweep.dir if sweep else config.hydra.run.dir))
        try:
            check_output_folder(folder, key, sweep)
        except UserError as e:
            exit_in_one_line(e)
        _CHECKED.append(folder)


_CHECKED: list[Path] = []
"""The output folders :class:`OutputFolderCheck` accepted in this process."""

HYDRA_FILES = ("multirun.yaml", ".hydra", "run.lock")
"""What Hydra (and a run's lock) writes in an output folder before lossvo's first file, besides logs."""


def leaving_as_found(main: Callable[_P, _R]) -> Callable[_P, _R]:
    """A Hydra entry point whose disk errors name the output folder where they name no file, and leave
    each output folder that holds only what Hydra wrote as it was found."""

    @functools.wraps(main)
    def wrapped(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        try:
            return main(*args, **kwargs)
        except OSError as e:
            if disk_error(e) is not None and _CHECKED:
                if e.filename is None:
                    e.filename = str(_CHECKED[-1])
                for folder in (f for f in _CHECKED if f.is_dir() and was_empty(f)):
                    made = {*HYDRA_FILES, *(p.name for p in folder.glob("*.log"))}
                    remove_refused(folder, made, keep_folder=existed(folder))
            raise

    return wrapped
