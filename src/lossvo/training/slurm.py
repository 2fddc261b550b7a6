"""SLURM: the checks before a sweep submits to it, and the environment Lightning trains in there.

:class:`ClusterCheck` is a Hydra callback (``hydra.callbacks.slurm`` in the train config). When the sweep's
launcher is Hydra's submitit SLURM launcher it checks, before anything is submitted, that a job has a task
per device, that a cluster answers (``sbatch`` on the PATH, ``scontrol ping``) and that the partition and
account the launcher asks for exist; each refusal is one line with exit status 2. Hydra turns a
callback's exceptions into warnings, so the callback ends the command itself.
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


def check_partition(partition: str | None) -> None:
    """Every partition of ``hydra.launcher.partition`` (a comma list) is one of the cluster's."""
    if not partition:
        return
    known = set(_query("sinfo", "-h", "-o", "%R").stdout.split())
    missing = [name for name in partition.split(",") if name not in known]
    if missing:
        has = ", ".join(sorted(known)) or "none"
        raise ClusterError(
            f"hydra.launcher.partition={partition}: the cluster has no partition "
            f"{missing[0]!r} (it has: {has})"
        )


def check_account(account: str | None) -> None:
    """``hydra.launcher.account`` is one of the accounting database's accounts (unchecked where the
    cluster keeps no accounting: ``sacctmgr`` fails)."""
    if not account:
        return
    listed = _query("sacctmgr", "-n", "-P", "show", "account", "format=account")
    known = set(listed.stdout.split())
    if listed.returncode == 0 and account not in known:
        has = ", ".join(sorted(known)) or "none"
        raise ClusterError(
            f"hydra.launcher.account={account}: the cluster has no account {account!r} (it has: {has})"
        )


def check_tasks(launcher: DictConfig, trainer: DictConfig) -> None:
    """Under SLURM, ``srun`` starts one process per device and Lightning takes them instead of spawning
    its own: ``hydra.launcher.tasks_per_node`` must equal the trainer's devices a node (``-1``: the job's
    ``gpus_per_node``)."""
    devices, tasks = trainer.get("devices", 1), launcher.get("tasks_per_node", 1)
    if devices in (-1, "-1", "auto"):
        devices = launcher.get("gpus_per_node") or 1
    if isinstance(devices, int) and devices != tasks:
        raise ClusterError(
            f"hydra.launcher.tasks_per_node={tasks} but trainer.devices={devices}: under "
            f"SLURM each device is a task that srun starts (Lightning does not spawn them "
            f"there); set hydra.launcher.tasks_per_node={devices}"
        )


def check_cluster(launcher: DictConfig, trainer: DictConfig) -> None:
    """The checks for a SLURM launcher's config, in order; raises :class:`ClusterError`."""
    check_tasks(launcher, trainer)
    check_reachable()
    check_partition(launcher.get("partition"))
    check_account(launcher.get("account"))


class ClusterCheck(Callback):
    """Before a sweep with the SLURM launcher submits: :func:`check_cluster`, ending the command in one
    line (``error: ...``) with exit status 2 when it fails (:func:`~lossvo.console.exit_in_one_line`)."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        launcher = config.hydra.launcher
        if launcher.get("_target_") != SLURM_LAUNCHER:
            return
        try:
            check_cluster(launcher, config.trainer)
        except (ClusterError, OSError, subprocess.TimeoutExpired) as e:
            exit_in_one_line(e)


def slurm_job() -> dict[str, Any]:
    """The SLURM job this process runs in: ``{"slurm_job": "12_0", "slurm_restarts": 1}`` (an array
    task as sacct names it; restarts: how often SLURM requeued it), or {} outside SLURM."""
    env = os.environ
    if "SLURM_JOB_ID" not in env:
        return {}
    array = env.get("SLURM_ARRAY_JOB_ID"), env.get("SLURM_ARRAY_TASK_ID")
    job = f"{array[0]}_{array[1]}" if all(array) else env["SLURM_JOB_ID"]
    return {"slurm_job": job, "slurm_restarts": int(env.get("SLURM_RESTART_COUNT", "0"))}


def lightning_environment() -> list[SLURMEnvironment]:
    """Under SLURM, Lightning's SLURM environment without its own requeue (``auto_requeue=False``): the
    submitit launcher owns the requeue, and a requeued job resumes from lossvo's ``last.ckpt``."""
    return [SLURMEnvironment(auto_requeue=False)] if SLURMEnvironment.detect() else []
