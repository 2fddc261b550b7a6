"""SLURM: the checks before a sweep submits to it (:class:`ClusterCheck`), and the environment Lightning
trains in there (docs/training.md).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from typing import Any

from hydra.experimental.callback import Callback
from lightning.pytorch.plugins.environments import SLURMEnvironment
from omegaconf import DictConfig

from lossvo.console import UserError, exit_in_one_line, first_line

SLURM_LAUNCHER = "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher"


class ClusterError(UserError):
    """No SLURM cluster answers, or it lacks what the launcher asks for (one line)."""


def _query(*command: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(command, capture_output=True, text=True, timeout=60)


def check_reachable() -> None:
    """``sbatch`` on the PATH and the controller answering ``scontrol ping``."""
    if shutil.which("sbatch") is None:
        raise ClusterError(
            "hydra/launcher: no SLURM cluster here (sbatch is not on the PATH): submit "
            "from a cluster's login node, or use hydra/launcher=joblib"
        )
    ping = _query("scontrol", "ping")
    if ping.returncode != 0 or "UP" not in ping.stdout:
        said = first_line(ping.stdout + ping.stderr) or f"exit status {ping.returncode}"
        raise ClusterError(f"hydra/launcher: the SLURM controller does not answer (scontrol ping: {said})")


LISTED = {
    "partition": ("sinfo", "-h", "-o", "%R"),
    "account": ("sacctmgr", "-n", "-P", "show", "account", "format=account"),
}
"""``hydra.launcher`` settings naming what the cluster has, each with the command listing the cluster's."""


def check_listed(what: str, value: str | None) -> None:
    """Every name of ``hydra.launcher.<what>`` (a comma list) is one the cluster lists (:data:`LISTED`);
    unchecked where the listing fails (``sacctmgr`` without accounting)."""
    if not value:
        return
    listed = _query(*LISTED[what])
    known = set(listed.stdout.split())
    missing = [name for name in value.split(",") if name not in known]
    if listed.returncode == 0 and missing:
        has = ", ".join(sorted(known)) or "none"
        raise ClusterError(
            f"hydra.launcher.{what}={value}: the cluster has no {what} {missing[0]!r} (it has: {has})"
        )


def check_tasks(launcher: DictConfig, trainer: DictConfig) -> None:
    """``hydra.launcher.tasks_per_node`` equals the trainer's devices a node (srun starts one per device)."""
    devices, tasks = trainer.get("devices", 1), launcher.get("tasks_per_node", 1)
    if devices in (-1, "-1", "auto"):
        devices = launcher.get("gpus_per_node") or 1
    if isinstance(devices, int) and devices != tasks:
        raise ClusterError(
            f"hydra.launcher.tasks_per_node={tasks} but trainer.devices={devices}: under "
            f"SLURM each device is a task that srun starts (Lightning does not spawn them "
            f"there); set hydra.launcher.tasks_per_node={devices}"
        )


class ClusterCheck(Callback):
    """Before a sweep with the SLURM launcher submits: tasks per device, a cluster answering, the partition
    and account existing; a refusal ends the command in one line with exit status 2."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        launcher = config.hydra.launcher
        if launcher.get("_target_") != SLURM_LAUNCHER:
            return
        try:
            check_tasks(launcher, config.trainer)
            check_reachable()
            for what in LISTED:
                check_listed(what, launcher.get(what))
        except (ClusterError, OSError, subprocess.TimeoutExpired) as e:
            exit_in_one_line(e)


def slurm_job() -> dict[str, Any]:
    """The SLURM job this process runs in, ``{"slurm_job": "12_0", "slurm_restarts": 1}``, or {}."""
    env = os.environ
    if "SLURM_JOB_ID" not in env:
        return {}
    array = env.get("SLURM_ARRAY_JOB_ID"), env.get("SLURM_ARRAY_TASK_ID")
    job = f"{array[0]}_{array[1]}" if all(array) else env["SLURM_JOB_ID"]
    return {"slurm_job": job, "slurm_restarts": int(env.get("SLURM_RESTART_COUNT", "0"))}


def lightning_environment() -> list[SLURMEnvironment]:
    """Under SLURM, Lightning's SLURM environment without its requeue (submitit's requeues)."""
    return [SLURMEnvironment(auto_requeue=False)] if SLURMEnvironment.detect() else []
