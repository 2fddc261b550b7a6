"""Reading a sweep folder and its job folders (``SWEEP_DIR/<num>_<overrides>/``) through the job-folder
contract (:mod:`lossvo.evaluation.job_folder`): what each job is, what happened, what it produced. The report
never builds a datamodule; see docs/report.md.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lossvo import folder_lock
from lossvo.checks import is_number
from lossvo.console import UserError, first_line
from lossvo.data.kitti import KittiFormatError, read_poses
from lossvo.data.sequence import sequence_names
from lossvo.evaluation.job_folder import (
    METRICS,
    RESULTS,
    TRANSLATION_METRIC,
    Curves,
    DataRecord,
    JobFolderError,
    Results,
    Scores,
    read_metrics,
    read_status,
)
from lossvo.evaluation.trajectories import read_tum

REPLICATE_KEY = "seed"
"""The override that names a replicate of a configuration; every other varying override names one."""
ARCHITECTURE_KEY = "model"
"""The config group whose choice names a job's architecture (``model=deepvo_small``, ``model=flowvo``)."""
DATA_KEY = "data"
"""The config group naming a job's training data (configurations are compared within their own data)."""

APE_TRANS = ("ape", "trans", "rmse")
APE_ROT = ("ape", "rot_rad", "rmse")
RPE_TRANS = ("rpe", "trans", "rmse")
RPE_ROT = ("rpe", "rot_rad", "rmse")
KITTI_T = ("kitti", "t_err_pct")
KITTI_R = ("kitti", "r_err_deg_per_100m")
"""Paths into a sequence's :class:`~lossvo.evaluation.job_folder.Scores`: RMSEs in m and rad, the KITTI
errors in % and deg/100 m (None where no 100 m segment exists)."""


class SweepError(UserError):
    """The folder given is not a Hydra sweep folder (or holds no sweep)."""


def metric_value(scores: Scores | None, path: Sequence[str]) -> float | None:
    """The number at ``path`` of a sequence's scores; None where the scores or the value are missing."""
    value: Any = scores
    for key in path:
        value = getattr(value, key, None)
    return None if value is None else float(value)


def finite_number(value: Any) -> float | None:
    """``value`` as a float if it is a finite number (not a bool), else None."""
    if not is_number(value) or not math.isfinite(value):
        return None
    return float(value)


def job_dirs(sweep: Path) -> list[Path]:
    """Job folders of a sweep (holding ``.hydra/config.yaml``) by job number; SweepError if none."""
    expected = "a Hydra sweep folder with job folders <num>_<overrides>/.hydra/config.yaml"
    if not sweep.is_dir():
        raise SweepError(f"{sweep}: no such folder (expected {expected})")
    jobs = [p for p in sweep.iterdir() if (p / ".hydra" / "config.yaml").is_file()]
    if not jobs:
        raise SweepError(f"{sweep}: not a sweep (expected {expected}, from python -m lossvo.train -m ...)")
    return sorted(jobs, key=job_number)


def job_number(path: Path) -> tuple[int, str]:
    """Sort key of a job folder: its leading job number (folders without one last), then its name."""
    head = path.name.split("_", 1)[0]
    return (int(head) if head.isdigit() else sys.maxsize, path.name)


def latest_sweep(parent: Path) -> Path:
    """The newest sweep folder under ``parent`` (by its ``multirun.yaml``'s mtime); SweepError if none."""
    if not parent.is_dir():
        raise SweepError(f"{parent}: no such folder (expected a folder of sweeps, e.g. outputs/multirun)")
    sweeps = [p for p in parent.iterdir() if p.is_dir() and any(p.glob("*/.hydra/config.yaml"))]
    if not sweeps:
        raise SweepError(f"{parent}: holds no sweep folder (expected {parent}/<time>/<num>_<overrides>/)")
    return max(sweeps, key=_started)


def _started(path: Path) -> tuple[float, str]:
    marker = path / "multirun.yaml"
    return ((marker if marker.is_file() else path).stat().st_mtime, path.name)


@dataclass
class Job:
    """One job folder as read (``code``, ``machines``: those its processes ran, from status.json)."""

    path: Path
    overrides: dict[str, str] = field(default_factory=dict)
    seed: Any = None
    status: str = "unknown"
    error: str | None = None
    results: Results | None = None
    curves: Curves | None = None
    config: Any = None
    skip: str | None = None
    notes: list[str] = field(default_factory=list)
    label: str = ""
    architecture: str | None = None
    data: str | None = None
    code: tuple[str, ...] = ()
    machines: tuple[str, ...] = ()
    choices: dict[str, str] = field(default_factory=dict)

    @property
    def included(self) -> bool:
        return self.skip is None

    @property
    def included_results(self) -> Results:
        """``results`` of an included job (which always has them)."""
        assert self.results is not None, f"{self.path.name} is not included: {self.skip}"
        return self.results


REQUIRED_CONFIG = ("selection.monitor", "selection.mode")
"""Keys that every job's ``.hydra/config.yaml`` has and the report reads."""


def parse_overrides(items: Sequence[str]) -> dict[str, str]:
    """Hydra overrides (``["loss=euler", "+evaluate=false"]``) as an ordered ``{key: value}`` by Hydra's
    parser: the key without a leading ``+``/``++`` (``~key`` kept), the value as written."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parsed = OverridesParser.create().parse_overrides([str(item) for item in items])
    return {o.get_key_element().lstrip("+"): str(o.input_line).partition("=")[2].strip() for o in parsed}


def read_overrides(path: Path) -> dict[str, str]:
    """``.hydra/overrides.yaml`` (a YAML list of ``key=value``) by :func:`parse_overrides`."""
    import yaml

    items = yaml.safe_load(path.read_text()) or []
    if not isinstance(items, list):
        raise UserError("expected a list of key=value strings")
    return parse_overrides(items)


def read_curves(folder: Path) -> tuple[Curves, list[str]]:
    """Per-epoch curves of a job folder's ``metrics.csv``, and notes on a missing or damaged file."""
    if not (folder / METRICS).is_file():
        return Curves(), [f"no {METRICS}: no curves"]
    try:
        table = read_metrics(folder)
    except JobFolderError as e:
        return Curves(), [f"{METRICS} {e.reason}: no curves"]
    if "epoch" not in table.header:
        return Curves(), [f"{METRICS} has no header with an 'epoch' column: no curves"]
    return table.curves(), [f"{METRICS} {table.damage}"] if table.damage else []


def load_job(path: Path) -> Job:
    """Read one job folder; never raises: what cannot be used is recorded in ``skip`` / ``notes``."""
    job = Job(path)
    try:
        _read_config(job)
    except Exception as e:  # YAML errors come in many classes
        job.skip = f"unreadable Hydra config ({type(e).__name__}: {first_line(e)})"
        return job
    try:
        status = read_status(path)
    except JobFolderError as e:
        job.skip = f"{e.path.name}: {e.reason}"
        return job
    if status is not None:
        job.status = status.state
        job.error = status.stop if status.state == "interrupted" else status.error
        job.code = tuple(dict.fromkeys(e.code for e in status.history if e.code))
        job.machines = tuple(dict.fromkeys(e.machine for e in status.history if e.machine))
    job.skip = _skip_reason(job)
    if job.skip is None:
        try:
            job.results = Results.read(path / RESULTS)
        except JobFolderError as e:
            job.skip = f"results.json: {e.reason}"
    if job.results is not None and job.results.translation != TRANSLATION_METRIC:
        job.notes.append(f"translation scored as {job.results.translation}: no metric scale, as ORB+E's")
    if job.results is not None and job.results.mirror_average:
        job.notes.append("evaluated with mirror averaging (each pose averaged with the mirrored inputs')")
    if job.status == "unknown" and job.skip is None:
        job.notes.append("no status.json")
    job.curves, notes = read_curves(path)
    job.notes.extend(notes)
    return job


def _read_config(job: Job) -> None:
    """Fill a job's config and what it names from ``.hydra/``; UserError without :data:`REQUIRED_CONFIG`."""
    from omegaconf import OmegaConf

    job.config = OmegaConf.load(job.path / ".hydra" / "config.yaml")
    missing = [key for key in REQUIRED_CONFIG if config_value(job.config, key) is None]
    if missing:
        raise UserError(f".hydra/config.yaml has no {missing[0]}")
    overrides = job.path / ".hydra" / "overrides.yaml"
    job.overrides = read_overrides(overrides) if overrides.is_file() else {}
    job.seed = job.config.get(REPLICATE_KEY, job.overrides.get(REPLICATE_KEY))
    job.choices = read_choices(job.path / ".hydra" / "hydra.yaml", job.overrides)
    job.architecture = read_architecture(job.choices, job.config)
    job.data = job.choices.get(DATA_KEY)


def read_choices(hydra_yaml: Path, overrides: dict[str, str]) -> dict[str, str]:
    """A job's ``overrides`` updated by the non-null config-group choices Hydra recorded in ``hydra.yaml``
    (``hydra.runtime.choices``); the overrides alone where that file is missing or unreadable."""
    import yaml

    try:
        recorded = yaml.safe_load(hydra_yaml.read_text())["hydra"]["runtime"]["choices"]
        recorded = {str(k): str(v) for k, v in recorded.items() if v is not None}
    except Exception:  # no file, YAML errors of many classes, another shape: the overrides alone
        recorded = {}
    return {**overrides, **recorded}


def read_architecture(choices: dict[str, str], config: Any) -> str | None:
    """A job's architecture: its :data:`ARCHITECTURE_KEY` choice (``flowvo``), else the class name of
    ``model._target_`` (``DeepVO``); None without either."""
    target = config_value(config, f"{ARCHITECTURE_KEY}._target_")
    return choices.get(ARCHITECTURE_KEY, str(target).rsplit(".", 1)[-1] if target is not None else None)


def _running(path: Path) -> str:
    """Why a job whose status.json says "running" is skipped: it runs, or it was killed."""
    alive = folder_lock.in_use(path)
    if alive is None:
        return "still running (status.json says running)"
    if alive:
        return f"still running ({folder_lock.holder(path)})"
    return (
        f"killed: status.json says running but no process holds {folder_lock.LOCK} (last held by "
        f"{folder_lock.holder(path)}; SIGKILL, out of memory or a lost node): run the sweep's command "
        "again to resume"
    )


def _skip_reason(job: Job) -> str | None:
    """Why a job's results cannot be used yet, from its status and files (None: read results.json)."""
    if job.status == "failed":
        return f"failed: {job.error or 'no error recorded'}"
    if job.status == "running":
        return _running(job.path)
    if job.status == "interrupted":
        return f"interrupted ({job.error or 'no signal recorded'}): run the sweep's command again to resume"
    if not (job.path / RESULTS).is_file():
        if job.status == "completed":
            return "completed but no results.json (trained with +evaluate=false?)"
        return "no results.json yet (still running, or stopped before the evaluation)"
    return None


UNRECORDED = "unrecorded"
"""The code version of a job whose status.json records none."""


def _pooled_note(
    jobs: Sequence[Job], values: Callable[[Job], tuple[str, ...]], ran: str, why: str
) -> str | None:
    """A note naming each value (code version, machine) of the included jobs with its jobs, if several."""
    found: dict[str, list[str]] = {}
    for job in (j for j in jobs if j.included):
        for value in values(job):
            found.setdefault(value, []).append(job.path.name)
    if len(found) < 2:
        return None
    listed = "; ".join(f"`{value}`: {', '.join(names)}" for value, names in found.items())
    return (
        f"**The included jobs ran {ran.format(len(found))}**, pooled in every table and test{why}: {listed}."
    )


def code_versions_note(jobs: Sequence[Job]) -> str | None:
    """:func:`_pooled_note` of the code versions."""
    why = " (a job resumed under another version counts under each)"
    return _pooled_note(jobs, lambda job: job.code or (UNRECORDED,), "{} code versions", why)


def machines_note(jobs: Sequence[Job]) -> str | None:
    """:func:`_pooled_note` of the machines recorded (jobs without a record not counted)."""
    why = "; jobs paired by seed on different machines are not one start (their arithmetic differs)"
    return _pooled_note(jobs, lambda job: job.machines, "on {} machines", why)


def config_value(config: Any, key: str, default: Any = None) -> Any:
    """The resolved value at dotted ``key`` of a job config; ``default`` if missing, null or unresolvable."""
    from omegaconf import OmegaConf

    if config is None:
        return default
    value = OmegaConf.select(config, key, default=None, throw_on_resolution_failure=False)
    return default if value is None else value


def config_sequences(jobs: Iterable[Job], key: str) -> list[str]:
    """The sequence names listed at ``key`` (``data.splits.val``) in the jobs' configs, first seen first."""
    return list(dict.fromkeys(n for job in jobs for n in sequence_names(config_value(job.config, key, []))))


def check_on_disk(data: DataRecord, job: Job) -> None:
    """UserError naming the job if the evaluated dataset or the training data is no longer there."""
    for name, root in (("evaluated dataset", data.root), ("training data", data.train_root)):
        if root is None or not Path(root).is_dir():
            raise UserError(f"the {name} of {job.path.name}, {root}, no longer exists")


def trained_sequences(job: Job) -> set[str]:
    """The evaluated sequences an included job trained on (none where it evaluated other data)."""
    data = job.included_results.data
    same = data.train_root is not None and os.path.realpath(data.root) == os.path.realpath(data.train_root)
    return set(data.train) if same else set()


def read_trajectory(job: Job, sequence: str) -> np.ndarray | None:
    """A job's estimated trajectory (N, 4, 4), m, of one sequence; None if missing or unreadable."""
    entry = job.results.sequences.get(sequence) if job.results else None
    try:
        return read_poses(job.path / (entry.trajectory if entry else f"trajectories/{sequence}.txt"))
    except (KittiFormatError, OSError):
        return None


def ground_truth(
    jobs: Sequence[Job], sequences: Sequence[str]
) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """``{sequence: ground-truth poses (N, 4, 4), m}`` from the pose file (KITTI, or TUM ``.tum``) named by
    the first job that evaluated it, and ``{sequence: reason}`` of those without."""
    found, missing = {}, {}
    for s in sequences:
        job = next((j for j in jobs if j.results and s in j.results.sequences), None)
        if job is None or job.results is None:
            missing[s] = "no job's results.json has it"
            continue
        path = job.results.sequences[s].ground_truth
        if path is None:
            missing[s] = f"{job.path.name}/results.json names no ground-truth file"
            continue
        try:
            found[s] = read_tum(path)[1] if path.endswith(".tum") else read_poses(path)
        except KittiFormatError as e:
            missing[s] = str(e)
    return found, missing
