"""Sweeps through a real single-node SLURM cluster (``cluster/cluster.sh up``: slurmctld, slurmd, slurmdbd
with MariaDB, munge), started by the ``cluster`` fixture of conftest.py.

SLURM holds a requeued batch job for two minutes before it is eligible again (its ``BeginTime``); the
tests release it at once (``scontrol update StartTime=now``), as an administrator may.

Every wait polls (SLURM's state, the job folder) up to a generous limit, so that a loaded machine (a
training sweep beside the tests) makes them slower, not failed: a job's work is sized so that its run
cannot end before the test acts on it, and a time-limited job may be requeued as often as it needs.
The tests are marked ``cluster`` (``make test-cluster``; see conftest.py).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from helpers import metrics_rows, status_of

WAIT = 1800
"""Seconds any one wait on SLURM or on a sweep may take before the test fails (a hang, not slowness)."""

pytestmark = pytest.mark.timeout(3 * WAIT)  # above pyproject's limit a test: each waits on several things


def sacct(job: str, *fields: str, steps: bool = False) -> list[list[str]]:
    """The accounting database's rows of a job (its array tasks; with ``steps``, their steps too) once none
    is PENDING or RUNNING: slurmdbd records a job's end a moment after the job has ended."""
    command = [
        "sacct",
        "-j",
        job,
        "-n",
        "-P",
        "-o",
        ",".join((*fields, "State")),
        *(() if steps else ("-X",)),
    ]
    deadline = time.monotonic() + WAIT
    while True:
        rows = [line.split("|") for line in subprocess.run(command, capture_output=True, text=True,
                                                            check=True).stdout.split()]  # fmt: skip
        if not any(row[-1] in ("PENDING", "RUNNING") for row in rows) or time.monotonic() > deadline:
            return rows
        time.sleep(1)


def sacct_states(job: str) -> dict[str, str]:
    """{job id: state} of a job array's tasks, from the accounting database (what submitit polls)."""
    return {job_id: state for job_id, state in sacct(job, "JobID")}


def sweep_command(tiny_kitti: Path, tmp_path: Path, sweep: Path, *overrides: str) -> list[str]:
    """A sweep of tiny jobs on ``tiny_kitti`` through the local cluster's launcher, one thread a job."""
    return [
        sys.executable,
        "-m",
        "lossvo.train",
        "-m",
        "hydra/launcher=submitit_slurm_local",
        "data=kitti",
        f"data.sources.kitti.root={tiny_kitti}",
        f"data.frames.cache_dir={tmp_path / 'cache'}",
        "data.splits.train=[00,01]",
        "data.splits.val=[02]",
        "data.splits.test=[02]",
        "data.frames.height=64",
        "data.frames.width=96",
        "data.windows.seq_len=3",
        "data.loader.num_workers=0",
        "model.width_mult=0.0625",
        "model.hidden_size=16",
        "threads=1",
        f"hydra.sweep.dir={sweep}",
        *overrides,
    ]


def job_folder(sweep: Path) -> Path:
    """The folder of a one-job sweep's job."""
    (job,) = (p for p in sweep.iterdir() if p.is_dir() and p.name[0].isdigit())
    return job


@dataclass
class Watch:
    """What :func:`releasing` saw of a job: the times it released it (one a requeue), the states it saw."""

    released: list[float] = field(default_factory=list)
    seen: list[str] = field(default_factory=list)

    def look(self, job: str) -> None:
        squeue = ["squeue", "-h", "-j", job, "-o", "%T %r"]
        state = subprocess.run(squeue, capture_output=True, text=True, timeout=WAIT).stdout.strip()
        if not self.seen or self.seen[-1] != state:
            self.seen.append(state)
        if state == "PENDING BeginTime":
            release = ["scontrol", "update", f"JobId={job}", "StartTime=now"]
            subprocess.run(release, capture_output=True, timeout=WAIT)
            self.released.append(time.monotonic())


class Sweep:
    """A one-job sweep through the cluster, run in the background with its output in files. Waiting on it
    (:meth:`until`, :meth:`finish`) also releases its requeued job at once (:class:`Watch`), in this
    thread: the test's only thread."""

    def __init__(self, command: list[str], folder: Path, cwd: Path) -> None:
        self.folder, self.watch, self.job = folder, Watch(), ""
        self.log = cwd / "sweep.log"
        with self.log.open("w") as log:
            self.proc = subprocess.Popen(command, cwd=cwd, stdout=log, stderr=subprocess.STDOUT)

    def _poll(self) -> None:
        submitit = self.folder / ".submitit"
        if not self.job and submitit.is_dir():  # submitit submits a one-job sweep alone, not as an array
            # a job's folder is named by its id; submitit's submission pickles (``<hex uuid>.pkl``) sit beside
            jobs = sorted(p.name for p in submitit.iterdir() if p.is_dir() and p.name.isdigit())
            self.job = jobs[0] if jobs else ""
        if self.job:
            self.watch.look(self.job)

    def until(self, condition: Callable[[], bool], what: str, timeout: float = WAIT) -> None:
        deadline = time.monotonic() + timeout
        while not condition():
            assert self.proc.poll() is None, f"the sweep ended before {what}: {self.log.read_text()[-3000:]}"
            assert time.monotonic() < deadline, f"no {what} within {timeout} s"
            self._poll()
            time.sleep(0.5)

    def finish(self, timeout: float = WAIT) -> str:
        """Wait for the sweep to end with exit status 0; its output."""
        self.until(lambda: self.proc.poll() is not None, "its end", timeout)
        assert self.proc.returncode == 0, self.log.read_text()[-3000:]
        return self.log.read_text()


def epochs_logged(job: Path) -> list[int]:
    """The epochs (from 0) of a job's validation rows in metrics.csv, in file order."""
    if not (job / "metrics.csv").is_file():
        return []
    return [int(float(r["epoch"])) for r in metrics_rows(job) if r.get("val/score")]


def events(job: Path) -> list[tuple[str, ...]]:
    """(event, signal or epoch...) of a job's status.json history, without times and job ids."""
    return [
        (e["event"], *(str(e[k]) for k in ("signal", "epoch") if k in e)) for e in status_of(job)["history"]
    ]


@pytest.mark.slow
def test_a_two_job_sweep_runs_through_slurm(cluster: None, tiny_kitti: Path, tmp_path: Path) -> None:
    """``hydra/launcher=submitit_slurm_local``: both jobs submitted with sbatch, run under srun, COMPLETED in
    sacct, their folders as a local sweep's; Lightning sees SLURM but leaves the requeue to submitit."""
    sweep = tmp_path / "sweep"
    command = sweep_command(tiny_kitti, tmp_path, sweep, "loss=euler,chordal", "trainer.max_epochs=1")
    run = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, timeout=WAIT)
    assert run.returncode == 0, run.stderr[-2000:]
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir() and p.name[0].isdigit())
    assert len(jobs) == 2
    array = sorted((sweep / ".submitit").glob("*_0"))[0].name.split("_")[0]
    assert set(sacct_states(array).values()) == {"COMPLETED"} and len(sacct_states(array)) == 2
    for job in jobs:
        assert json.loads((job / "status.json").read_text())["status"] == "completed"
        assert (job / "results.json").is_file() and (job / "checkpoints" / "last.ckpt").is_file()
        log = (job / "train.log").read_text()
        assert "SLURM auto-requeueing enabled" not in log
        assert [e["slurm_job"].split("_")[0] for e in status_of(job)["history"]] == [array, array]
    report = subprocess.run([sys.executable, "-m", "lossvo.report", str(sweep)], capture_output=True,
                            text=True, cwd=tmp_path, timeout=WAIT)  # fmt: skip
    assert report.returncode == 0, report.stderr[-2000:]
    assert "2 job(s): 2 included, 0 skipped" in (sweep / "report" / "report.md").read_text()


RESUMABLE = (
    "loss=chordal",
    "trainer.deterministic=true",
    "data.transforms=[{_target_:lossvo.data.transforms.Mirror,p:0.5},"
    "{_target_:lossvo.data.transforms.Roll,p:0.5,max_rad:0.01}]",
)
REQUEUED_EPOCHS = 100
"""The requeued job's epochs: the test requeues it after its second, so the other 98 (seconds of training
however loaded the machine, as the poll that sees the second slows with it) keep it running until then."""


@pytest.mark.slow
def test_a_requeued_job_resumes_and_equals_the_uninterrupted_run(
    cluster: None, tiny_kitti: Path, tmp_path: Path
) -> None:
    """``scontrol requeue`` (what preemption with requeue does) while the job trains: SLURM sends SIGTERM,
    the job records the stop and exits; SLURM runs it again in the same folder, where it resumes from
    last.ckpt and ends with the metrics and weights of a run that was never stopped."""
    epochs = (f"trainer.max_epochs={REQUEUED_EPOCHS}",)
    sweep = tmp_path / "sweep"
    run = Sweep(sweep_command(tiny_kitti, tmp_path, sweep, *RESUMABLE, *epochs), sweep, tmp_path)
    run.until(lambda: sweep.is_dir() and any(p.name[0].isdigit() for p in sweep.iterdir()), "a job folder")
    job = job_folder(sweep)
    run.until(lambda: len(epochs_logged(job)) >= 2 and bool(run.job), "the second epoch")
    subprocess.run(["scontrol", "requeue", run.job], check=True, capture_output=True)
    run.finish()
    assert run.watch.released, f"the job was not requeued (states seen: {run.watch.seen})"
    history = events(job)
    assert history[0] == ("started",) and history[-1] == ("completed",)
    stops = [i for i, e in enumerate(history) if e[0] == "stopped"]
    assert [history[i][1] for i in stops] == ["SIGTERM"], history
    stopped_in, resumed_at = int(history[stops[0]][2]), int(history[stops[0] + 1][1])
    assert history[stops[0] + 1][0] == "resumed" and 2 <= resumed_at <= stopped_in + 1, history
    assert [e["slurm_restarts"] for e in status_of(job)["history"]][-1] == 1
    assert epochs_logged(job) == list(range(REQUEUED_EPOCHS))  # every epoch once, across the requeue

    reference = tmp_path / "reference"
    command = sweep_command(tiny_kitti, tmp_path, reference, *RESUMABLE, *epochs, "hydra/launcher=basic")
    alone = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, timeout=WAIT)
    assert alone.returncode == 0, alone.stderr[-2000:]
    whole = job_folder(reference)
    for key in ("train/loss", "val/score", "val/rpe_trans_rmse", "lr-Adam"):
        ours = [(r["epoch"], r["step"], r[key]) for r in metrics_rows(job) if r.get(key)]
        assert ours == [(r["epoch"], r["step"], r[key]) for r in metrics_rows(whole) if r.get(key)], key
    assert json.loads((job / "results.json").read_text())["sequences"] == json.loads(
        (whole / "results.json").read_text())["sequences"]  # fmt: skip


EPOCHS = 2000
"""Of the time-limited job: more than the signal's 30-60 s on a fast machine (800 took under a minute)."""


@pytest.mark.slow
def test_a_time_limited_job_is_requeued_and_finishes(cluster: None, tiny_kitti: Path, tmp_path: Path) -> None:
    """A two-minute limit with submitit's signal 60 s before it: SLURM checks limits every 30 s and sends
    the signal at the first check within lead + 30 s of the limit, 30-60 s into the job, and kills at the
    first check past the limit, 60 s or more after the signal (a one-minute limit leaves 30 s, which a
    loaded machine can spend before submitit's ``scontrol requeue`` has returned). Submitit requeues the
    job on SIGUSR2 and exits, the job records the stop, and the requeued job resumes from last.ckpt until
    it finishes (one requeue or more)."""
    sweep = tmp_path / "sweep"
    limited = ("hydra.launcher.timeout_min=2", "hydra.launcher.signal_delay_s=60",
               "hydra.launcher.max_num_timeout=200", f"trainer.max_epochs={EPOCHS}")  # fmt: skip
    run = Sweep(sweep_command(tiny_kitti, tmp_path, sweep, *RESUMABLE, *limited), sweep, tmp_path)
    run.finish()
    job = job_folder(sweep)
    history = events(job)
    stops = [e for e in history if e[0] == "stopped"]
    assert stops and {e[1] for e in stops} == {"SIGUSR2"}, history
    assert run.watch.released, f"no requeued job was released (states seen: {run.watch.seen})"
    assert len(stops) == len([e for e in history if e[0] == "resumed"])
    assert history[-1] == ("completed",)
    assert epochs_logged(job) == list(range(EPOCHS))
    assert status_of(job)["status"] == "completed" and (job / "results.json").is_file()


DAEMONS = ("munged", "mariadbd", "slurmdbd", "slurmctld", "slurmd")


def held_by_daemons() -> set[str]:
    """Every file or pipe the cluster's daemons hold open (their /proc/PID/fd targets)."""
    pids = [
        pid
        for name in DAEMONS  # pgrep matches names of at most 15 characters: one name a call
        for pid in subprocess.run(["pgrep", "-x", name], capture_output=True, text=True).stdout.split()
    ]
    assert len(pids) >= len(DAEMONS), f"not every daemon runs: {pids}"
    return {os.readlink(fd) for pid in pids for fd in Path(f"/proc/{pid}/fd").iterdir()}


@pytest.mark.slow
def test_up_again_returns_and_the_daemons_hold_nothing_of_their_caller(cluster: None) -> None:
    """A second ``cluster.sh up`` (each test worker calls it) returns within its time: the daemons the
    first one started do not hold its lock, and no daemon holds a pipe the caller passed past stderr.
    (The cluster stays up: the other worker's tests may be using it.)"""
    script = str(Path(__file__).resolve().parents[1] / "cluster" / "cluster.sh")
    read, write = os.pipe()
    try:
        run = subprocess.run(["bash", script, "up"], capture_output=True, text=True, timeout=120,
                             pass_fds=(write,))  # fmt: skip
        held = held_by_daemons()
    finally:
        os.close(write)
    pipe = os.readlink(f"/proc/self/fd/{read}")
    os.close(read)
    assert run.returncode == 0, run.stderr
    assert pipe not in held and not any(target.endswith("lossvo-cluster.lock") for target in held), held


def refused(tmp_path: Path, *overrides: str, env: dict[str, str] | None = None) -> str:
    """stderr of a SLURM sweep refused before it submits: exit status 2, one line, no sweep folder."""
    sweep = tmp_path / "sweep"
    command = [sys.executable, "-m", "lossvo.train", "-m", "hydra/launcher=submitit_slurm_local",
               f"hydra.sweep.dir={sweep}", *overrides]  # fmt: skip
    run = subprocess.run(
        command, capture_output=True, text=True, cwd=tmp_path, env={**os.environ, **(env or {})}
    )
    assert run.returncode == 2, run.stderr[-2000:]
    assert len(run.stderr.strip().splitlines()) == 1 and "Traceback" not in run.stderr, run.stderr
    assert not sweep.exists()
    return run.stderr.strip()


@pytest.mark.slow
def test_no_sbatch_is_one_line_before_anything_is_submitted(tmp_path: Path) -> None:
    line = refused(tmp_path, env={"PATH": str(tmp_path)})
    assert line == ("error: hydra/launcher: no SLURM cluster here (sbatch is not on the PATH): submit from a "
                    "cluster's login node, or use hydra/launcher=joblib")  # fmt: skip


@pytest.mark.slow
def test_a_controller_that_does_not_answer_is_one_line(cluster: None, tmp_path: Path) -> None:
    """A slurm.conf whose controller listens nowhere (the running cluster, which installs SLURM's
    commands, is left alone)."""
    conf = tmp_path / "slurm.conf"
    lines = ["ClusterName=gone", "SlurmctldHost=localhost", "SlurmctldPort=6999", "MessageTimeout=2",
             "NodeName=localhost CPUs=1 State=UNKNOWN", "PartitionName=debug Nodes=localhost"]  # fmt: skip
    conf.write_text("\n".join(lines) + "\n")
    line = refused(tmp_path, env={"SLURM_CONF": str(conf)})
    assert line.startswith("error: hydra/launcher: the SLURM controller does not answer (scontrol ping: "), (
        line
    )
    assert "DOWN" in line


@pytest.mark.slow
@pytest.mark.parametrize(("key", "known"), [("partition", "debug"), ("account", "lossvo, root")])
def test_a_partition_or_account_the_cluster_lacks_is_named(cluster: None, tmp_path: Path, key: str,
                                                           known: str) -> None:  # fmt: skip
    line = refused(tmp_path, f"hydra.launcher.{key}=nowhere")
    assert (
        line == f"error: hydra.launcher.{key}=nowhere: the cluster has no {key} 'nowhere' (it has: {known})"
    )


@pytest.mark.slow
def test_ddp_with_two_processes_a_job_writes_one_folder_a_job(cluster: None, tiny_kitti: Path,
                                                               tmp_path: Path) -> None:  # fmt: skip
    """``hydra.launcher.tasks_per_node=2`` and ``trainer=ddp trainer.devices=2``: srun starts both ranks
    of each job, Lightning takes them from SLURM (no spawning), and each job has one folder, whose
    status.json and evaluation are rank 0's."""
    sweep = tmp_path / "sweep"
    ddp = ("loss=euler,chordal", "hydra.launcher.tasks_per_node=2", "trainer=ddp", "trainer.accelerator=cpu",
           "trainer.devices=2", "trainer.max_epochs=2")  # fmt: skip
    run = subprocess.run(sweep_command(tiny_kitti, tmp_path, sweep, *ddp), capture_output=True, text=True,
                         cwd=tmp_path, timeout=WAIT)  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    jobs = sorted(p for p in sweep.iterdir() if p.name[0].isdigit())
    assert len(jobs) == 2 and {p.name for p in sweep.iterdir()} - {j.name for j in jobs} == {
        ".submitit", "multirun.yaml"}  # fmt: skip
    array = sorted((sweep / ".submitit").glob("*_0"))[0].name.split("_")[0]
    for task, job in enumerate(jobs):
        steps = sacct(f"{array}_{task}", "JobName", "NTasks", steps=True)
        assert any(step[1:] == ["2", "COMPLETED"] for step in steps), steps  # the srun step: two tasks
        assert "Starting with 2 processes" in (job / "train.log").read_text()
        assert [e["event"] for e in status_of(job)["history"]] == ["started", "completed"]
        assert status_of(job)["status"] == "completed" and (job / "results.json").is_file()
        assert epochs_logged(job) == [0, 1]


@pytest.mark.slow
def test_ddp_devices_without_as_many_tasks_is_one_line(tmp_path: Path) -> None:
    """Found from the config alone, before the cluster is asked."""
    line = refused(tmp_path, "trainer=ddp", "trainer.accelerator=cpu", "trainer.devices=2")
    assert line == ("error: hydra.launcher.tasks_per_node=1 but trainer.devices=2: under SLURM each device "
                    "is a task that srun starts (Lightning does not spawn them there); set "
                    "hydra.launcher.tasks_per_node=2")  # fmt: skip
