"""The compared configurations of a sweep (jobs grouped by the overrides that differ, seeds as replicates),
their architectures, rotation weighting (k · gain) and selection metric, and the configurations table; read
from the jobs' ``.hydra/`` (and metrics.csv for learned weighting). See docs/report.md.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from lossvo import weighting
from lossvo.console import UserError
from lossvo.report.jobs import (
    ARCHITECTURE_KEY,
    DATA_KEY,
    REPLICATE_KEY,
    Curves,
    Job,
    config_value,
    finite_number,
    job_number,
)
from lossvo.report.tables import NETWORK, UNKNOWN_ARCHITECTURE, Cell, Column, mean_std_text, with_architecture
from lossvo.table_render import Rows

SCORE = "val/score"
"""The loss-independent validation score (:mod:`lossvo.training.selection`)."""
LOSS_DEPENDENT = ("val/loss", "val/rot_loss")
"""Monitors whose value depends on the loss and its weights."""

GROUPS = (DATA_KEY, ARCHITECTURE_KEY)
"""The config groups whose choice groups configurations (compared within each choice)."""


def design(jobs: Sequence[Job]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """One row per job: its overrides other than ``seed`` (a column per key), and its :data:`GROUPS`
    choices."""
    index = pd.RangeIndex(len(jobs))
    rows = [{k: v for k, v in job.overrides.items() if k != REPLICATE_KEY} for job in jobs]
    overrides = pd.DataFrame(rows, index=index, dtype=object)
    chosen = {DATA_KEY: [j.data for j in jobs], ARCHITECTURE_KEY: [j.architecture for j in jobs]}
    return overrides, pd.DataFrame(chosen, index=index, dtype=object)


CONFIGURATION_KEYS = ("experiment", ARCHITECTURE_KEY, DATA_KEY)
"""The keys that come first in a configuration's label (``model=flowvo,loss=euler``)."""


def varying_keys(jobs: Sequence[Job]) -> list[str]:
    """Override keys (other than ``seed``) whose value differs between jobs or is missing in some,
    :data:`CONFIGURATION_KEYS` first; a group's key only where its resolved choice differs, and without
    the settings that each choice fixes (:func:`_fixed_by_group`)."""
    overrides, choices = design(jobs)
    values = overrides.assign(**{g: choices[g] for g in GROUPS if g in overrides})
    varies = values.nunique(dropna=False) > 1
    keys = [k for k in overrides if varies[k] and not _fixed_by_group(k, overrides, choices)]
    return [k for k in CONFIGURATION_KEYS if k in keys] + [k for k in keys if k not in CONFIGURATION_KEYS]


def _fixed_by_group(key: str, overrides: pd.DataFrame, choices: pd.DataFrame) -> bool:
    """Whether ``key`` (``data.sources.car.root``) takes one value per choice of a group that varies."""
    for group in GROUPS:
        if key.startswith(f"{group}."):
            values = overrides[key].groupby(choices[group], dropna=False).nunique(dropna=False)
            if len(values) > 1 and (values == 1).all():
                return True
    return False


def label_jobs(jobs: Sequence[Job]) -> None:
    """Set each job's ``label`` from the varying overrides (``loss=euler``); from all of them where only
    the seed varies."""
    keys = varying_keys(jobs)
    for job in jobs:
        job.label = override_label(job.overrides, keys or [k for k in job.overrides if k != REPLICATE_KEY])


def override_label(overrides: dict[str, str], keys: Sequence[str]) -> str:
    """The ``keys`` that ``overrides`` has as ``key=value`` joined by commas (``defaults`` for none)."""
    return ",".join(f"{k}={overrides[k]}" for k in keys if k in overrides) or "defaults"


def network_columns(jobs: Sequence[Job]) -> list[Column]:
    """One column per label of the included jobs, replicates by seed, architecture ``flowvo on data=mix``
    where the data varies."""
    columns: dict[str, Column] = {}
    for job in jobs:
        if job.included:
            columns.setdefault(job.label, Column(job.label, NETWORK, [], [])).jobs.append(job)
    several_data = len({j.data for j in jobs if j.included}) > 1  # different data: compared within each
    for column in columns.values():
        column.jobs.sort(key=lambda j: (_seed_order(j.seed), job_number(j.path)))
        column.replicates = [f"{REPLICATE_KEY}={j.seed}" for j in column.jobs]
        column.results = [j.included_results.scored() for j in column.jobs]
        architecture = " + ".join(sorted({j.architecture or UNKNOWN_ARCHITECTURE for j in column.jobs}))
        data = " + ".join(sorted({str(j.data) for j in column.jobs}))
        column.architecture = f"{architecture} on {DATA_KEY}={data}" if several_data else architecture
    return list(columns.values())


def architecture_groups(columns: Sequence[Column], by_architecture: bool = True) -> dict[str, list[Column]]:
    """The network columns by architecture, first seen first; all under ``""`` unless ``by_architecture``."""
    groups: dict[str, list[Column]] = {}
    for column in columns:
        if column.kind == NETWORK:
            architecture = (column.architecture or UNKNOWN_ARCHITECTURE) if by_architecture else ""
            groups.setdefault(architecture, []).append(column)
    return groups


def varies_architecture(columns: Sequence[Column]) -> bool:
    """Whether the network columns span more than one architecture."""
    return len(architecture_groups(columns)) > 1


def architecture_file_name(architecture: str) -> str:
    """An architecture's name as part of a file name (``flowvo on data=mix`` -> ``flowvo-on-data-mix``)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", architecture).strip("-.") or "unknown"


def treatments(columns: Sequence[Column]) -> dict[str, str]:
    """``{label: treatment}`` of the network columns: the varying overrides without those that name the
    group (:data:`GROUPS`, or take one value within each: ``model=flowvo,loss=euler`` -> ``loss=euler``)."""
    networks = [c for c in columns if c.kind == NETWORK and c.jobs]
    jobs = [j for c in networks for j in c.jobs]
    overrides, choices = design(jobs)
    within = overrides.groupby([choices[g] for g in GROUPS], dropna=False).nunique(dropna=False)
    one_per_group = set(within.columns[(within == 1).all()]) if len(within) > 1 else set()
    keys = [k for k in varying_keys(jobs) if k not in {*GROUPS, *one_per_group}]
    return {c.label: override_label(c.jobs[0].overrides, keys) for c in networks}


def _seed_order(seed: Any) -> tuple[int, float, str]:
    """Sort key of seeds: numbers numerically (2 before 10), then the rest by text."""
    try:
        return (0, float(seed), "")
    except (TypeError, ValueError):
        return (1, 0.0, str(seed))


def loss_target(job: Job) -> str | None:
    """The job's ``loss._target_`` (``lossvo.losses.ChordalLoss``), None if missing."""
    target = config_value(job.config, "loss._target_")
    return str(target) if target is not None else None


def loss_class_name(job: Job) -> str | None:
    """The class name of the job's loss (``ChordalLoss``), None if missing."""
    target = loss_target(job)
    return target.rsplit(".", 1)[-1] if target else None


def loss_attribute(target: str | None, name: str) -> float | None:
    """A numeric class attribute (``small_angle_gain``) of the loss class ``target``; None if unavailable."""
    from hydra.utils import get_class

    if not target:
        return None
    try:
        return finite_number(getattr(get_class(target), name, None))
    except Exception:  # a class that cannot be imported here: the report goes on without the attribute
        return None


@dataclass(frozen=True)
class Weighting:
    """A job's rotation weighting: small-angle gain (rotation term ~ gain·theta², rad) and weight (k·gain,
    or gain·exp(s_t − s_r) at the last epoch when learned); None where unknown."""

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
    """How the job weighted its rotation term."""
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
    k = _preset_k(job, target, preset)
    weight = k * gain if k is not None and gain is not None and squared else None
    return Weighting(name, preset, k, gain, weight, squared)


def _preset_k(job: Job, target: str | None, preset: str | None) -> float | None:
    """``loss.k`` if it is a number, else the preset's k (:func:`lossvo.weighting.preset_k`), else None."""
    k = finite_number(config_value(job.config, "loss.k"))
    if k is not None or preset not in ("matched", "paper") or target is None:
        return k
    try:
        return weighting.preset_k(target, preset, config_value(job.config, "weighting.c"))
    except Exception:  # no weighting.c, or a class that cannot be imported here: k unknown
        return None


def short(x: float | None) -> str:
    """A weight or gain with up to 4 significant digits; ``"?"`` if None."""
    return "?" if x is None else f"{x:.4g}"


def weight_text(weightings: Sequence[Weighting]) -> str:
    """The rotation weight of a configuration's seeds as text (``"learned: mean ± std"`` if learned)."""
    if not weightings:
        return "?"
    if any(w.learned for w in weightings):
        cell = Cell.of([w.weight for w in weightings])
        if cell.n == 0:
            return "learned: ? (no train/s_t, train/s_r in metrics.csv)"
        return f"learned: {mean_std_text(cell)}"
    if not all(w.squared for w in weightings):
        return "n/a (unsquared rotation term: not gain·theta²)"
    return ", ".join(sorted({short(w.weight) for w in weightings}))


@dataclass(frozen=True)
class Selection:
    """How a job chose its best checkpoint (``selection.monitor``, ``selection.mode``)."""

    monitor: str
    mode: str


def job_selection(config: Any) -> Selection:
    """The selection metric of a job config; UserError without one."""
    monitor, mode = (config_value(config, f"selection.{key}") for key in ("monitor", "mode"))
    if None in (monitor, mode):
        raise UserError("the job's config has no selection.monitor and selection.mode")
    return Selection(str(monitor), str(mode))


def selections_text(jobs: Sequence[Job]) -> str:
    """The jobs' selection metrics, each once: ``"`val/score` (min)"``."""
    return ", ".join(sorted({f"`{s.monitor}` ({s.mode})" for s in (job_selection(j.config) for j in jobs)}))


def selection_identity(job: Job) -> tuple[Any, ...]:
    """A job's selection metric: monitor, mode (and loss and weights where they define its value)."""
    selection = job_selection(job.config)
    key: tuple[Any, ...] = (selection.monitor, selection.mode)
    if selection.monitor in LOSS_DEPENDENT:
        w = job_weighting(job)
        key += (w.loss, w.preset, None if w.learned else w.k, w.squared)
    return key


def selection_warning(columns: Sequence[Column]) -> str | None:
    """A bold warning if the configurations were selected by different metrics (or one loss-dependent
    monitor over different losses or weights); None if one metric selected them all."""
    networks = [c for c in columns if c.kind == NETWORK and c.jobs]
    if len({selection_identity(j) for c in networks for j in c.jobs}) < 2:
        return None
    per_config = "; ".join(f"{c.label}: {selections_text(c.jobs)}" for c in networks)
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


CONFIGURATION_HEADER = (
    "configuration",
    "loss",
    "weighting",
    "k",
    "gain",
    "rotation weight k·gain",
    "selected by",
    "seeds",
)
"""The configurations table's markdown header (the CSV's: without `` k·gain``, ``_`` for spaces)."""


def configuration_row(column: Column) -> list[str]:
    """One configuration's :data:`CONFIGURATION_HEADER` fields as text (its seeds' values joined)."""
    ws = [job_weighting(j) for j in column.jobs]
    first = ws[0] if ws else Weighting(None, None, None, None, None)
    return [
        column.label,
        first.loss or "?",
        first.preset or "? (not in the config)",
        ", ".join(sorted({short(w.k) for w in ws})),
        short(first.gain),
        weight_text(ws),
        selections_text(column.jobs),
        str(len(column.jobs)),
    ]


def configuration_rows(columns: Sequence[Column], by_architecture: bool = False, csv: bool = False) -> Rows:
    """The configurations table; ``csv``: CSV headers, backticks dropped."""
    networks = [c for c in columns if c.kind == NETWORK]
    rows = [
        [c.architecture, *(v.replace("`", "") if csv else v for v in configuration_row(c))] for c in networks
    ]
    header = [h.removesuffix(" k·gain").replace(" ", "_") if csv else h for h in CONFIGURATION_HEADER]
    return with_architecture(header, rows, by_architecture)
