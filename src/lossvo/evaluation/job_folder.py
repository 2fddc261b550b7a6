"""A job folder's files, typed and read and written here only: ``status.json`` (:class:`Status`),
``results.json`` with ``results.csv`` (:class:`Results`) and ``metrics.csv`` (:class:`MetricsTable`).

Each JSON file is a tree of frozen dataclasses (:class:`Record`) checked against their type annotations;
a file that does not fit raises :class:`JobFolderError` naming the key. Fields and units: docs/training.md.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import MISSING, Field, dataclass, field, fields
from pathlib import Path
from typing import Annotated, Any, TypeVar, get_args, get_origin, get_type_hints

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
State = Annotated[str, f"one of {', '.join(STATES)}", STATES.__contains__]
"""What ``status.json`` says of a run (:class:`Record`'s type of it)."""

STATUS_SCHEMA_VERSION = 1
"""The version of ``status.json`` (a file without ``schema_version`` is read as this one)."""
SCHEMA_VERSION = 2
"""The version of :class:`Results` that this code writes and reads."""
TRANSLATION_METRIC = "metric"
TRANSLATION_SCALED = "direction (scaled to the ground-truth step length)"
TRANSLATIONS = {"metric": TRANSLATION_METRIC, "direction": TRANSLATION_SCALED, "cue": TRANSLATION_METRIC}
"""``Results.translation`` for each ``loss.translation`` (:data:`lossvo.losses.TRANSLATIONS`)."""
TRANSLATED = (TRANSLATION_METRIC, TRANSLATION_SCALED)
Translation = Annotated[str, " or ".join(map(repr, TRANSLATED)), TRANSLATED.__contains__]
"""``Results.translation``: its values, and :class:`Record`'s type of it."""
MULTI_LAYOUT = "multi"
"""The layout recorded for data of several datasets (each in :attr:`DataRecord.sources`)."""


class JobFolderError(UserError):
    """A job folder's file that cannot be read; the message is one line, ``"<path>: <reason>"``."""

    def __init__(self, path: str | os.PathLike, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path, self.reason = Path(path), reason


class _MalformedError(ValueError):
    """A value of a JSON file that does not fit its record (the message names its key path)."""


def _read_text(path: Path) -> str:
    try:
        return path.read_text()
    except FileNotFoundError:
        raise JobFolderError(path, "no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        reason = e.strerror if isinstance(e, OSError) and e.strerror else type(e).__name__
        raise JobFolderError(path, f"unreadable ({reason})") from None


R = TypeVar("R", bound="Record")
S = TypeVar("S", bound="_ScoredOrNoted")


def _path(where: str, name: str) -> str:
    return f"{where}.{name}" if where else name


def _fail(where: str, what: str, value: Any, nullable: bool = False) -> _MalformedError:
    return _MalformedError(f"{where}: expected {what}{' or null' if nullable else ''}, got {value!r:.40}")


def _object(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise _MalformedError(
            f"{where + ': ' if where else ''}expected an object, got {type(value).__name__}"
        )
    return value


_SCALARS: dict[Any, tuple[str, Callable[[Any], bool]]] = {
    str: ("a string", lambda v: isinstance(v, str)),
    bool: ("true or false", lambda v: isinstance(v, bool)),
    int: ("an integer", is_integer),
    float: ("a number", is_number),
}


def _value(kind: Any, value: Any, where: str, nullable: bool = False) -> Any:
    """``value`` read as ``kind``: a :class:`Record`, ``X | None``, ``list[X]``, ``tuple[X, ...]``,
    ``dict[str, X]``, ``str``, ``bool``, ``int``, ``float`` (an integer read as a float) or
    ``Annotated[X, what, *checks]`` (``what`` the message says it must be, ``checks`` of a value not null)."""
    origin, args = get_origin(kind), get_args(kind)
    if origin is Annotated:
        what, *checks = kind.__metadata__
        try:
            read = _value(args[0], value, where)
        except _MalformedError:
            raise _fail(where, what, value) from None
        if value is not None and not all(check(value) for check in checks):
            raise _fail(where, what, value)
        return read
    if type(None) in args:
        inner = next(a for a in args if a is not type(None))
        return None if value is None else _value(inner, value, where, nullable=True)
    if isinstance(kind, type) and issubclass(kind, Record):
        return kind.from_json(value, where)
    if origin in (list, tuple):
        if not isinstance(value, list):
            raise _fail(where, "a list", value, nullable)
        return origin(_value(args[0], v, f"{where}[{i}]") for i, v in enumerate(value))
    if origin is dict:
        return {k: _value(args[1], v, _path(where, k)) for k, v in _object(value, where).items()}
    what, fits = _SCALARS[kind]
    if not fits(value):
        raise _fail(where, what, value, nullable)
    return float(value) if kind is float else value


def _optional(f: Field) -> bool:
    """Whether a field's key may be missing from the file (it has a default, and is not ``required``)."""
    return not f.metadata.get("required") and (f.default is not MISSING or f.default_factory is not MISSING)


def _check_version(obj: dict[str, Any], supported: int, missing: int | None = None, hint: str = "") -> None:
    """Refuse an object whose ``schema_version`` (``missing`` where it has none) is not ``supported``."""
    version = obj.get("schema_version", missing)
    if version != supported:
        found = "no schema_version" if version is None else f"schema_version {version!r} is not supported"
        raise _MalformedError(f"{found} (supported: {supported}){hint}")


class Record:
    """A frozen dataclass read from and written to a JSON object (:meth:`from_json`, :meth:`to_json`),
    checked against its type annotations (:func:`_value`).

    A field's metadata may give ``key`` (its JSON key), ``required`` (the key must be there despite a
    default) and ``inline`` (a record whose keys are the enclosing object's own, present where that holds
    this key). The JSON keys are in field order (keyword-only fields keep their place).
    """

    @classmethod
    def from_json(cls: type[R], obj: Any, where: str = "") -> R:
        """The record in the JSON object ``obj`` at key path ``where`` (other keys ignored); ValueError
        naming the key path of a key missing or a value that does not fit."""
        obj, values, types = _object(obj, where), {}, get_type_hints(cls, include_extras=True)
        for f in fields(cls):  # type: ignore[arg-type]
            name = f.metadata.get("key", f.name)
            if "inline" in f.metadata:
                values[f.name] = _value(types[f.name], obj, where) if f.metadata["inline"] in obj else None
            elif name in obj:
                values[f.name] = _value(types[f.name], obj[name], _path(where, name))
            elif not _optional(f):
                raise _MalformedError(f"{_path(where, name)} is missing")
        return cls(**values)

    def to_json(self) -> dict[str, Any]:
        """The record as a JSON object, in field order, without the optional keys that are None."""
        out: dict[str, Any] = {}
        for f in fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            if "inline" in f.metadata:
                out |= {} if value is None else value.to_json()
            elif value is not None or not _optional(f):
                out[f.metadata.get("key", f.name)] = _json(value)
        return out


Names = Annotated[list[str], "a list of sequence names"]
REQUIRED = {"required": True}
"""For :class:`Record`: the type of a list of sequence names; the metadata of a key that must be there."""


def _json(value: Any) -> Any:
    if isinstance(value, Record):
        return value.to_json()
    if isinstance(value, dict):
        return {k: _json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json(v) for v in value]
    return value


def _read(path: Path, cls: type[R]) -> R:
    """``path`` read as the record ``cls``; JobFolderError where it cannot be."""
    try:
        obj = json.loads(_read_text(path))
    except json.JSONDecodeError as e:
        raise JobFolderError(path, f"invalid JSON ({e.msg} at line {e.lineno})") from None
    try:
        return cls.from_json(obj)
    except _MalformedError as e:
        raise JobFolderError(path, str(e)) from None


@dataclass(frozen=True)
class Event(Record):
    """One entry of a run's history: ``event`` (``"started"``, ``"resumed"``, ``"stopped"``, ``"killed"``,
    ``"failed"``, ``"completed"``) at ``time`` (UTC, ISO 8601; None where unknown), an ``epoch`` counted
    from 1, ``source`` the checkpoint a resume continues from; ``code`` and ``machine``: see
    :mod:`lossvo.code_version`, :mod:`lossvo.machine`."""

    event: str
    time: str | None = None
    signal: str | None = None
    epoch: int | None = None
    stage: str | None = None
    source: str | None = field(default=None, metadata={"key": "from"})
    error: str | None = None
    slurm_job: str | None = None
    slurm_restarts: int | None = None
    code: str | None = None
    machine: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {"event": self.event, "time": self.time} | super().to_json()


@dataclass(frozen=True)
class Status(Record):
    """A job folder's ``status.json``: ``state`` (:data:`STATES`, ``"status"`` in the file), the folder's
    ``history`` (oldest first), a completed run's last ``metrics``, and what stopped a failed or
    interrupted run (``resume_from``: its ``last.ckpt``, None where there is none)."""

    state: State = field(metadata={"key": "status"})
    history: tuple[Event, ...] = ()
    threads: int | None = None
    metrics: Annotated[dict[str, float] | None, "an object of numbers"] = None
    error: str | None = None
    signal: str | None = None
    epoch: int | None = None
    stage: str | None = None
    resume_from: str | None = None

    @property
    def stop(self) -> str:
        """What stopped an interrupted run: ``"SIGTERM during epoch 3"``."""
        where = "the evaluation" if self.stage == "evaluation" else f"epoch {self.epoch or '?'}"
        return f"{self.signal or 'a signal'} during {where}"

    def to_json(self) -> dict[str, Any]:
        out = super().to_json()
        history = out.pop("history")
        if self.state == "interrupted":
            out["resume_from"] = self.resume_from
        return {"schema_version": STATUS_SCHEMA_VERSION} | out | {"history": history}

    @classmethod
    def from_json(cls, obj: Any, where: str = "") -> Status:
        _check_version(_object(obj, where), STATUS_SCHEMA_VERSION, STATUS_SCHEMA_VERSION)
        return super().from_json({**obj, "history": obj.get("history") or []}, where)


def read_status(folder: Path) -> Status | None:
    """The folder's ``status.json``; None where there is none."""
    path = folder / STATUS
    return _read(path, Status) if path.is_file() else None


def write_status(folder: Path, status: Status) -> None:
    """Write the folder's ``status.json`` atomically."""
    write_text_atomic(folder / STATUS, json.dumps(status.to_json(), indent=2) + "\n")


@dataclass(frozen=True)
class Statistics(Record):
    """evo's statistics of an error vector (:func:`lossvo.evaluation.metrics.statistics`), in its unit."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float


@dataclass(frozen=True)
class PoseErrors(Record):
    """APE or RPE: statistics of the translation errors (m) and of the rotation angles (rad)."""

    trans: Statistics
    rot_rad: Statistics


@dataclass(frozen=True)
class KittiError(Record):
    """The KITTI odometry error in % and deg per 100 m; None, with a ``note``, where no segment exists."""

    t_err_pct: float | None
    r_err_deg_per_100m: float | None
    note: str | None = None


@dataclass(frozen=True)
class Scores(Record):
    """One trajectory (or several pooled) against its ground truth, as
    :func:`lossvo.evaluation.metrics.evaluate_relative` computes them (``rpe_scaled`` None: not recorded)."""

    ape: PoseErrors
    rpe: PoseErrors
    kitti: KittiError
    rpe_scaled: PoseErrors | None = None


class _ScoredOrNoted(Record):
    """A record with its scores (the object's own keys) or, without them, a ``note`` saying why."""

    scores: Scores | None
    note: str | None

    @classmethod
    def from_json(cls: type[S], obj: Any, where: str = "") -> S:
        entry = super().from_json(obj, where)
        if entry.scores is None and entry.note is None:
            raise _MalformedError(f"{where}: neither scores (ape, rpe, kitti) nor a note")
        return entry


def _is_3x3(value: Any) -> bool:
    return len(value) == 3 and all(len(row) == 3 for row in value)


@dataclass(frozen=True)
class SequenceResult(_ScoredOrNoted):
    """One evaluated sequence: files relative to the run folder (``ground_truth`` absolute, None without
    one), ``K`` (3, 3) in pixels, ``rate_from`` ``"timestamps"`` or ``"assumed"``; None: not recorded."""

    frames: int
    trajectory: str
    plot: str
    ground_truth: str | None
    unseen: bool
    scores: Scores | None = field(default=None, metadata={"inline": "ape"})
    note: str | None = None
    K: Annotated[list[list[float]] | None, "a 3x3 matrix (pixels) or null", _is_3x3] = None
    rate_hz: float | None = None
    rate_from: str | None = None
    metric_scale: bool | None = None

    def to_json(self) -> dict[str, Any]:
        out = super().to_json()
        last = {key: out.pop(key) for key in ("ground_truth", "unseen")}
        return out | last


@dataclass(frozen=True)
class Overall(_ScoredOrNoted):
    """Scores pooled over the evaluated ``sequences`` with ground truth (None, with a ``note``, without)."""

    sequences: Names
    scores: Scores | None = field(default=None, metadata={"inline": "ape"})
    note: str | None = None


@dataclass(frozen=True)
class LossRecord(Record):
    """The network's loss: its class name (``ChordalLoss``) and rotation weight k (None: learned)."""

    name: str | None = field(metadata={"key": "class"})
    k: float | None


@dataclass(frozen=True)
class SourceRecord(Record):
    """One dataset of several: its ``layout`` (:data:`lossvo.data.layouts.LAYOUTS`), ``root``, frames kept,
    and whether it is the synthetic town ``rendered`` in that layout."""

    layout: str
    root: str
    keep_every: int = 1
    rendered: bool = False


SOURCE_FIELDS = ("sources", "train_sources")
"""The fields of :class:`DataRecord` that list the datasets of data of several."""


@dataclass(frozen=True)
class DataRecord(Record):
    """The data evaluated and the data trained on (``train_*``), with the network's input settings.

    Data of several datasets has the layout :data:`MULTI_LAYOUT`, sequences named ``<source>/<sequence>``
    and its ``sources``, left out of the file for one dataset. Roots are as recorded; they may be gone.
    """

    kind: str | None
    root: str
    test: Names
    unseen: Names
    train_root: str | None
    train: Names
    height: int | None = field(default=None, metadata=REQUIRED)
    width: int | None = field(default=None, metadata=REQUIRED)
    seq_len: int | None = field(default=None, metadata=REQUIRED)
    normalization: str | None = field(default=None, metadata=REQUIRED)
    mean: list[float] | None = field(default=None, metadata=REQUIRED)
    std: list[float] | None = field(default=None, metadata=REQUIRED)
    layout: str = "kitti"
    train_layout: str = "kitti"
    keep_every: int = 1
    train_keep_every: int = 1
    sources: dict[str, SourceRecord] = field(default_factory=dict)
    train_sources: dict[str, SourceRecord] = field(default_factory=dict)

    def identity(self) -> dict[str, Any]:
        """What decides the frames on disk and the training split's poses (a cache key)."""
        train_root = None if self.train_root is None else str(Path(self.train_root))
        identity = {"root": str(Path(self.root)), "train_root": train_root, "train": list(self.train)}
        return identity | {key: value for key, value in self.to_json().items() if key in SOURCE_FIELDS}

    def to_json(self) -> dict[str, Any]:
        return {key: value for key, value in super().to_json().items() if key not in SOURCE_FIELDS or value}


TIDY_COLUMNS = ("sequence", "metric", "part", "statistic", "value")
"""The columns of ``results.csv`` (:meth:`Results.tidy_rows`)."""


@dataclass(frozen=True)
class Results(Record):
    """The content of a run's ``results.json`` (``checkpoint`` None: the last weights of a fit); the
    keyword-only fields are in the file's order among the others."""

    schema_version: int = field(default=SCHEMA_VERSION, kw_only=True)
    checkpoint: str | None
    loss: LossRecord
    align: str
    delta: int
    seq_len: int
    carry_state: bool
    mirror_average: bool = field(default=False, kw_only=True)
    translation: Translation = field(default=TRANSLATION_METRIC, kw_only=True, metadata=REQUIRED)
    threads: int | None = field(default=None, kw_only=True, metadata=REQUIRED)
    data: DataRecord
    sequences: dict[str, SequenceResult]
    overall: Overall

    def scored(self) -> dict[str, Scores]:
        """The sequences with ground truth and their scores, in order."""
        return {name: s.scores for name, s in self.sequences.items() if s.scores is not None}

    def unseen(self) -> set[str]:
        """The unseen-motion sequences: those flagged and those the data record lists."""
        return {name for name, s in self.sequences.items() if s.unseen} | set(self.data.unseen)

    @classmethod
    def from_json(cls, obj: Any, where: str = "") -> Results:
        again = "; evaluate the checkpoint again (python -m lossvo.eval ckpt_path=...)"
        _check_version(_object(obj, where), SCHEMA_VERSION, hint=again)
        return super().from_json(obj, where)

    def tidy_rows(self) -> list[tuple[str, str, str, str, float | None]]:
        """The scores as ``results.csv``'s tidy rows (:data:`TIDY_COLUMNS`): each scored sequence, then
        ``overall``."""
        pooled = {"overall": self.overall.scores} if self.overall.scores is not None else {}
        rows: list[tuple[str, str, str, str, float | None]] = []
        for name, scores in {**self.scored(), **pooled}.items():
            errors = scores.to_json()  # ape, rpe, kitti, then rpe_scaled where recorded
            kitti = errors.pop("kitti")
            for metric, parts in errors.items():
                for part, stats in parts.items():
                    rows += [(name, metric, part, stat, value) for stat, value in stats.items()]
            rows += [(name, "kitti", key, "mean", kitti[key]) for key in ("t_err_pct", "r_err_deg_per_100m")]
        return rows

    def write(self, path: str | os.PathLike) -> None:
        """Write ``path`` (JSON, NaN allowed) and ``results.csv`` beside it (:meth:`tidy_rows`) atomically."""
        write_text_atomic(Path(path), json.dumps(self.to_json(), indent=2, allow_nan=True) + "\n")
        table = io.StringIO()
        writer = csv.writer(table, lineterminator="\n")
        writer.writerow(TIDY_COLUMNS)
        for *keys, value in self.tidy_rows():
            writer.writerow([*keys, "" if value is None else repr(value)])
        write_text_atomic(Path(path).with_name(RESULTS_TABLE), table.getvalue())

    @classmethod
    def read(cls, path: str | os.PathLike) -> Results:
        """Read ``path``; JobFolderError, one line, where it cannot be."""
        return _read(Path(path), cls)


@dataclass
class Curves:
    """Per-epoch values of metrics.csv: ``{column: (epochs (E,) int, values (E,) float)}``."""

    series: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


@dataclass(frozen=True)
class MetricsTable:
    """A ``metrics.csv`` as Lightning's CSV logger writes it: one row per logging call, values as written
    (``""`` where a row does not log a column; ``epoch`` from 0); ``damage``: where reading stopped, for a
    file whose later rows are cut or corrupt."""

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


def read_metrics(folder: Path) -> MetricsTable:
    """The folder's ``metrics.csv`` (empty where there is none), up to a row cut short or corrupt (a process
    killed mid-write); JobFolderError where the file cannot be read or is not CSV."""
    path = folder / METRICS
    if not path.is_file():
        return MetricsTable()
    try:
        header, *lines = list(csv.reader(io.StringIO(_read_text(path)))) or [[]]
    except csv.Error as e:
        raise JobFolderError(path, f"not CSV ({e})") from None
    rows, damage = [], None
    for number, line in enumerate(lines, start=2):
        try:  # a row cut short, or a value float() refuses
            if len(line) != len(header):
                raise ValueError(f"{len(line)} fields, header has {len(header)}")
            for value in filter(str.strip, line):
                float(value)
        except ValueError as e:
            damage = f"line {number} is truncated or corrupt ({e}): later rows ignored"
            break
        rows.append(dict(zip(header, line, strict=True)))
    return MetricsTable(tuple(header), tuple(rows), damage)


def write_metrics(folder: Path, table: MetricsTable) -> None:
    """Write the folder's ``metrics.csv`` whole, atomically."""
    with atomic_path(folder / METRICS, suffix=".csv") as tmp, tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=table.header)
        writer.writeheader()
        writer.writerows(table.rows)


def append_metrics(folder: Path, header: Sequence[str], rows: Sequence[Mapping[str, Any]]) -> None:
    """Append logged rows to the folder's ``metrics.csv`` under ``header``; new columns first rewrite the
    file whole, atomically."""
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
