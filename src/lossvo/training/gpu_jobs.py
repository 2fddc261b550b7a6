"""Several training jobs at once on one GPU (Hydra's joblib launcher): how many fit, and the check before a
sweep starts (:class:`GpuJobsCheck`). The memory a job needs: docs/sweep.md.
"""

from __future__ import annotations

import math
import subprocess
import sys
from collections.abc import Mapping, Sequence
from typing import Any

import joblib
import torch
from hydra.errors import HydraException
from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from lossvo.console import UserError, exit_in_one_line, first_line
from lossvo.training import config_checks
from lossvo.training.config_checks import CUDA_ACCELERATORS, check_accelerator
from lossvo.training.slurm import SLURM_LAUNCHER

GIB = 2**30
JOBLIB_LAUNCHER = "hydra_plugins.hydra_joblib_launcher.joblib_launcher.JoblibLauncher"
JOB_MEMORY_KEY = "hydra.callbacks.gpu_jobs.job_memory_gib"

_FREE_MEMORY = "import torch; print(torch.cuda.mem_get_info()[0])"


class GpuMemoryError(UserError):
    """More jobs at once than the GPU's free memory holds (one line)."""


def jobs_that_fit(free_bytes: int, job_bytes: int, cpus: int) -> int:
    """How many jobs run at once on one GPU: each needs a core and ``job_bytes`` of the free memory."""
    return max(0, min(cpus, free_bytes // job_bytes))


def jobs_at_once(n_jobs: int, sweep_jobs: int | None) -> int:
    """Jobs the joblib launcher runs at once: ``n_jobs`` as joblib reads it, at most ``sweep_jobs``."""
    at_once = int(joblib.effective_n_jobs(n_jobs))
    return at_once if sweep_jobs is None else min(at_once, sweep_jobs)


def check_jobs_fit(n_jobs: int, at_once: int, free_bytes: int, job_bytes: int) -> None:
    """Raise :class:`GpuMemoryError` when ``at_once`` jobs of ``job_bytes`` need more than ``free_bytes``."""
    if at_once * job_bytes <= free_bytes:
        return
    fit, need = free_bytes // job_bytes, at_once * job_bytes
    jobs = f"{at_once} job{'s' * (at_once != 1)}"
    set_to = f"set hydra.launcher.n_jobs={fit} or lower" if fit else "free GPU memory first"
    raise GpuMemoryError(
        f"hydra.launcher.n_jobs={n_jobs}: {jobs} at once on the GPU need {need / GIB:.1f} GiB at "
        f"{job_bytes / GIB:g} GiB a job ({JOB_MEMORY_KEY}), but it has {free_bytes / GIB:.1f} GiB free: "
        f"{fit} fit; {set_to}"
    )


def free_memory() -> int:
    """The GPU's free bytes, read in a child process (a CUDA context here would hold memory all sweep)."""
    done = subprocess.run([sys.executable, "-c", _FREE_MEMORY], capture_output=True, text=True, timeout=300)
    if done.returncode != 0:
        raise OSError(f"cannot read the GPU's free memory: {first_line(done.stderr) or done.returncode}")
    return int(done.stdout.split()[-1])


def sweep_jobs(overrides: Sequence[str], params: Mapping[str, Any] | None = None) -> int | None:
    """How many jobs Hydra's basic sweeper makes of ``overrides`` and ``hydra.sweeper.params``, or None."""
    given = [f"{key}={value}" for key, value in (params or {}).items()] + list(overrides)
    try:
        return len(config_checks.sweep_jobs(given))
    except HydraException:  # a sweep the basic sweeper refuses (interval), or one needing the config (glob)
        return None


def trains_on_cuda(accelerator: str, cuda_available: bool) -> bool:
    """Whether a trainer with ``accelerator`` trains on a CUDA GPU here (``auto`` takes one when there is)."""
    return accelerator in CUDA_ACCELERATORS or (accelerator == "auto" and cuda_available)


class GpuJobsCheck(Callback):
    """Before a sweep on this machine (not SLURM) trains: a CUDA trainer needs a GPU, and with the joblib
    launcher the jobs at once must fit its free memory; a refusal ends the command in one line, exit
    status 2 (Hydra turns a callback's exceptions into warnings)."""

    def __init__(self, job_memory_gib: float) -> None:
        self.job_memory_gib = job_memory_gib

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        launcher = config.hydra.launcher.get("_target_")
        accelerator = str(config.trainer.get("accelerator", "auto"))
        if launcher == SLURM_LAUNCHER:
            return
        cuda = torch.cuda.is_available()
        try:
            check_accelerator(accelerator, cuda, config.hydra.runtime.choices.get("trainer"))
            if launcher == JOBLIB_LAUNCHER and trains_on_cuda(accelerator, cuda):
                self._check_memory(config)
        except (UserError, OSError, subprocess.TimeoutExpired) as e:
            exit_in_one_line(e)

    def _check_memory(self, config: DictConfig) -> None:
        gib = self.job_memory_gib
        if not (isinstance(gib, (int, float)) and math.isfinite(gib) and gib > 0):
            raise UserError(f"{JOB_MEMORY_KEY}: expected a finite number > 0 (GiB), got {gib!r}")
        hydra, size = config.hydra, None
        if str(hydra.sweeper.get("_target_", "")).endswith(".BasicSweeper"):
            size = sweep_jobs([str(o) for o in hydra.overrides.task], hydra.sweeper.get("params"))
        n_jobs = int(hydra.launcher.n_jobs)
        check_jobs_fit(n_jobs, jobs_at_once(n_jobs, size), free_memory(), int(gib * GIB))
