"""A sweep folder -> the study's tables and figures: ``python -m lossvo.report SWEEP_DIR [--out DIR]``.

A Hydra multirun (``python -m lossvo.train -m loss=euler,quat,chordal [seed=0,1,2]``) leaves one job folder
per run, ``SWEEP_DIR/<num>_<overrides>/``, with ``.hydra/{config,overrides}.yaml``, ``status.json``,
``metrics.csv``, ``results.json`` and ``trajectories/NN.txt``. This module writes into ``--out`` (default
``SWEEP_DIR/report/``), every file atomically:

- ``report.md``: a bold warning at the top when the configurations were selected by different metrics;
  the configurations (loss, weighting, k, the effective small-angle rotation weight k·gain, the selection
  metric); Table I (APE / RPE translation RMSE, m), Table II (APE / RPE rotation RMSE, rad) and Table III
  (KITTI t_err %, r_err deg/100 m) per test sequence plus a mean row, one column pair per compared
  configuration and per baseline; the minimum of each row in bold, over all columns including the
  baselines, sequences of ``data.unseen`` marked ``(unseen motion)``; the pairwise comparison of the
  configurations; convergence (the first epoch within 10 % of the best ``val/score``); each job against
  the mean-motion baseline on the validation sequences and, on the unseen-motion sequences, against zero
  motion and the sequence's own mean motion; which jobs were included or skipped and why; and last, the
  study's claims (chordal gives the lowest errors, converges fastest) with their paired tests and
  verdicts (:mod:`lossvo.claims`);
- ``tables/{translation,rotation,kitti}.{csv,tex}`` (LaTeX with booktabs), ``tables/pairwise.csv``,
  ``tables/configurations.csv``, ``tables/convergence.csv`` and ``tables/claims.csv``;
- ``figures/``: score and loss curves (mean and ± std band over seeds), bird's-eye trajectories per
  sequence, APE bar chart (PNG).

Configurations are named by the overrides that differ between jobs (``loss=euler`` vs ``loss=quat``, or
``loss.k=50`` vs ``loss.k=100``); ``seed`` is the replicate axis: with several seeds a cell is the mean ±
sample standard deviation (ddof = 1) over seeds. Baselines (:mod:`lossvo.baselines`) are computed on the
same sequences with the same alignment and RPE delta, and cached under ``<out>/cache/``. The tables are
built and formatted in :mod:`lossvo.tables`, the figures drawn in :mod:`lossvo.figures`.

Command line::

    python -m lossvo.report outputs/multirun/2026-11-23_10-00-00
    python -m lossvo.report --latest outputs/multirun          # the newest sweep under that folder
    python -m lossvo.report SWEEP_DIR --out DIR --no-baselines

It prints the path of ``report.md``. A folder that is not a sweep is a one-line error, exit status 2.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import logging
import math
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from lossvo import claims
from lossvo.atomic import write_text_atomic
from lossvo.claims import PairedTest, wilcoxon_p
from lossvo.console import emit
from lossvo.figures import plot_ape_bars, plot_curves, plot_trajectories
from lossvo.tables import (
    BASELINE,
    METRIC_PATHS,
    NETWORK,
    TABLES,
    Cell,
    Column,
    Table,
    build_table,
    fmt,
    lookup,
    md,
    mean_std_text,
    samples,
    table_csv,
    table_latex,
    table_markdown,
)

if TYPE_CHECKING:
    from lossvo.metrics import AlignMode

log = logging.getLogger("lossvo")

REPLICATE_KEY = "seed"
SIGNIFICANCE = 0.05


class SweepError(ValueError):
    """The folder given is not a Hydra sweep folder (or holds no sweep)."""


# --------------------------------------------------------------------------------------------------
# Finding the sweep and its jobs
# --------------------------------------------------------------------------------------------------


def job_dirs(sweep: Path) -> list[Path]:
    """Job folders of a sweep (sub-folders holding ``.hydra/config.yaml``), ordered by job number.

    Raises:
        SweepError: naming the folder and what was expected, if it is missing or holds no job folder.
    """
    expected = "a Hydra sweep folder with job folders <num>_<overrides>/.hydra/config.yaml"
    if not sweep.is_dir():
        raise SweepError(f"{sweep}: no such folder (expected {expected})")
    jobs = [p for p in sweep.iterdir() if (p / ".hydra" / "config.yaml").is_file()]
    if not jobs:
        raise SweepError(f"{sweep}: not a sweep (expected {expected}, from python -m lossvo.train -m ...)")
    return sorted(jobs, key=_job_number)


def _job_number(path: Path) -> tuple[int, str]:
    head = path.name.split("_", 1)[0]
    return (int(head) if head.isdigit() else sys.maxsize, path.name)


def latest_sweep(parent: Path) -> Path:
    """The newest sweep folder directly under ``parent`` (e.g. ``outputs/multirun``).

    Newest by the modification time of its ``multirun.yaml`` (written once, when the sweep starts; a
    report written later into the folder does not make it newer), else of the folder itself.

    Raises:
        SweepError: if ``parent`` is missing or holds no sweep folder.
    """
    if not parent.is_dir():
        raise SweepError(f"{parent}: no such folder (expected a folder of sweeps, e.g. outputs/multirun)")
    sweeps = [p for p in parent.iterdir() if p.is_dir() and any(p.glob("*/.hydra/config.yaml"))]
    if not sweeps:
        raise SweepError(f"{parent}: holds no sweep folder (expected {parent}/<time>/<num>_<overrides>/)")

    def started(path: Path) -> tuple[float, str]:
        marker = path / "multirun.yaml"
        return ((marker if marker.is_file() else path).stat().st_mtime, path.name)

    return max(sweeps, key=started)


# --------------------------------------------------------------------------------------------------
# Reading one job
# --------------------------------------------------------------------------------------------------


@dataclass
class Curves:
    """Per-epoch values of metrics.csv: ``{column: (epochs (E,) int, values (E,) float)}``."""

    series: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


@dataclass
class Job:
    """One job folder as read: what it is (overrides, seed), what happened (status), what it produced."""

    path: Path
    overrides: dict[str, str] = field(default_factory=dict)
    seed: Any = None
    status: str = "unknown"
    error: str | None = None
    results: dict[str, Any] | None = None
    curves: Curves | None = None
    config: Any = None
    skip: str | None = None
    notes: list[str] = field(default_factory=list)
    label: str = ""

    @property
    def included(self) -> bool:
        return self.skip is None

    @property
    def included_results(self) -> dict[str, Any]:
        """``results`` of an included job: load_job includes a job only with a valid results.json."""
        assert self.results is not None, f"{self.path.name} is not included: {self.skip}"
        return self.results


def parse_override(text: str) -> tuple[str, str]:
    """``"loss=euler"`` -> ``("loss", "euler")``; a leading ``+``/``++`` is dropped, ``~key`` kept."""
    key, _, value = str(text).partition("=")
    return key.lstrip("+").strip(), value.strip()


def read_overrides(path: Path) -> dict[str, str]:
    """``.hydra/overrides.yaml`` (a YAML list of ``key=value`` strings) as an ordered dict."""
    import yaml

    items = yaml.safe_load(path.read_text()) or []
    if not isinstance(items, list):
        raise ValueError("expected a list of key=value strings")
    return dict(parse_override(item) for item in items)


def read_json(path: Path) -> Any:
    """A JSON file; ValueError with a short reason for a missing, unreadable or invalid one."""
    try:
        text = path.read_text()
    except OSError as e:
        raise ValueError(f"{path.name}: {e.strerror or 'unreadable'}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise ValueError(f"{path.name}: invalid JSON ({e.msg} at line {e.lineno})") from None


def check_results(results: Any) -> list[str]:
    """Names of the sequences with metrics in a results.json; ValueError if its shape is not
    :func:`lossvo.eval.evaluate_run`'s."""
    if not isinstance(results, dict) or not isinstance(results.get("sequences"), dict):
        raise ValueError("results.json: expected an object with 'sequences'")
    names = []
    for name, entry in results["sequences"].items():
        if not isinstance(entry, dict) or "ape" not in entry:
            continue  # a sequence without ground truth has a note and no metrics
        for path in METRIC_PATHS:
            value = lookup(entry, path)
            if not (value is None and path[0] == "kitti") and not isinstance(value, (int, float)):
                raise ValueError(f"results.json: sequence {name}: no number at {'.'.join(path)}")
        names.append(name)
    return names


def read_metrics_csv(path: Path) -> tuple[Curves, list[str]]:
    """Per-epoch curves from a Lightning CSVLogger file, and notes on any damage.

    Train and validation values sit on different rows; each column's value of an epoch is the last
    non-empty one logged in that epoch. Rows with a wrong number of fields (a file cut mid-write) or a
    non-number end the reading there (noted); rows without an epoch (e.g. the first learning-rate row) are
    ignored.
    """
    notes: list[str] = []
    try:
        rows = list(csv.reader(io.StringIO(path.read_text())))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        return Curves(), [f"metrics.csv unreadable ({e}): no curves"]
    if not rows or "epoch" not in rows[0]:
        return Curves(), ["metrics.csv has no header with an 'epoch' column: no curves"]
    header, body = rows[0], rows[1:]
    table = []
    for line, row in enumerate(body, start=2):
        try:
            if len(row) != len(header):
                raise ValueError(f"{len(row)} fields, header has {len(header)}")
            table.append([float(v) if v.strip() else math.nan for v in row])
        except ValueError as e:
            notes.append(f"metrics.csv line {line} is truncated or corrupt ({e}): later rows ignored")
            break
    return _per_epoch(header, np.array(table, dtype=np.float64).reshape(-1, len(header))), notes


def _per_epoch(header: list[str], table: np.ndarray) -> Curves:
    """(rows, columns) floats -> per column, the last finite value logged in each epoch."""
    epoch = table[:, header.index("epoch")]
    curves = Curves()
    for j, name in enumerate(header):
        if name in ("epoch", "step"):
            continue
        keep = np.flatnonzero(np.isfinite(epoch) & np.isfinite(table[:, j]))[::-1]  # newest row first
        if keep.size:
            epochs, first = np.unique(epoch[keep].astype(int), return_index=True)
            curves.series[name] = (epochs, table[keep[first], j])
    return curves


def read_status(path: Path) -> tuple[str, str | None]:
    """(status, error) from status.json; ("unknown", None) without the file."""
    if not path.is_file():
        return "unknown", None
    status = read_json(path)
    if not isinstance(status, dict) or "status" not in status:
        raise ValueError("status.json: expected an object with 'status'")
    return str(status["status"]), status.get("error")


def load_job(path: Path) -> Job:
    """Read one job folder; never raises: what cannot be used is recorded in ``skip`` / ``notes``."""
    from omegaconf import OmegaConf

    job = Job(path)
    try:
        job.config = OmegaConf.load(path / ".hydra" / "config.yaml")
        overrides = path / ".hydra" / "overrides.yaml"
        job.overrides = read_overrides(overrides) if overrides.is_file() else {}
        job.seed = job.config.get(REPLICATE_KEY, job.overrides.get(REPLICATE_KEY))
    except Exception as e:  # YAML errors come in many classes
        job.skip = f"unreadable Hydra config ({type(e).__name__}: {_first_line(e)})"
        return job
    try:
        job.status, job.error = read_status(path / "status.json")
    except ValueError as e:
        job.skip = str(e)
        return job
    job.skip = _skip_reason(job)
    if job.skip is None:
        try:
            job.results = read_json(path / "results.json")
            check_results(job.results)
        except ValueError as e:
            job.results, job.skip = None, str(e)
    if job.status == "unknown" and job.skip is None:
        job.notes.append("no status.json")
    if (path / "metrics.csv").is_file():
        job.curves, notes = read_metrics_csv(path / "metrics.csv")
        job.notes.extend(notes)
    else:
        job.notes.append("no metrics.csv: no curves")
    return job


def _skip_reason(job: Job) -> str | None:
    """Why a job's results cannot be used yet, from its status and files (None: try results.json)."""
    if job.status == "failed":
        return f"failed: {job.error or 'no error recorded'}"
    if job.status == "running":
        return "still running (status.json says running)"
    if not (job.path / "results.json").is_file():
        if job.status == "completed":
            return "completed but no results.json (trained with +evaluate=false?)"
        return "no results.json yet (still running, or stopped before the evaluation)"
    return None


# --------------------------------------------------------------------------------------------------
# Configurations: jobs grouped by the overrides that differ, seeds as replicates
# --------------------------------------------------------------------------------------------------


def varying_keys(jobs: Sequence[Job]) -> list[str]:
    """Override keys (other than ``seed``) whose value differs between jobs or is missing in some, in the
    order they first appear."""
    keys: list[str] = []
    for job in jobs:
        keys.extend(k for k in job.overrides if k not in keys and k != REPLICATE_KEY)
    values = {k: {job.overrides.get(k) for job in jobs} for k in keys}
    return [k for k in keys if len(values[k]) > 1]


def label_jobs(jobs: Sequence[Job]) -> None:
    """Set each job's ``label`` from the varying overrides (``loss=euler``); the common overrides name a
    sweep whose jobs differ only in seed."""
    keys = varying_keys(jobs)
    for job in jobs:
        names = [f"{k}={job.overrides[k]}" for k in keys if k in job.overrides]
        if not keys:
            names = [f"{k}={v}" for k, v in job.overrides.items() if k != REPLICATE_KEY]
        job.label = ",".join(names) or "defaults"


def network_columns(jobs: Sequence[Job]) -> list[Column]:
    """One column per configuration (jobs with equal labels), replicates ordered by seed; only included
    jobs; in the order of the configurations' first job."""
    columns: dict[str, Column] = {}
    for job in jobs:
        if not job.included:
            continue
        column = columns.setdefault(job.label, Column(job.label, NETWORK, [], []))
        column.jobs.append(job)
    for column in columns.values():
        column.jobs.sort(key=lambda j: (_seed_order(j.seed), _job_number(j.path)))
        column.replicates = [f"{REPLICATE_KEY}={j.seed}" for j in column.jobs]
        column.results = [_sequence_metrics(j.included_results) for j in column.jobs]
    return list(columns.values())


def _seed_order(seed: Any) -> tuple[int, float, str]:
    """Sort key of seeds: numbers numerically (2 before 10), then anything else by its text."""
    try:
        return (0, float(seed), "")
    except (TypeError, ValueError):
        return (1, 0.0, str(seed))


def _sequence_metrics(results: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {
        name: entry
        for name, entry in results["sequences"].items()
        if isinstance(entry, dict) and "ape" in entry
    }


# --------------------------------------------------------------------------------------------------
# Pairwise comparison of configurations
# --------------------------------------------------------------------------------------------------

COMPARED = (
    ("APE trans RMSE [m]", ("ape", "trans", "rmse")),
    ("RPE trans RMSE [m]", ("rpe", "trans", "rmse")),
    ("RPE rot RMSE [rad]", ("rpe", "rot_rad", "rmse")),
)


@dataclass
class Comparison:
    """A vs B on one metric over paired (seed, sequence) values: ``median_diff`` of A - B, the count of
    pairs where A is lower, and the two-sided Wilcoxon signed-rank p-value."""

    a: str
    b: str
    metric: str
    n: int
    median_diff: float
    a_lower: int
    p_value: float
    seeds: int

    @property
    def verdict(self) -> str:
        if self.n == 0:
            return "n/a (no common seed and sequence)"
        if self.seeds < 2:
            return "n/a (one seed: no seed-noise estimate)"
        return "yes" if self.p_value < SIGNIFICANCE else "no"


def paired_values(a: Column, b: Column, path: Sequence[str]) -> tuple[np.ndarray, np.ndarray, int]:
    """Values of A and B on the (seed, sequence) pairs both have: (P,), (P,) and the number of seeds."""
    seeds = [s for s in a.replicates if s in b.replicates]
    xs, ys = [], []
    for seed in seeds:
        ra, rb = a.results[a.replicates.index(seed)], b.results[b.replicates.index(seed)]
        for name in ra:
            x, y = lookup(ra[name], path), lookup(rb.get(name), path)
            if isinstance(x, (int, float)) and isinstance(y, (int, float)):
                xs.append(float(x))
                ys.append(float(y))
    return np.array(xs), np.array(ys), len(seeds)


def compare(columns: Sequence[Column]) -> list[Comparison]:
    """Every pair of network columns on each metric of :data:`COMPARED`."""
    out = []
    for a, b in combinations([c for c in columns if c.kind == NETWORK], 2):
        for metric, path in COMPARED:
            x, y, seeds = paired_values(a, b, path)
            d = x - y
            p = wilcoxon_p(d) if d.size else math.nan
            median = float(np.median(d)) if d.size else math.nan
            out.append(
                Comparison(a.label, b.label, metric, int(d.size), median, int((d < 0).sum()), p, seeds)
            )
    return out


def comparisons_markdown(comparisons: Sequence[Comparison]) -> str:
    header = "| A | B | metric | pairs | median A − B | A lower | p (Wilcoxon) | distinguishable at 0.05 |"
    lines = [header, "|" + "---|" * 8]
    for c in comparisons:
        lines.append(
            f"| {md(c.a)} | {md(c.b)} | {c.metric} | {c.n} | {fmt(c.median_diff)} | {c.a_lower}/{c.n} | "
            f"{fmt(c.p_value, 3)} | {c.verdict} |"
        )
    return "\n".join(lines)


def comparisons_csv(comparisons: Sequence[Comparison]) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["a", "b", "metric", "pairs", "seeds", "median_diff", "a_lower", "p_value", "verdict"])
    for c in comparisons:
        writer.writerow(
            [c.a, c.b, c.metric, c.n, c.seeds, repr(c.median_diff), c.a_lower, repr(c.p_value), c.verdict]
        )
    return out.getvalue()


# --------------------------------------------------------------------------------------------------
# Configurations: rotation weights and selection metrics, from the jobs' configs
# --------------------------------------------------------------------------------------------------

SCORE = "val/score"
DEFAULT_MONITOR = "val/loss"
LOSS_DEPENDENT = ("val/loss", "val/rot_loss")
"""Monitors whose value depends on the loss and its weights: the same key names a different metric in
configurations that differ in loss or weighting."""


def config_value(config: Any, key: str, default: Any = None) -> Any:
    """The value at dotted ``key`` of a job config (a DictConfig or a mapping), interpolations resolved;
    ``default`` where the key is missing, null or cannot be resolved here."""
    from omegaconf import OmegaConf

    if config is None:
        return default
    if not OmegaConf.is_config(config):
        config = OmegaConf.create(config)
    value = OmegaConf.select(config, key, default=None, throw_on_resolution_failure=False)
    return default if value is None else value


def _number(value: Any) -> float | None:
    """``value`` as a float if it is a finite number (not a bool), else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


def loss_target(job: Job) -> str | None:
    """The job's ``loss._target_`` (e.g. ``lossvo.losses.ChordalLoss``), None if missing."""
    target = config_value(job.config, "loss._target_")
    return str(target) if target is not None else None


def loss_class_name(job: Job) -> str | None:
    """The class name of the job's loss (``ChordalLoss``), None if missing."""
    target = loss_target(job)
    return target.rsplit(".", 1)[-1] if target else None


def loss_attribute(target: str | None, name: str) -> float | None:
    """A numeric class attribute (``small_angle_gain``, ``paper_k``) of the loss class named ``target``;
    None if the class cannot be imported or lacks it."""
    from hydra.utils import get_class

    if not target:
        return None
    try:
        return _number(getattr(get_class(target), name, None))
    except Exception:  # an old or renamed class: the report goes on without the attribute
        return None


@dataclass(frozen=True)
class Weighting:
    """A job's rotation weighting: the loss class, ``weighting.preset`` (None for old jobs), the k used,
    the loss's small-angle gain (rotation term ~ gain·theta², theta in rad) and the effective small-angle
    rotation weight relative to the translation term (k·gain, or gain·exp(s_t − s_r) at the last epoch
    under learned weighting); None where unknown."""

    loss: str | None
    preset: str | None
    k: float | None
    gain: float | None
    weight: float | None
    squared: bool = True

    @property
    def learned(self) -> bool:
        return self.preset == "learned"


def learned_ratio(curves: Curves | None) -> float | None:
    """``exp(s_t − s_r)`` at the last epoch with both ``train/s_t`` and ``train/s_r`` logged, or None."""
    if curves is None or not {"train/s_t", "train/s_r"} <= set(curves.series):
        return None
    (et, st), (er, sr) = curves.series["train/s_t"], curves.series["train/s_r"]
    common = np.intersect1d(et, er)
    if common.size == 0:
        return None
    last = common[-1]
    return float(np.exp(st[et == last][0] - sr[er == last][0]))


def job_weighting(job: Job) -> Weighting:
    """How the job weighted its rotation term, from ``.hydra/config.yaml`` (and metrics.csv for learned).

    k is ``loss.k`` if it is a number; otherwise the preset's (``weighting.c / gain`` for matched, the
    class's ``paper_k`` for paper).
    """
    target = loss_target(job)
    preset = config_value(job.config, "weighting.preset")
    preset = str(preset) if preset is not None else None
    gain = loss_attribute(target, "small_angle_gain")
    squared = config_value(job.config, "loss.squared", True) is not False
    name = loss_class_name(job)
    if preset == "learned":
        ratio = learned_ratio(job.curves)
        weight = gain * ratio if gain is not None and ratio is not None else None
        return Weighting(name, preset, 1.0, gain, weight, squared)
    k = _number(config_value(job.config, "loss.k"))
    if k is None and preset == "matched":
        c = _number(config_value(job.config, "weighting.c"))
        k = c / gain if c is not None and gain else None
    elif k is None and preset == "paper":
        k = loss_attribute(target, "paper_k")
    weight = k * gain if k is not None and gain is not None and squared else None
    return Weighting(name, preset, k, gain, weight, squared)


def short(x: float | None) -> str:
    """A weight or gain with up to 4 significant digits (``100``, ``0.25``, ``33.33``); ``"?"`` if None."""
    return "?" if x is None else f"{x:.4g}"


def weight_text(weightings: Sequence[Weighting]) -> str:
    """The effective small-angle rotation weight of a configuration's seeds as text: one number (k·gain),
    ``"learned: mean ± std"`` over seeds, ``"?"`` where unknown."""
    if not weightings:
        return "?"
    if any(w.learned for w in weightings):
        cell = Cell.of(np.array([w.weight if w.weight is not None else np.nan for w in weightings]))
        if cell.n == 0:
            return "learned: ? (no train/s_t, train/s_r in metrics.csv)"
        return f"learned: {mean_std_text(cell)}"
    if not all(w.squared for w in weightings):
        return "n/a (unsquared rotation term: not gain·theta²)"
    return ", ".join(sorted({short(w.weight) for w in weightings}))


@dataclass(frozen=True)
class Selection:
    """How a job chose its best checkpoint: the monitored metrics.csv column and ``min`` / ``max``, and
    the config key it was read from (``selection.monitor``, ``callbacks.model_checkpoint.monitor`` or
    ``default`` for an old job without either)."""

    monitor: str
    mode: str
    source: str


def job_selection(config: Any) -> Selection:
    """The selection metric of a job config: ``selection.monitor``, else the checkpoint callback's
    monitor, else ``val/loss``; the mode likewise (``min`` by default)."""
    for prefix in ("selection", "callbacks.model_checkpoint"):
        monitor = config_value(config, f"{prefix}.monitor")
        if monitor is not None:
            return Selection(str(monitor), str(config_value(config, f"{prefix}.mode", "min")), prefix)
    return Selection(DEFAULT_MONITOR, "min", "default")


def selection_text(selection: Selection) -> str:
    """``"`val/score` (min)"``, marked when the value was assumed for an old job."""
    text = f"`{selection.monitor}` ({selection.mode})"
    return text + ", assumed: not in the config" if selection.source == "default" else text


def selection_identity(job: Job) -> tuple[Any, ...]:
    """What a job's selection metric is: the monitor and mode, plus, for a loss-dependent monitor
    (:data:`LOSS_DEPENDENT`), the loss and weights that define its value."""
    selection = job_selection(job.config)
    key: tuple[Any, ...] = (selection.monitor, selection.mode)
    if selection.monitor in LOSS_DEPENDENT:
        w = job_weighting(job)
        key += (w.loss, w.preset, None if w.learned else w.k, w.squared)
    return key


def selection_warning(columns: Sequence[Column]) -> str | None:
    """A bold markdown warning if the configurations were selected by different metrics (different
    monitors, or one loss-dependent monitor such as ``val/loss`` over different losses or weights);
    None if one metric selected them all."""
    networks = [c for c in columns if c.kind == NETWORK and c.jobs]
    if len({selection_identity(j) for c in networks for j in c.jobs}) < 2:
        return None
    per_config = "; ".join(
        f"{c.label}: {', '.join(sorted({selection_text(job_selection(j.config)) for j in c.jobs}))}"
        for c in networks
    )
    monitors = {job_selection(j.config).monitor for c in networks for j in c.jobs}
    why = (
        "each by its own loss value, which differs between losses and weights"
        if len(monitors) == 1
        else "different columns of metrics.csv"
    )
    return (
        f"**Warning: the configurations of this sweep were selected by different metrics ({why}; "
        f"{per_config}): their best checkpoints, and so the tables below, were not chosen by one rule. "
        f"A fair comparison selects every configuration by the loss-independent `{SCORE}`.**"
    )


CONFIGURATION_FIELDS = (
    ("configuration", "configuration"),
    ("loss", "loss"),
    ("weighting", "weighting"),
    ("k", "k"),
    ("gain", "gain"),
    ("rotation weight k·gain", "rotation_weight"),
    ("selected by", "selected_by"),
    ("seeds", "seeds"),
)
"""(markdown header, CSV header) of the configurations table."""


def configuration_row(column: Column) -> list[str]:
    """One configuration's :data:`CONFIGURATION_FIELDS` as text (several values of its seeds joined)."""
    ws = [job_weighting(j) for j in column.jobs]
    first = ws[0] if ws else Weighting(None, None, None, None, None)
    return [
        column.label,
        first.loss or "?",
        first.preset or "? (not in the config)",
        ", ".join(sorted({short(w.k) for w in ws})),
        short(first.gain),
        weight_text(ws),
        ", ".join(sorted({selection_text(job_selection(j.config)) for j in column.jobs})),
        str(len(column.jobs)),
    ]


def configurations_markdown(columns: Sequence[Column]) -> str:
    """Per configuration: loss class, weighting preset, k, gain, k·gain and the selection metric."""
    lines = ["| " + " | ".join(h for h, _ in CONFIGURATION_FIELDS) + " |", "|" + "---|" * 8]
    for c in columns:
        if c.kind == NETWORK:
            lines.append("| " + " | ".join(md(v) for v in configuration_row(c)) + " |")
    return "\n".join(lines)


def configurations_csv(columns: Sequence[Column]) -> str:
    """:data:`CONFIGURATION_FIELDS` per configuration, as in report.md (backticks dropped)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow([name for _, name in CONFIGURATION_FIELDS])
    for c in columns:
        if c.kind == NETWORK:
            writer.writerow([v.replace("`", "") for v in configuration_row(c)])
    return out.getvalue()


# --------------------------------------------------------------------------------------------------
# Convergence: the first epoch within 10 % of the best validation score
# --------------------------------------------------------------------------------------------------


def convergence_metric(job: Job) -> tuple[str, str]:
    """(metrics.csv column, mode) a job's convergence is measured on: ``val/score`` (min) if logged,
    else its selection monitor."""
    if job.curves is not None and SCORE in job.curves.series:
        return SCORE, "min"
    selection = job_selection(job.config)
    return selection.monitor, selection.mode


@dataclass
class Convergence:
    """A configuration's convergence: per replicate (seed) the column used, the first epoch (1-based,
    = metrics.csv epoch + 1) within :data:`lossvo.claims.CONVERGENCE_TOLERANCE` of its best value (None
    without that column) and the number of epochs logged."""

    label: str
    replicates: list[str]
    metrics: list[str]
    epochs: list[int | None]
    logged: list[int]

    def cell(self) -> Cell:
        return Cell.of(np.array([e if e is not None else np.nan for e in self.epochs], dtype=np.float64))

    def epoch_of(self, replicate: str) -> int | None:
        return self.epochs[self.replicates.index(replicate)] if replicate in self.replicates else None


def job_convergence(job: Job) -> tuple[str, int | None, int]:
    """(column, first epoch within 10 % of the best (1-based) or None, epochs logged) of one job."""
    column, mode = convergence_metric(job)
    if job.curves is None or column not in job.curves.series:
        return column, None, 0
    epochs, values = job.curves.series[column]
    epoch = claims.convergence_epoch(epochs, values, mode=mode)
    return column, (epoch + 1 if epoch is not None else None), len(epochs)


def convergence(columns: Sequence[Column]) -> list[Convergence]:
    """One :class:`Convergence` per network column, replicates in the column's order."""
    out = []
    for c in columns:
        if c.kind != NETWORK:
            continue
        per_job = [job_convergence(j) for j in c.jobs]
        out.append(
            Convergence(
                c.label,
                list(c.replicates),
                [m for m, _, _ in per_job],
                [e for _, e, _ in per_job],
                [n for _, _, n in per_job],
            )
        )
    return out


def epoch_text(cell: Cell) -> str:
    """Epochs as ``"mean ± std"`` with one decimal (``"n/a"`` without any)."""
    if cell.n == 0:
        return "n/a"
    return f"{cell.mean:.1f}" + (f" ± {cell.std:.1f}" if cell.n > 1 else "")


def convergence_markdown(items: Sequence[Convergence]) -> str:
    tolerance = f"{claims.CONVERGENCE_TOLERANCE:.0%}"
    lines = [
        f"The first epoch (counted from 1, as in the curves; metrics.csv counts from 0) at which the "
        f"validation score comes within {tolerance} of its best over the run (value <= best × "
        f"{1 + claims.CONVERGENCE_TOLERANCE:g} for a min metric), mean ± sample std over seeds. The "
        f"score is the loss-independent `{SCORE}`, the same for every loss.",
    ]
    fallback = sorted({m for c in items for m in c.metrics if m != SCORE})
    if fallback:
        lines += [
            "",
            f"*Note:* `{SCORE}` is not in every metrics.csv: those jobs are measured on their selection "
            f"monitor ({', '.join(f'`{m}`' for m in fallback)}), which is not on one scale across losses.",
        ]
    lines += [
        "",
        "| configuration | metric | seeds with a curve | epoch (mean ± std) | per seed | epochs logged |",
        "|" + "---|" * 6,
    ]
    for c in items:
        pairs = zip(c.replicates, c.epochs, strict=True)
        per_seed = ", ".join(f"{r}: {e if e is not None else 'n/a'}" for r, e in pairs)
        cell = c.cell()
        lines.append(
            f"| {md(c.label)} | {md(', '.join(sorted(set(c.metrics))))} | {cell.n} | {epoch_text(cell)} | "
            f"{md(per_seed)} | {md(', '.join(map(str, sorted(set(c.logged)))))} |"
        )
    return "\n".join(lines)


def convergence_csv(items: Sequence[Convergence]) -> str:
    """One row per configuration and seed: ``configuration, seed, metric, epoch`` (1-based, empty if
    none), ``epochs_logged``; then per configuration a row with seed ``mean`` (mean epoch) and one with
    seed ``std`` (sample std)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["configuration", "seed", "metric", "epoch", "epochs_logged"])
    for c in items:
        for r, m, e, n in zip(c.replicates, c.metrics, c.epochs, c.logged, strict=True):
            writer.writerow([c.label, r, m, "" if e is None else e, n])
        cell, metric = c.cell(), ",".join(sorted(set(c.metrics)))
        writer.writerow([c.label, "mean", metric, repr(cell.mean) if cell.n else "", ""])
        writer.writerow([c.label, "std", metric, repr(cell.std) if cell.n > 1 else "", ""])
    return out.getvalue()


# --------------------------------------------------------------------------------------------------
# The study's claims, tested on the numbers
# --------------------------------------------------------------------------------------------------

CLAIMED_LOSS = "ChordalLoss"
CLAIM_ERRORS = (
    ("RPE trans RMSE [m]", ("rpe", "trans", "rmse")),
    ("RPE rot RMSE [rad]", ("rpe", "rot_rad", "rmse")),
    ("APE trans RMSE [m]", ("ape", "trans", "rmse")),
)
CLAIM_A = "the chordal loss gives the lowest errors"
CLAIM_B = "it converges fastest"
EPOCHS = "convergence epoch"


@dataclass
class QuantityTests:
    """The claimed configuration against each other on one quantity (an error metric or the
    convergence epoch): the paired tests and their verdict."""

    quantity: str
    tests: list[PairedTest]
    verdict: str


@dataclass
class Claim:
    """One claim about one claimed configuration: what was paired (``scope``), per configuration the
    measured numbers ``{label: {quantity: Cell over seeds}}``, the tests per quantity, the overall
    verdict and notes. ``untested`` says why there are no tests (then ``verdict`` is empty)."""

    statement: str
    configuration: str
    scope: str = ""
    measured: dict[str, dict[str, Cell]] = field(default_factory=dict)
    quantities: list[QuantityTests] = field(default_factory=list)
    verdict: str = ""
    notes: list[str] = field(default_factory=list)
    untested: str | None = None


def is_claimed(column: Column) -> bool:
    """Whether a network column is a chordal configuration: every job's ``loss._target_`` class is
    :data:`CLAIMED_LOSS`."""
    return (
        column.kind == NETWORK
        and bool(column.jobs)
        and all(loss_class_name(j) == CLAIMED_LOSS for j in column.jobs)
    )


def training_sequences(columns: Sequence[Column]) -> set[str]:
    """The union of the jobs' ``data.train`` sequences (as strings)."""
    out: set[str] = set()
    for c in columns:
        for j in c.jobs:
            out.update(str(s) for s in (config_value(j.config, "data.train") or []))
    return out


def restrict(column: Column, sequences: Sequence[str]) -> Column:
    """A copy of a column whose results hold only ``sequences``."""
    results = [{s: r[s] for s in sequences if s in r} for r in column.results]
    return Column(column.label, column.kind, list(column.replicates), results, list(column.jobs))


def seed_means(column: Column, path: Sequence[str], sequences: Sequence[str]) -> Cell:
    """Mean ± std over seeds of each seed's mean of one metric over ``sequences`` (a seed missing one
    sequence is left out)."""
    values = samples(column, path, sequences)  # (seeds, sequences)
    return Cell.of(values.mean(axis=1) if values.shape[1] else np.array([]))


def error_claim(claimed: Column, others: Sequence[Column], heldout: Sequence[str]) -> Claim:
    """Claim (a): the claimed configuration's errors against every other's, paired over (seed, held-out
    sequence), one verdict per metric of :data:`CLAIM_ERRORS`, combined by :func:`lossvo.claims.combine`."""
    scope = f"On the sequences outside the training split: {', '.join(heldout)}."
    claim = Claim(CLAIM_A, claimed.label, scope)
    for column in (claimed, *others):
        claim.measured[column.label] = {q: seed_means(column, p, heldout) for q, p in CLAIM_ERRORS}
    a = restrict(claimed, heldout)
    for quantity, path in CLAIM_ERRORS:
        tests = []
        for other in others:
            x, y, _ = paired_values(a, restrict(other, heldout), path)
            tests.append(claims.paired_test(other.label, x, y))
        claim.quantities.append(QuantityTests(quantity, tests, claims.verdict(tests)))
    claim.verdict = claims.combine([q.verdict for q in claim.quantities])
    claim.notes.append(
        "The sequences of one seed share one trained network, so the (seed, sequence) pairs are not fully "
        "independent: read p as indicative."
    )
    return claim


def convergence_claim(claimed: Convergence, others: Sequence[Convergence]) -> Claim:
    """Claim (b): the claimed configuration's convergence epochs against every other's, paired by seed."""
    claim = Claim(CLAIM_B, claimed.label, "Paired by seed, on the epochs of *Convergence*.")
    for c in (claimed, *others):
        claim.measured[c.label] = {EPOCHS: c.cell()}
    tests = []
    for other in others:
        pairs = [(claimed.epoch_of(r), other.epoch_of(r)) for r in claimed.replicates]
        pairs = [(x, y) for x, y in pairs if x is not None and y is not None]
        x, y = (np.array([p[i] for p in pairs], dtype=np.float64) for i in (0, 1))
        tests.append(claims.paired_test(other.label, x, y))
    claim.quantities.append(QuantityTests(EPOCHS, tests, claims.verdict(tests)))
    claim.verdict = claim.quantities[0].verdict
    smallest = sorted({(t.n, claims.smallest_p(t.n)) for t in tests})
    claim.notes += [
        f"With n = {n} paired seeds the smallest two-sided p an exact Wilcoxon test can give is {fmt(p, 3)}"
        + (f", so p < {claims.ALPHA} cannot be reached." if p >= claims.ALPHA else ".")
        for n, p in smallest
    ]
    metrics = {m for c in (claimed, *others) for m in c.metrics}
    if metrics != {SCORE}:
        claim.notes.append(
            f"Not every job logged `{SCORE}`: epochs are measured on {', '.join(sorted(metrics))}, curves "
            "that are not on one scale across losses."
        )
    return claim


def study_claims(
    columns: Sequence[Column], items: Sequence[Convergence], sequences: Sequence[str]
) -> list[Claim]:
    """Claims (a) and (b) for every chordal configuration against all non-chordal ones (an untested
    claim says why: no chordal configuration, nothing to compare with, no held-out sequence)."""
    networks = [c for c in columns if c.kind == NETWORK]
    claimed = [c for c in networks if is_claimed(c)]
    others = [c for c in networks if not is_claimed(c)]
    if not claimed:
        reason = f"the sweep has no chordal configuration (no job with loss._target_ {CLAIMED_LOSS})"
        return [Claim(s, "", untested=reason) for s in (CLAIM_A, CLAIM_B)]
    train = training_sequences(networks)
    heldout = [s for s in sequences if s not in train]
    by_label = {c.label: c for c in items}
    out = []
    for column in claimed:
        if not others:
            reason = "no other configuration with results to compare with"
            out += [Claim(s, column.label, untested=reason) for s in (CLAIM_A, CLAIM_B)]
            continue
        if heldout:
            a = error_claim(column, others, heldout)
        else:
            a = Claim(CLAIM_A, column.label, untested="no evaluated sequence is outside the training split")
        out += [a, convergence_claim(by_label[column.label], [by_label[o.label] for o in others])]
    return out


CLAIMS_RULE = (
    f"Verdict rule (`lossvo.claims.verdict`): the chordal configuration (`loss._target_` class "
    f"`{CLAIMED_LOSS}`) is paired with every other configuration and each pair is tested with a two-sided "
    f"Wilcoxon signed-rank test (`scipy.stats.wilcoxon`). **{claims.SUPPORTED}**: the chordal mean is lower "
    f"than every other configuration's and every p < {claims.ALPHA}; **{claims.CONTRADICTED}**: some other "
    f"configuration's mean is lower with p < {claims.ALPHA}; otherwise **{claims.NOT_DISTINGUISHABLE}**. "
    f"Claim (a) is tested per error metric, paired over (seed, sequence) on the sequences outside the "
    f"training split (`data.train`), and the metrics combine as: {claims.CONTRADICTED} if any metric is, "
    f"{claims.SUPPORTED} if all are, otherwise {claims.NOT_DISTINGUISHABLE}. Claim (b) pairs the convergence "
    f"epochs (*Convergence*) by seed."
)


def _measured_markdown(claim: Claim) -> list[str]:
    quantities = list(next(iter(claim.measured.values())))
    fmt_cell = epoch_text if quantities == [EPOCHS] else mean_std_text
    lines = ["| configuration | " + " | ".join(quantities) + " |", "|" + "---|" * (len(quantities) + 1)]
    for label, cells in claim.measured.items():
        lines.append(f"| {md(label)} | " + " | ".join(fmt_cell(cells[q]) for q in quantities) + " |")
    return lines


def _tests_markdown(claim: Claim) -> list[str]:
    lines = [
        f"| quantity | {md(claim.configuration)} vs | pairs n | mean {md(claim.configuration)} | mean other "
        "| p (Wilcoxon) | smallest p at this n | verdict on the quantity |",
        "|" + "---|" * 8,
    ]
    for q in claim.quantities:
        number = (lambda x: f"{x:.2f}" if math.isfinite(x) else "n/a") if q.quantity == EPOCHS else fmt
        for t in q.tests:
            lines.append(
                f"| {q.quantity} | {md(t.versus)} | {t.n} | {number(t.mean)} | {number(t.versus_mean)} | "
                f"{fmt(t.p_value, 3)} | {fmt(claims.smallest_p(t.n), 3)} | {q.verdict} |"
            )
    return lines


def claim_markdown(claim: Claim, letter: str) -> str:
    """One claim: measured numbers (mean ± std over seeds), the paired tests and the verdict."""
    head = f'### ({letter}) "{claim.statement}"'
    head += f" ({claim.configuration})" if claim.configuration else ""
    if claim.untested:
        return f"{head}\n\nCannot be tested: {claim.untested}."
    what = "each seed's mean over those sequences" if claim.statement == CLAIM_A else "epochs"
    lines = [head, "", claim.scope, "", f"Measured ({what}; mean ± sample std over seeds):", ""]
    lines += [*_measured_markdown(claim), "", "Paired tests:", "", *_tests_markdown(claim)]
    lines += [f"\n*Note:* {n}" for n in claim.notes]
    lines += ["", f"**Verdict: {claim.verdict}.**"]
    return "\n".join(lines)


def claims_markdown(items: Sequence[Claim]) -> str:
    letters = {CLAIM_A: "a", CLAIM_B: "b"}
    return "\n\n".join([CLAIMS_RULE, *(claim_markdown(c, letters[c.statement]) for c in items)])


CLAIMS_HEADER = (
    "claim",
    "configuration",
    "versus",
    "quantity",
    "n",
    "mean",
    "versus_mean",
    "p_value",
    "smallest_p",
    "verdict",
    "note",
)


def claims_csv(items: Sequence[Claim]) -> str:
    """One row per paired test (``verdict``: that quantity's), then one ``all`` row per claim with its
    verdict; an untested claim is one row with verdict ``cannot be tested`` and the reason in ``note``."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CLAIMS_HEADER)
    for c in items:
        if c.untested:
            writer.writerow([c.statement, c.configuration, *[""] * 7, "cannot be tested", c.untested])
            continue
        for q in c.quantities:
            for t in q.tests:
                numbers = [
                    t.n,
                    repr(t.mean),
                    repr(t.versus_mean),
                    repr(t.p_value),
                    repr(claims.smallest_p(t.n)),
                ]
                writer.writerow([c.statement, c.configuration, t.versus, q.quantity, *numbers, q.verdict, ""])
        writer.writerow([c.statement, c.configuration, "all", "all", *[""] * 5, c.verdict, " ".join(c.notes)])
    return out.getvalue()


# --------------------------------------------------------------------------------------------------
# Baselines
# --------------------------------------------------------------------------------------------------


@dataclass
class BaselineRun:
    """The baselines of a report: columns, trajectories per sequence, ORB failures, notes and time."""

    columns: list[Column] = field(default_factory=list)
    trajectories: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    failures: dict[str, int] = field(default_factory=dict)
    frames: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0
    cached: int = 0


def evaluation_settings(jobs: Sequence[Job]) -> tuple[str, int, list[str]]:
    """(align, delta) of the included jobs' results.json (the first job's) and notes if they differ."""
    results = [j.included_results for j in jobs]
    settings = {(str(r.get("align", "none")), int(r.get("delta", 1))) for r in results}
    first = (str(results[0].get("align", "none")), int(results[0].get("delta", 1)))
    notes = (
        []
        if len(settings) == 1
        else [f"jobs differ in align/delta {sorted(settings)}: baselines use {first}"]
    )
    return first[0], first[1], notes


def run_baselines(jobs: Sequence[Job], sequences: Sequence[str], cache_dir: Path, n_jobs: int) -> BaselineRun:
    """Baselines on ``sequences`` for the data config of the first included job; never raises (a failure
    becomes a note and no baseline columns)."""
    from lossvo import baselines

    run = BaselineRun()
    start = time.perf_counter()
    align, delta, run.notes = evaluation_settings(jobs)
    try:
        data = [_plain(j.config.data) for j in jobs]
        if len({json.dumps(baselines.data_identity(d), sort_keys=True, default=str) for d in data}) > 1:
            run.notes.append(f"jobs differ in their data config: baselines use {jobs[0].path.name}'s")
        mode = cast("AlignMode", align)  # results.json's text; metrics.align rejects an unknown mode
        results = baselines.compute_baselines(data[0], sequences, cache_dir, mode, delta, n_jobs)
    except Exception as e:  # a missing dataset, a broken config: the report goes on without baselines
        run.notes.append(f"baselines skipped: {type(e).__name__}: {_first_line(e)}")
        run.seconds = time.perf_counter() - start
        return run
    for name in baselines.NAMES:
        per_sequence = {s: results[s][name].metrics for s in sequences}
        run.columns.append(Column(name, BASELINE, ["deterministic"], [per_sequence]))
    for s in sequences:
        run.trajectories[s] = {name: results[s][name].trajectory for name in baselines.NAMES}
        run.failures[s] = results[s][baselines.ORB].failures
        run.frames[s] = len(results[s][baselines.ZERO].trajectory)
    run.cached = sum(results[s][baselines.ZERO].cached for s in sequences)
    run.seconds = time.perf_counter() - start
    return run


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else ""


def _plain(cfg: Any) -> dict[str, Any]:
    from omegaconf import OmegaConf

    if OmegaConf.is_config(cfg):  # a DictConfig (a job's cfg.data): to_container gives a str-keyed dict
        return cast("dict[str, Any]", OmegaConf.to_container(cfg, resolve=True))
    return dict(cfg)


def ground_truth(job: Job, sequences: Sequence[str]) -> dict[str, np.ndarray]:
    """Ground-truth poses (N, 4, 4) of the sequences from a job's data config, without rendering or
    caching anything; empty if the dataset is not there."""
    from hydra.utils import instantiate

    try:
        datamodule = instantiate(_plain(job.config.data), _convert_="all")
        datamodule.load_metadata()
    except Exception as e:  # the dataset is not (or no longer) there: figures without ground truth
        log.info("no ground truth for the trajectory figures: %s", _first_line(e))
        return {}
    found = {s: datamodule.sequences[s].poses for s in sequences if s in datamodule.sequences}
    return {s: poses for s, poses in found.items() if poses is not None}


# --------------------------------------------------------------------------------------------------
# report.md
# --------------------------------------------------------------------------------------------------


def jobs_markdown(jobs: Sequence[Job]) -> str:
    lines = ["| job | configuration | seed | status | in tables | notes |", "|---|---|---|---|---|---|"]
    for job in jobs:
        used = "yes" if job.skip is None else f"no: {md(job.skip)}"  # job.included: skip is None
        lines.append(
            f"| `{job.path.name}` | {md(job.label or '?')} | {md(job.seed)} | {md(job.status)} | {used} | "
            f"{md('; '.join(job.notes))} |"
        )
    return "\n".join(lines)


def seeds_text(columns: Sequence[Column]) -> str:
    networks = [c for c in columns if c.kind == NETWORK]
    counts = ", ".join(f"{c.label}: n = {len(c.replicates)} ({', '.join(c.replicates)})" for c in networks)
    if any(len(c.replicates) > 1 for c in networks):
        return (
            "Cells are the mean ± the sample standard deviation (ddof = 1) over seeds; bold marks the "
            "lowest mean. The mean row averages each seed over the sequences first, then takes mean ± std "
            f"over seeds. Seeds per configuration: {counts}."
        )
    return (
        f"One seed per configuration ({counts}): no seed-noise estimate is available, so differences "
        "between configurations below cannot be told apart from the run-to-run variation of training."
    )


def baselines_markdown(run: BaselineRun, enabled: bool) -> str:
    if not enabled:
        return "Baselines were not computed (`--no-baselines`)."
    lines = [
        "Computed on the same sequences, integrated from the first ground-truth pose and scored with the "
        "same alignment and RPE delta as the jobs' results.json (`lossvo.baselines`):",
        "",
        "- **zero motion**: identity relative poses (the camera stands still);",
        "- **mean motion (train)**: the training split's mean relative pose (mean translation, chordal mean "
        "rotation) at every step;",
        "- **ORB+E (GT scale)**: ORB features, `cv2.findEssentialMat` (RANSAC, OpenCV's USAC) and "
        "`cv2.recoverPose` with K from calib.txt; each step's translation is scaled to the ground-truth "
        "step length (monocular VO has no scale: this is an optimistic baseline). A pair whose matches do "
        "not move is a step straight ahead; a pair with too few matches or inliers takes the previous "
        "pair's motion (counted below as a failure);",
        "- **own mean motion (oracle)**: the sequence's own mean relative pose (from its ground truth) at "
        "every step: it knows the sequence's average motion, so a network that learned only an average "
        "motion cannot beat it.",
    ]
    if run.failures:
        total = sum(run.failures.values())
        pairs = sum(n - 1 for n in run.frames.values())
        per = ", ".join(f"{s}: {f}" for s, f in run.failures.items() if f)
        lines += [
            "",
            f"ORB+E failed (fell back) on {total} of {pairs} frame pairs" + (f" ({per})." if per else "."),
        ]
    if run.columns:
        lines += [
            "",
            f"Baselines took {run.seconds:.1f} s ({run.cached} of {len(run.frames)} sequences from "
            "the report's `cache/`, keyed by data config and sequence).",
        ]
    lines += [f"\n*Note:* {note}" for note in run.notes]
    return "\n".join(lines)


LEARNING_METRICS = (("RPE trans", ("rpe", "trans", "rmse")), ("RPE rot", ("rpe", "rot_rad", "rmse")))


def config_sequences(columns: Sequence[Column], key: str) -> list[str]:
    """The sequence names listed at ``key`` (e.g. ``data.val``) in the networks' job configs, in order of
    first appearance; a missing or empty key lists none."""
    names: list[str] = []
    for column in columns:
        for job in column.jobs:
            value = config_value(job.config, key, [])
            items = value.split(",") if isinstance(value, str) else list(value or [])
            for item in items:
                name = f"{item:02d}" if isinstance(item, int) else str(item).strip()
                if name and name not in names:
                    names.append(name)
    return names


def validation_sequences(columns: Sequence[Column]) -> list[str]:
    """The validation sequences (``data.val``) of the networks' jobs, in order."""
    return config_sequences(columns, "data.val")


UNSEEN_KEY = "data.unseen"
UNSEEN_NOTE = "unseen motion"
"""The note beside an unseen-motion sequence's name in the per-sequence tables."""


def unseen_sequences(columns: Sequence[Column], sequences: Sequence[str]) -> list[str]:
    """The evaluated ``sequences`` that some network job lists in ``data.unseen`` (route families never
    used for training), in the order of ``sequences``."""
    unseen = set(config_sequences(columns, UNSEEN_KEY))
    return [s for s in sequences if s in unseen]


def reduction(value: Any, reference: Any) -> float | None:
    """``1 - value / reference`` (the fraction by which a network beats a baseline), or None."""
    value, reference = _number(value), _number(reference)
    if value is None or reference is None or reference <= 0:
        return None
    return 1.0 - value / reference


def learning_markdown(networks: Sequence[Column], base: BaselineRun) -> str:
    """Per job and validation sequence: how far below the mean-motion baseline its RPE lies."""
    mean_motion = next((c for c in base.columns if c.label == "mean motion (train)"), None)
    sequences = validation_sequences(networks)
    if mean_motion is None or not sequences:
        return "No mean-motion baseline or no validation sequence: nothing to compare."
    header = ["configuration", "seed"] + [f"{s} {name}" for s in sequences for name, _ in LEARNING_METRICS]
    rows = []
    for column in networks:
        for job, results in zip(column.jobs, column.results, strict=True):
            cells = []
            for s in sequences:
                for _, path in LEARNING_METRICS:
                    r = reduction(lookup(results.get(s), path), lookup(mean_motion.results[0].get(s), path))
                    cells.append("–" if r is None else f"{100 * r:.0f} %")
            rows.append([md(column.label), str(job.seed), *cells])
    lines = [
        "How far each job's RPE RMSE lies below the mean-motion baseline's on the validation sequences "
        "(1 − network / baseline; negative: worse than predicting the training set's mean motion).",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
        *("| " + " | ".join(row) + " |" for row in rows),
    ]
    return "\n".join(lines)


UNSEEN_ROTATION_BAR = 0.30
"""Fraction by which a job's RPE rotation RMSE must lie below zero motion's on an unseen-motion sequence."""
RPE_ROT, RPE_TRANS = ("rpe", "rot_rad", "rmse"), ("rpe", "trans", "rmse")


@dataclass(frozen=True)
class UnseenCheck:
    """One job on one unseen-motion sequence: RPE rotation RMSE (rad) and its reduction against zero
    motion, RPE translation RMSE (m) and its reduction against the sequence's own mean motion (the
    oracle), reductions as fractions (1 - network / baseline); None where a value is missing."""

    rot: float | None
    rot_reduction: float | None
    trans: float | None
    trans_reduction: float | None

    @property
    def met(self) -> bool:
        """Rotation at least :data:`UNSEEN_ROTATION_BAR` below zero motion and translation below the
        oracle; a missing value meets neither."""
        rot_ok = self.rot_reduction is not None and self.rot_reduction >= UNSEEN_ROTATION_BAR
        return rot_ok and self.trans_reduction is not None and self.trans_reduction > 0


def unseen_check(entry: Any, zero: Any, own: Any) -> UnseenCheck:
    """The :class:`UnseenCheck` of a job's results entry of one sequence against the zero-motion and
    own-mean-motion baselines' entries of that sequence (each as in results.json, or None)."""
    rot, trans = _number(lookup(entry, RPE_ROT)), _number(lookup(entry, RPE_TRANS))
    return UnseenCheck(
        rot, reduction(rot, lookup(zero, RPE_ROT)), trans, reduction(trans, lookup(own, RPE_TRANS))
    )


def _percent(fraction: float | None) -> str:
    return "–" if fraction is None else f"{100 * fraction:.1f} %"


UNSEEN_HEADER = ("RPE rot [rad]", "vs zero motion", "RPE trans [m]", "vs own mean motion", "both met")


def _check_cells(check: UnseenCheck) -> list[str]:
    """An :class:`UnseenCheck` as the cells of :data:`UNSEEN_HEADER`."""
    rmse = ["–" if v is None else fmt(v) for v in (check.rot, check.trans)]
    reductions = [_percent(check.rot_reduction), _percent(check.trans_reduction)]
    return [rmse[0], reductions[0], rmse[1], reductions[1], "yes" if check.met else "no"]


def unseen_markdown(networks: Sequence[Column], base: BaselineRun, unseen: Sequence[str]) -> str:
    """Per job and unseen-motion sequence: RPE rotation against zero motion, RPE translation against the
    sequence's own mean motion, whether both criteria are met; then how many jobs meet both on every
    unseen sequence."""
    by_label = {c.label: c for c in base.columns}
    zero, own = by_label.get("zero motion"), by_label.get("own mean motion (oracle)")
    if zero is None or own is None:
        return "No zero-motion or own-mean-motion baseline: nothing to compare."
    rows, passed, total = [], 0, 0
    for column in networks:
        for job, results in zip(column.jobs, column.results, strict=True):
            checks = [
                unseen_check(results.get(s), zero.results[0].get(s), own.results[0].get(s)) for s in unseen
            ]
            rows += [
                [md(column.label), md(job.seed), s, *_check_cells(c)]
                for s, c in zip(unseen, checks, strict=True)
            ]
            passed += all(c.met for c in checks)
            total += 1
    header = ["configuration", "seed", "sequence", *UNSEEN_HEADER]
    lines = [
        f"On the sequences of route families never used for training (`{UNSEEN_KEY}`): each job's RPE "
        "rotation RMSE against zero motion's and its RPE translation RMSE against the sequence's own mean "
        "motion (the oracle), as 1 − network / baseline. Both are met when the rotation lies at least "
        f"{100 * UNSEEN_ROTATION_BAR:.0f} % below zero motion's and the translation below the oracle's "
        "(a reduction above 0); a missing value meets neither.",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
        *("| " + " | ".join(row) + " |" for row in rows),
        "",
        f"{passed} of {total} jobs meet both on every unseen sequence.",
    ]
    return "\n".join(lines)


def figures_markdown(figures: Sequence[Path] | None, out: Path) -> str:
    if figures is None:
        return "Figures were not drawn (`--no-figures`)."
    if not figures:
        return "No figures (no job with curves or results)."
    return "\n\n".join(f"![{p.stem}]({p.relative_to(out).as_posix()})" for p in figures)


@dataclass
class Study:
    """What a report measures besides the tables: the configurations (network columns), their
    convergence, the study's claims and the evaluated sequences of unseen motion (``data.unseen``)."""

    networks: list[Column]
    convergence: list[Convergence]
    claims: list[Claim]
    unseen: list[str] = field(default_factory=list)


def analyse(networks: Sequence[Column], sequences: Sequence[str]) -> Study:
    """Convergence, claims and unseen-motion sequences of the network columns on the evaluated
    ``sequences``."""
    items = convergence(networks)
    claimed = study_claims(networks, items, sequences)
    return Study(list(networks), items, claimed, unseen_sequences(networks, sequences))


TABLE_FILES = ("pairwise.csv", "configurations.csv", "convergence.csv", "claims.csv")


def render_report(
    sweep: Path,
    out: Path,
    jobs: Sequence[Job],
    tables: Sequence[Table],
    comparisons: Sequence[Comparison],
    base: BaselineRun,
    baselines_on: bool,
    figures: Sequence[Path] | None,
    sequences: Sequence[str],
    study: Study,
) -> str:
    """The text of report.md (``figures`` None: not drawn)."""
    included = [j for j in jobs if j.included]
    skipped = [j for j in jobs if not j.included]
    lines = [
        f"# Sweep report: `{sweep}`",
        "",
        f"Generated {time.strftime('%Y-%m-%d %H:%M:%S')} by `python -m lossvo.report`. "
        f"{len(jobs)} job(s): {len(included)} included, {len(skipped)} skipped (see *Jobs*).",
    ]
    warning = selection_warning(study.networks)
    if warning:
        lines += ["", warning]
    if study.networks:
        lines += [
            "",
            "## Configurations",
            "",
            "Rotation weight: the small-angle weight of the rotation term relative to the translation "
            "term, k · gain: each loss's rotation term is ≈ gain · θ² for a small rotation error θ (rad), "
            "so a configuration's loss is ≈ |t − t^|² (m²) + k · gain · θ². Under learned weighting it is "
            "gain · exp(s_t − s_r) at the last epoch (mean ± std over seeds). Selected by: the metric "
            "that chose each job's best checkpoint.",
            "",
            configurations_markdown(study.networks),
        ]
    if included:
        align, delta, _ = evaluation_settings(included)
        lines += [
            "",
            f"Test sequences: {', '.join(sequences)}. APE alignment: `{align}`; RPE delta: {delta} "
            "frame(s) (as in the jobs' results.json). Columns are named by the overrides that differ "
            "between jobs; **bold**: the lowest value of the row over all columns, baselines "
            "included, so a winning baseline shows."
            + (
                f" Rows marked ({UNSEEN_NOTE}) are sequences of route families never used for training "
                f"(`{UNSEEN_KEY}`): {', '.join(study.unseen)}."
                if study.unseen
                else ""
            ),
            "",
            seeds_text([*tables[0].columns]),
        ]
    for table in tables:
        lines += ["", f"## {table.spec.title}", "", table_markdown(table)]
        if table.mean_over != table.rows[:-1]:
            lines += [
                "",
                f"Mean over the sequences with a value in every column: "
                f"{', '.join(table.mean_over) or 'none'}.",
            ]
    if not included:
        lines += ["", "No job has usable results yet: no tables."]
    lines += ["", "## Pairwise comparison", ""]
    if comparisons:
        lines += [
            "Paired over (seed, sequence): the per-sequence RMSE of A and of B from the same seed on the "
            "same sequence. Two-sided Wilcoxon signed-rank test (`scipy.stats.wilcoxon`) on the differences "
            "A − B; *distinguishable* means p < 0.05. Sequences within a seed share one trained network, so "
            "the pairs are not fully independent: read p as indicative.",
            "",
            comparisons_markdown(comparisons),
        ]
    else:
        lines += ["Fewer than two configurations with results: nothing to compare."]
    if study.convergence:
        lines += ["", "## Convergence", "", convergence_markdown(study.convergence)]
    lines += ["", "## Baselines", "", baselines_markdown(base, baselines_on)]
    if baselines_on and included:
        networks = [c for c in tables[0].columns if c.kind == NETWORK] if tables else []
        lines += ["", "## Against the mean motion, per job", "", learning_markdown(networks, base)]
        if study.unseen:
            lines += ["", "## Unseen motion", "", unseen_markdown(networks, base, study.unseen)]
    lines += ["", "## Jobs", "", jobs_markdown(jobs)]
    lines += [
        "",
        "Jobs whose metrics.csv is damaged stay in the tables (their results.json is intact) and "
        "lose only their loss curves.",
    ]
    files = [f"`tables/{t.spec.key}.{ext}`" for t in tables for ext in ("csv", "tex")]
    files += [f"`tables/{name}`" for name in TABLE_FILES]
    lines += ["", "## Files", "", f"Tables as CSV and LaTeX (booktabs): {', '.join(files)}."]
    lines += ["", "## Figures", "", figures_markdown(figures, out)]
    lines += ["", "## The study's claims", "", claims_markdown(study.claims)]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------------
# The whole report
# --------------------------------------------------------------------------------------------------


def evaluated_sequences(columns: Sequence[Column]) -> list[str]:
    """Sequences with metrics in any included job, sorted."""
    return sorted({name for c in columns for per_sequence in c.results for name in per_sequence})


def write_tables(
    tables: Sequence[Table], comparisons: Sequence[Comparison], study: Study, folder: Path
) -> None:
    for table in tables:
        write_text_atomic(folder / f"{table.spec.key}.csv", table_csv(table))
        write_text_atomic(folder / f"{table.spec.key}.tex", table_latex(table))
    texts = (
        comparisons_csv(comparisons),
        configurations_csv(study.networks),
        convergence_csv(study.convergence),
        claims_csv(study.claims),
    )
    for name, text in zip(TABLE_FILES, texts, strict=True):
        write_text_atomic(folder / name, text)


def write_figures(
    networks: Sequence[Column],
    tables: Sequence[Table],
    base: BaselineRun,
    gt: dict[str, np.ndarray],
    sequences: Sequence[str],
    folder: Path,
) -> list[Path]:
    """Every figure; returns the paths written."""
    written = []
    if networks and plot_curves(networks, folder / "curves.png"):
        written.append(folder / "curves.png")
    if tables and tables[0].columns:
        plot_ape_bars(tables[0], folder / "ape_trans_rmse.png")
        written.append(folder / "ape_trans_rmse.png")
    for s in sequences:
        extra = {k: v for k, v in base.trajectories.get(s, {}).items() if not k.startswith("zero")}
        plot_trajectories(s, networks, gt.get(s), extra, folder / f"trajectory_{s}.png")
        written.append(folder / f"trajectory_{s}.png")
    return written


def make_report(
    sweep: Path,
    out: Path | None = None,
    with_baselines: bool = True,
    with_figures: bool = True,
    n_jobs: int | None = None,
) -> Path:
    """Write the report of a sweep folder; returns the path of report.md.

    Raises:
        SweepError: if ``sweep`` is not a sweep folder.
    """
    sweep = Path(sweep)
    out = Path(out) if out is not None else sweep / "report"
    jobs = [load_job(p) for p in job_dirs(sweep)]
    label_jobs([j for j in jobs if j.config is not None])
    networks = network_columns(jobs)
    sequences = evaluated_sequences(networks)
    included = [j for j in jobs if j.included]
    base = BaselineRun()
    if with_baselines and included and sequences:
        n_jobs = n_jobs or os.cpu_count() or 1
        base = run_baselines(included, sequences, out / "cache", n_jobs)
    columns = [*networks, *base.columns]
    comparisons = compare(networks)
    study = analyse(networks, sequences)
    notes = dict.fromkeys(study.unseen, UNSEEN_NOTE)
    tables = [build_table(spec, columns, sequences, notes) for spec in TABLES] if networks else []
    write_tables(tables, comparisons, study, out / "tables")
    figures = None
    if with_figures:
        gt = ground_truth(included[0], sequences) if included else {}
        figures = write_figures(networks, tables, base, gt, sequences, out / "figures")
    text = render_report(
        sweep, out, jobs, tables, comparisons, base, with_baselines, figures, sequences, study
    )
    write_text_atomic(out / "report.md", text)
    return out / "report.md"


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m lossvo.report SWEEP_DIR [--out DIR] [--latest] [--no-baselines] [--jobs N]``."""
    parser = argparse.ArgumentParser(prog="python -m lossvo.report", description=__doc__.splitlines()[0])
    parser.add_argument(
        "sweep_dir",
        type=Path,
        help="a sweep folder (outputs/multirun/<time>), or with --latest the folder holding sweeps",
    )
    parser.add_argument("--out", type=Path, default=None, help="output folder (default SWEEP_DIR/report)")
    parser.add_argument("--latest", action="store_true", help="report the newest sweep under SWEEP_DIR")
    parser.add_argument("--no-baselines", action="store_true", help="skip the zero / mean / ORB baselines")
    parser.add_argument("--no-figures", action="store_true", help="write the tables only")
    parser.add_argument(
        "--jobs",
        type=int,
        default=None,
        help="sequences computed in parallel for the baselines (default: CPU count)",
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
    start = time.perf_counter()
    try:
        sweep = latest_sweep(args.sweep_dir) if args.latest else args.sweep_dir
        path = make_report(sweep, args.out, not args.no_baselines, not args.no_figures, args.jobs)
    except SweepError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    log.info("report written in %.1f s", time.perf_counter() - start)
    emit(str(path))
    return 0


if __name__ == "__main__":
    sys.exit(main())
