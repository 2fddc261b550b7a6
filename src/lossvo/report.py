"""A sweep folder -> the study's tables and figures: ``python -m lossvo.report SWEEP_DIR [--out DIR]``.

A Hydra multirun (``python -m lossvo.train -m loss=euler,quat,chordal [seed=0,1,2]``) leaves one job folder
per run, ``SWEEP_DIR/<num>_<overrides>/``, with ``.hydra/{config,overrides}.yaml``, ``status.json``,
``metrics.csv``, ``results.json`` and ``trajectories/NN.txt``. This module writes into ``--out`` (default
``SWEEP_DIR/report/``), every file atomically:

- ``report.md``: Table I (APE / RPE translation RMSE, m), Table II (APE / RPE rotation RMSE, rad) and
  Table III (KITTI t_err %, r_err deg/100 m) per test sequence plus a mean row, one column pair per compared
  configuration and per baseline; the minimum of each row in bold, over all columns including the
  baselines; the pairwise comparison of the configurations; which jobs were included or skipped and why;
- ``tables/{translation,rotation,kitti}.{csv,tex}`` (LaTeX with booktabs) and ``tables/pairwise.csv``;
- ``figures/``: loss curves, bird's-eye trajectories per sequence, APE bar chart (PNG).

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
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from lossvo.atomic import write_text_atomic
from lossvo.figures import plot_ape_bars, plot_curves, plot_trajectories
from lossvo.tables import (
    BASELINE,
    METRIC_PATHS,
    NETWORK,
    TABLES,
    Column,
    Table,
    build_table,
    fmt,
    lookup,
    md,
    table_csv,
    table_latex,
    table_markdown,
)

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
        column.results = [_sequence_metrics(j.results) for j in column.jobs]
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


def wilcoxon_p(differences: np.ndarray) -> float:
    """Two-sided Wilcoxon signed-rank p-value of paired differences (1.0 if all are zero)."""
    from scipy.stats import wilcoxon

    if not np.any(differences != 0):
        return 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # small samples with ties: scipy warns and uses the normal approx.
        return float(wilcoxon(differences).pvalue)


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
    settings = {(str(j.results.get("align", "none")), int(j.results.get("delta", 1))) for j in jobs}
    first = (str(jobs[0].results.get("align", "none")), int(jobs[0].results.get("delta", 1)))
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
        results = baselines.compute_baselines(data[0], sequences, cache_dir, align, delta, n_jobs)
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

    return OmegaConf.to_container(cfg, resolve=True) if OmegaConf.is_config(cfg) else dict(cfg)


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
        used = "yes" if job.included else f"no: {md(job.skip)}"
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
        "pair's motion (counted below as a failure).",
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


def figures_markdown(figures: Sequence[Path] | None, out: Path) -> str:
    if figures is None:
        return "Figures were not drawn (`--no-figures`)."
    if not figures:
        return "No figures (no job with curves or results)."
    return "\n\n".join(f"![{p.stem}]({p.relative_to(out).as_posix()})" for p in figures)


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
    if included:
        align, delta, _ = evaluation_settings(included)
        lines += [
            "",
            f"Test sequences: {', '.join(sequences)}. APE alignment: `{align}`; RPE delta: {delta} "
            "frame(s) (as in the jobs' results.json). Columns are named by the overrides that differ "
            "between jobs; **bold**: the lowest value of the row over all columns, baselines "
            "included, so a winning baseline shows.",
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
    lines += ["", "## Baselines", "", baselines_markdown(base, baselines_on)]
    lines += ["", "## Jobs", "", jobs_markdown(jobs)]
    lines += [
        "",
        "Jobs whose metrics.csv is damaged stay in the tables (their results.json is intact) and "
        "lose only their loss curves.",
    ]
    files = [f"`tables/{t.spec.key}.{ext}`" for t in tables for ext in ("csv", "tex")]
    files.append("`tables/pairwise.csv`")
    lines += ["", "## Files", "", f"Tables as CSV and LaTeX (booktabs): {', '.join(files)}."]
    lines += ["", "## Figures", "", figures_markdown(figures, out)]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------------
# The whole report
# --------------------------------------------------------------------------------------------------


def evaluated_sequences(columns: Sequence[Column]) -> list[str]:
    """Sequences with metrics in any included job, sorted."""
    return sorted({name for c in columns for per_sequence in c.results for name in per_sequence})


def write_tables(tables: Sequence[Table], comparisons: Sequence[Comparison], folder: Path) -> None:
    for table in tables:
        write_text_atomic(folder / f"{table.spec.key}.csv", table_csv(table))
        write_text_atomic(folder / f"{table.spec.key}.tex", table_latex(table))
    write_text_atomic(folder / "pairwise.csv", comparisons_csv(comparisons))


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
    tables = [build_table(spec, columns, sequences) for spec in TABLES] if networks else []
    comparisons = compare(networks)
    write_tables(tables, comparisons, out / "tables")
    figures = None
    if with_figures:
        gt = ground_truth(included[0], sequences) if included else {}
        figures = write_figures(networks, tables, base, gt, sequences, out / "figures")
    text = render_report(sweep, out, jobs, tables, comparisons, base, with_baselines, figures, sequences)
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
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
