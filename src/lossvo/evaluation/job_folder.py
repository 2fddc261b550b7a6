"""A job folder's record of its run: ``status.json`` and ``metrics.csv``, read and written here only.

A job folder holds ``.hydra/``, ``status.json`` (:class:`Status`), ``metrics.csv`` (:class:`MetricsTable`),
``checkpoints/`` (:mod:`lossvo.evaluation.checkpoints`), ``results.json``
(:class:`lossvo.evaluation.results.Results`), ``trajectories/`` and ``plots/``. Every write is atomic
(:mod:`lossvo.atomic`), apart from the rows Lightning's logger appends to ``metrics.csv``
(:func:`append_metrics`). A file that cannot be read raises :class:`JobFolderError`: one line naming
the file and what is wrong.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from lossvo.atomic import atomic_path, write_text_atomic
from lossvo.checks import is_integer, is_number
from lossvo.console import UserError

STATUS = "status.json"
METRICS = "metrics.csv"
RESULTS = "results.json"
RESULTS_TABLE = "results.csv"
LAST_CHECKPOINT = Path("checkpoints") / "last.ckpt"
"""Paths of a job folder's files, relative to the folder."""

STATES = ("running", "completed", "failed", "interrupted")
"""What ``status.json`` says of a run."""

STATUS_SCHEMA_VERSION = 1
"""The version of ``status.json``'s fields, written in it as ``schema_version``; a file without one is read
as this version."""


class JobFolderError(UserError):
    """A ``status.json`` or ``metrics.csv`` that cannot be read; the message is one line,
    ``"<path>: <reason>"``."""

    def __init__(self, path: str | os.PathLike, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path, self.reason = Path(path), reason


def _read_text(path: Path) -> str:
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        reason = e.strerror if isinstance(e, OSError) and e.strerror else type(e).__name__
        raise JobFolderError(path, f"unreadable ({reason})") from None


# --------------------------------------------------------------------------------------------------
# status.json
# --------------------------------------------------------------------------------------------------

_JSON_NAMES = {"state": "status", "source": "from"}
"""Fields whose JSON key is another word (``from`` is a Python keyword)."""


_INTEGERS = ("epoch", "slurm_restarts", "threads")


def _typed(name: str, value: Any, where: str) -> Any:
    """``value`` of field ``name``, checked against the field's type; UserError naming the key."""
    if name in _INTEGERS:
        kind, fits = "an integer", is_integer(value)
    elif name == "metrics":
        kind = "an object of numbers"
        fits = isinstance(value, dict) and all(is_number(v) for v in value.values())
    else:
        kind, fits = "a string", isinstance(value, str)
    if not fits:
        raise UserError(f"{where}{_JSON_NAMES.get(name, name)}: expected {kind}, got {value!r}")
    return value


def _from_json(cls: type, obj: Any, where: str) -> dict[str, Any]:
    """The fields of dataclass ``cls`` (``history`` aside) found in the JSON object ``obj``, checked
    (other keys are ignored); ``where``: the object's place in the file, prefixed to a message."""
    if not isinstance(obj, dict):
        raise UserError(f"{where}expected an object, got {type(obj).__name__}")
    keys = {f.name: _JSON_NAMES.get(f.name, f.name) for f in fields(cls) if f.name != "history"}
    return {name: _typed(name, obj[key], where) for name, key in keys.items() if obj.get(key) is not None}


@dataclass(frozen=True)
class Event:
    """One entry of a run's history.

    Attributes:
        event: ``"started"``, ``"resumed"``, ``"stopped"``, ``"killed"``, ``"failed"`` or ``"completed"``.
        time: when, in UTC, ISO 8601 to the second; None where unknown (a kill that left no file).
        signal: the signal of a stop (``"SIGTERM"``, ``"SIGINT"``, ``"SIGUSR2"``).
        epoch: the epoch a stop interrupted, or a resume continues with, counted from 1.
        stage: ``"evaluation"`` where a stop interrupted, or a resume continues with, the evaluation.
        source: the checkpoint a resume continues from (``"from"`` in the file).
        error: the error of a failure: a user error's one line, any other ``"Type: message"``.
        slurm_job, slurm_restarts: the SLURM job and how often SLURM requeued it.
        code: the code version of a start or resume (:func:`lossvo.code_version.code_version`).
    """

    event: str
    time: str | None
    signal: str | None = None
    epoch: int | None = None
    stage: str | None = None
    source: str | None = None
    error: str | None = None
    slurm_job: str | None = None
    slurm_restarts: int | None = None
    code: str | None = None

    def to_json(self) -> dict[str, Any]:
        """The entry as a JSON object: ``event`` and ``time``, then the fields that are set."""
        values = {_JSON_NAMES.get(f.name, f.name): getattr(self, f.name) for f in fields(self)}
        return {k: v for k, v in values.items() if v is not None or k in ("event", "time")}

    @classmethod
    def from_json(cls, obj: Any, where: str) -> Event:
        found = _from_json(cls, obj, where)
        if "event" not in found:
            raise UserError(f"{where}expected an 'event'")
        return cls(**{"time": None, **found})


@dataclass(frozen=True)
class Status:
    """A job folder's ``status.json``: what the run is doing, or how it ended, always true.

    Attributes:
        state: one of :data:`STATES` (``"status"`` in the file).
        history: the folder's events, oldest first, across every process that ran in it.
        threads: the CPU thread count the run trains with.
        metrics: a completed run's last value of each column of ``metrics.csv``.
        error: a failed run's error: a user error's one line, any other ``"Type: message"``.
        signal, epoch, stage: what stopped an interrupted run, during which epoch (from 1) or stage.
        resume_from: the ``last.ckpt`` an interrupted run resumes from; None where there is none.
    """

    state: str
    history: tuple[Event, ...] = ()
    threads: int | None = None
    metrics: dict[str, float] | None = None
    error: str | None = None
    signal: str | None = None
    epoch: int | None = None
    stage: str | None = None
    resume_from: str | None = None

    @property
    def stop(self) -> str:
        """What stopped an interrupted run: ``"SIGTERM during epoch 3"``, ``"SIGINT during the
        evaluation"``."""
        where = "the evaluation" if self.stage == "evaluation" else f"epoch {self.epoch or '?'}"
        return f"{self.signal or 'a signal'} during {where}"

    def to_json(self) -> dict[str, Any]:
        """The file's object: ``schema_version``, ``status``, the fields that are set (``resume_from``
        always for an interrupted run), then ``history``."""
        obj = {_JSON_NAMES.get(f.name, f.name): getattr(self, f.name) for f in fields(self)}
        history = [e.to_json() for e in obj.pop("history")]
        kept = {k: v for k, v in obj.items() if v is not None}
        if self.state == "interrupted":
            kept["resume_from"] = self.resume_from
        return {"schema_version": STATUS_SCHEMA_VERSION, **kept, "history": history}

    @classmethod
    def from_json(cls, obj: Any) -> Status:
        found = _from_json(cls, obj, "")
        version = obj.get("schema_version", STATUS_SCHEMA_VERSION)
        if version != STATUS_SCHEMA_VERSION:
            raise UserError(
                f"schema_version {version!r} is not supported (supported: {STATUS_SCHEMA_VERSION})"
            )
        if found.get("state") not in STATES:
            raise UserError(f"expected 'status' to be one of {', '.join(STATES)}, got {obj.get('status')!r}")
        history = obj.get("history") or []
        if not isinstance(history, list):
            raise UserError(f"history: expected a list, got {type(history).__name__}")
        events = tuple(Event.from_json(e, f"history[{i}]: ") for i, e in enumerate(history))
        return cls(**found, history=events)


def read_status(folder: Path) -> Status | None:
    """The folder's ``status.json``; None where there is none.

    Raises:
        JobFolderError: unreadable, not JSON, or not a status (naming the key that does not fit).
    """
    path = folder / STATUS
    if not path.is_file():
        return None
    try:
        obj = json.loads(_read_text(path))
    except json.JSONDecodeError as e:
        raise JobFolderError(path, f"invalid JSON ({e.msg} at line {e.lineno})") from None
    try:
        return Status.from_json(obj)
    except UserError as e:
        raise JobFolderError(path, str(e)) from None


def write_status(folder: Path, status: Status) -> None:
    """Write the folder's ``status.json`` atomically."""
    write_text_atomic(folder / STATUS, json.dumps(status.to_json(), indent=2) + "\n")


# --------------------------------------------------------------------------------------------------
# metrics.csv
# --------------------------------------------------------------------------------------------------


@dataclass
class Curves:
    """Per-epoch values of metrics.csv: ``{column: (epochs (E,) int, values (E,) float)}``."""

    series: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


@dataclass(frozen=True)
class MetricsTable:
    """A ``metrics.csv`` as Lightning's CSV logger writes it: one row per logging call, its values as
    written (strings, ``""`` where the row does not log a column).

    The ``epoch`` column is Lightning's, counted from 0; ``step`` is the global step. Training and
    validation values of an epoch sit on different rows; rows without an epoch (the learning rate's
    first) exist.

    Attributes:
        header: the column names. rows: the complete rows, in file order.
        damage: where reading stopped, for a file whose later rows are cut or corrupt; else None.
    """

    header: tuple[str, ...] = ()
    rows: tuple[dict[str, str], ...] = ()
    damage: str | None = None

    def final(self) -> dict[str, float]:
        """The last value of every metric column (``epoch`` and ``step`` aside), in header order."""
        last: dict[str, float] = {}
        for row in self.rows:
            last.update({key: float(value) for key, value in row.items() if value.strip()})
        return {key: last[key] for key in self.header if key in last and key not in ("epoch", "step")}

    def curves(self) -> Curves:
        """Per column, the last finite value logged in each epoch (empty without an ``epoch`` column)."""
        if "epoch" not in self.header:
            return Curves()
        values = [[float(row[k]) if row[k].strip() else math.nan for k in self.header] for row in self.rows]
        table = np.array(values, dtype=np.float64).reshape(-1, len(self.header))
        epoch = table[:, self.header.index("epoch")]
        curves = Curves()
        for j, name in enumerate(self.header):
            if name in ("epoch", "step"):
                continue
            keep = np.flatnonzero(np.isfinite(epoch) & np.isfinite(table[:, j]))[::-1]  # newest row first
            if keep.size:
                epochs, first = np.unique(epoch[keep].astype(int), return_index=True)
                curves.series[name] = (epochs, table[keep[first], j])
        return curves


def _complete(row: Sequence[str], header: Sequence[str]) -> dict[str, str]:
    """A row as a dict; UserError for a row cut short, ValueError for a value that is not a number."""
    if len(row) != len(header):
        raise UserError(f"{len(row)} fields, header has {len(header)}")
    for value in row:
        if value.strip():
            float(value)
    return dict(zip(header, row, strict=True))


def read_metrics(folder: Path) -> MetricsTable:
    """The folder's ``metrics.csv``; an empty table where there is none. Reading stops at a row cut
    short or holding something other than numbers (a process killed mid-write), said in ``damage``.

    Raises:
        JobFolderError: the file cannot be read, or is not CSV.
    """
    path = folder / METRICS
    if not path.is_file():
        return MetricsTable()
    try:
        header, *lines = list(csv.reader(io.StringIO(_read_text(path)))) or [[]]
    except csv.Error as e:
        raise JobFolderError(path, f"not CSV ({e})") from None
    rows, damage = [], None
    for number, line in enumerate(lines, start=2):
        try:
            rows.append(_complete(line, header))
        except (UserError, ValueError) as e:  # ValueError: float() of a value that is not a number
            damage = f"line {number} is truncated or corrupt ({e}): later rows ignored"
            break
    return MetricsTable(tuple(header), tuple(rows), damage)


def write_metrics(folder: Path, table: MetricsTable) -> None:
    """Write the folder's ``metrics.csv`` whole, atomically."""
    with atomic_path(folder / METRICS, suffix=".csv") as tmp, tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=table.header)
        writer.writeheader()
        writer.writerows(table.rows)


def append_metrics(folder: Path, header: Sequence[str], rows: Sequence[Mapping[str, Any]]) -> None:
    """Append logged rows to the folder's ``metrics.csv`` under ``header`` (CSV as :class:`csv.DictWriter`
    writes it). A header with new columns first rewrites the file whole, atomically, with every row it
    held; a missing file is created with its header."""
    path = folder / METRICS
    if path.is_file():
        with path.open(newline="") as f:
            held = next(csv.reader(f), [])
        if held != list(header):
            write_metrics(folder, MetricsTable(tuple(header), read_metrics(folder).rows))
    else:
        write_metrics(folder, MetricsTable(tuple(header)))
    with path.open("a", newline="") as f:
        csv.DictWriter(f, fieldnames=header).writerows(rows)
