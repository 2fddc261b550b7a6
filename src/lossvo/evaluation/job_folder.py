"""A job folder's files, typed: ``status.json``, ``results.json`` (with ``results.csv`` beside it) and
``metrics.csv``, read and written here only.

A job folder holds ``.hydra/``, ``status.json`` (:class:`Status`), ``metrics.csv`` (:class:`MetricsTable`),
``checkpoints/`` (:mod:`lossvo.evaluation.checkpoints`), ``results.json`` (:class:`Results`, the contract
between evaluation and everything that reads a run: the report, the baselines, users; written by
:func:`lossvo.evaluation.results.evaluate_run`), ``results.csv`` (the same scores as a tidy table),
``trajectories/`` and ``plots/``. Every write is atomic (:mod:`lossvo.atomic`), apart from the rows
Lightning's logger appends to ``metrics.csv`` (:func:`append_metrics`).

Each JSON file is a tree of frozen dataclasses (:class:`Record`) read through one path,
:meth:`Record.from_json`: every field is checked against its type annotation, and a file that cannot be
read raises :class:`JobFolderError`, one line naming the file and the key that does not fit. The fields of
``results.json``: docs/training.md. Units: APE / RPE translation in m, rotation in rad (``rot_rad``); KITTI
errors in % and deg per 100 m, null where no 100 m segment exists.
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
from typing import Any, TypeVar, get_args, get_origin, get_type_hints

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

SCHEMA_VERSION = 2
"""The version of :class:`Results` that this code writes and reads."""
TRANSLATION_METRIC = "metric"
TRANSLATION_SCALED = "direction (scaled to the ground-truth step length)"
TRANSLATIONS = {"metric": TRANSLATION_METRIC, "direction": TRANSLATION_SCALED, "cue": TRANSLATION_METRIC}
"""``Results.translation`` for each ``loss.translation`` (:data:`lossvo.losses.TRANSLATIONS`): a network
trained on the direction only is scored with each predicted step scaled to the ground-truth step length;
one trained on metric steps where a platform gives scale a cue chains its steps as predicted, and each
sequence's ``metric_scale`` says whether its metric or its scale-given RPE is the one to read."""
MULTI_LAYOUT = "multi"
"""The training layout recorded for a network trained on several datasets (their sources:
:attr:`DataRecord.train_sources`)."""


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


# --------------------------------------------------------------------------------------------------
# Records: JSON objects read into dataclasses
# --------------------------------------------------------------------------------------------------

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
    ``dict[str, X]``, ``str``, ``bool``, ``int`` or ``float`` (an integer read as a float)."""
    args = get_args(kind)
    if type(None) in args:
        inner = next(a for a in args if a is not type(None))
        return None if value is None else _value(inner, value, where, nullable=True)
    if isinstance(kind, type) and issubclass(kind, Record):
        return kind.from_json(value, where)
    origin = get_origin(kind)
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


class Record:
    """A frozen dataclass read from and written to a JSON object (:meth:`from_json`, :meth:`to_json`).

    A field's metadata may give ``key``, its JSON key (default: the field's name); ``what`` it must be, in
    an error message (default: its type's words), and ``fits``, a check beyond its type; ``required``,
    whether the key must be in the file although the field has a default; ``inline``, a record whose keys
    are the enclosing object's own, present where that holds the key given.
    """

    @classmethod
    def from_json(cls: type[R], obj: Any, where: str = "") -> R:
        """The record in the JSON object ``obj`` at key path ``where`` (other keys are ignored); a missing
        key takes its field's default. ValueError, one line naming the key path, for a key that is missing
        or a value that does not fit its field's type."""
        obj, values, types = _object(obj, where), {}, get_type_hints(cls)
        for f in fields(cls):  # type: ignore[arg-type]
            name, what, fits = f.metadata.get("key", f.name), f.metadata.get("what"), f.metadata.get("fits")
            at, kind = _path(where, name), types[f.name]
            if "inline" in f.metadata:
                values[f.name] = _value(kind, obj, where) if f.metadata["inline"] in obj else None
            elif name not in obj and not _optional(f):
                raise _MalformedError(f"{at} is missing")
            elif name in obj:
                try:
                    values[f.name] = _value(kind, obj[name], at)
                except _MalformedError:
                    if what is None:
                        raise
                    raise _fail(at, what, obj[name]) from None
                if fits is not None and obj[name] is not None and not fits(obj[name]):
                    raise _fail(at, str(what), obj[name])
        return cls(**values)

    def to_json(self) -> dict[str, Any]:
        """The record as a JSON object, in field order: a key that may be missing is left out where its
        value is None, an inline record's keys are the object's own."""
        out: dict[str, Any] = {}
        for f in fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            if "inline" in f.metadata:
                out |= {} if value is None else value.to_json()
            elif value is not None or not _optional(f):
                out[f.metadata.get("key", f.name)] = _json(value)
        return out


NAMES = {"what": "a list of sequence names"}
REQUIRED = {"required": True}
"""Field metadata (:class:`Record`): a list of sequence names; a key that must be in the file."""


def _json(value: Any) -> Any:
    if isinstance(value, Record):
        return value.to_json()
    if isinstance(value, dict):
        return {k: _json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json(v) for v in value]
    return value


def _read(path: Path, cls: type[R]) -> R:
    """``path`` read as the record ``cls``.

    Raises:
        JobFolderError: missing, unreadable, not JSON, or a key that does not fit (naming it).
    """
    try:
        obj = json.loads(_read_text(path))
    except json.JSONDecodeError as e:
        raise JobFolderError(path, f"invalid JSON ({e.msg} at line {e.lineno})") from None
    try:
        return cls.from_json(obj)
    except _MalformedError as e:
        raise JobFolderError(path, str(e)) from None


# --------------------------------------------------------------------------------------------------
# status.json
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Event(Record):
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
        machine: the processor of a start or resume (:func:`lossvo.machine.machine`).
    """

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
        """The entry as a JSON object: ``event`` and ``time``, then the fields that are set."""
        return {"event": self.event, "time": self.time} | super().to_json()

    @classmethod
    def from_json(cls, obj: Any, where: str = "") -> Event:
        """The entry ``where`` (``history[i]``), each problem prefixed with it: ``history[0]: epoch: ...``."""
        if isinstance(obj, dict) and obj.get("event") is None:
            raise _MalformedError(f"{where}: expected an 'event'")
        try:
            return super().from_json(obj)
        except _MalformedError as e:
            raise _MalformedError(f"{where}: {e}") from None


@dataclass(frozen=True)
class Status(Record):
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

    state: str = field(metadata={"key": "status"})
    history: tuple[Event, ...] = ()
    threads: int | None = None
    metrics: dict[str, float] | None = field(default=None, metadata={"what": "an object of numbers"})
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
        out = super().to_json()
        history = out.pop("history")
        if self.state == "interrupted":
            out["resume_from"] = self.resume_from
        return {"schema_version": STATUS_SCHEMA_VERSION} | out | {"history": history}

    @classmethod
    def from_json(cls, obj: Any, where: str = "") -> Status:
        version = _object(obj, where).get("schema_version", STATUS_SCHEMA_VERSION)
        if version != STATUS_SCHEMA_VERSION:
            raise _MalformedError(
                f"schema_version {version!r} is not supported (supported: {STATUS_SCHEMA_VERSION})"
            )
        state = obj.get("status")
        if state not in STATES:
            raise _MalformedError(f"expected 'status' to be one of {', '.join(STATES)}, got {state!r}")
        return super().from_json({**obj, "history": obj.get("history") or []}, where)


def read_status(folder: Path) -> Status | None:
    """The folder's ``status.json``; None where there is none.

    Raises:
        JobFolderError: unreadable, not JSON, or not a status (naming the key that does not fit).
    """
    path = folder / STATUS
    return _read(path, Status) if path.is_file() else None


def write_status(folder: Path, status: Status) -> None:
    """Write the folder's ``status.json`` atomically."""
    write_text_atomic(folder / STATUS, json.dumps(status.to_json(), indent=2) + "\n")


# --------------------------------------------------------------------------------------------------
# results.json and results.csv
# --------------------------------------------------------------------------------------------------


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
    """The KITTI odometry error (mean over 100-800 m segments): translation in %, rotation in deg per
    100 m; both None with a ``note`` where no segment exists."""

    t_err_pct: float | None
    r_err_deg_per_100m: float | None
    note: str | None = None


@dataclass(frozen=True)
class Scores(Record):
    """One trajectory (or several pooled) against its ground truth: APE, RPE and the KITTI error, as
    :func:`lossvo.evaluation.metrics.evaluate` computes them (its dict is read with :meth:`from_json`), and
    the scale-given RPE ``rpe_scaled`` (each step scaled to the ground-truth step length; None: not
    recorded)."""

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
    """One evaluated sequence: its frame count, trajectory and plot files (relative to the run folder),
    the ground-truth pose file it was scored against (absolute; None without one), whether it is of a
    route family never trained on, its :class:`Scores` (None, with a ``note``, without ground
    truth) and ``K``, the (3, 3) intrinsics of the frames the network saw (pixels; None: not recorded);
    ``rate_hz``, the frames a second it was given (of the frames kept); ``rate_from``, ``"timestamps"``
    or ``"assumed"`` (a layout without timestamps: its reader's rate,
    :data:`lossvo.data.layouts.ASSUMED_RATE_HZ`); ``metric_scale``, whether the sequence's platform gives
    metric scale a cue (:data:`lossvo.data.layouts.METRIC_SCALE_LAYOUTS`): its translation is read as the
    metric RPE where true, as the scale-given RPE where false (each None: not recorded). In the file the
    scores' keys are the entry's own."""

    frames: int
    trajectory: str
    plot: str
    ground_truth: str | None
    unseen: bool
    scores: Scores | None = field(default=None, metadata={"inline": "ape"})
    note: str | None = None
    K: list[list[float]] | None = field(
        default=None, metadata={"what": "a 3x3 matrix (pixels) or null", "fits": _is_3x3}
    )
    rate_hz: float | None = None
    rate_from: str | None = None
    metric_scale: bool | None = None

    def to_json(self) -> dict[str, Any]:
        out = super().to_json()
        last = {key: out.pop(key) for key in ("ground_truth", "unseen")}
        return out | last


@dataclass(frozen=True)
class Overall(_ScoredOrNoted):
    """Scores pooled over the evaluated ``sequences`` that have ground truth (None, with a ``note``,
    when none has); in the file the scores' keys are the object's own."""

    sequences: list[str] = field(metadata=NAMES)
    scores: Scores | None = field(default=None, metadata={"inline": "ape"})
    note: str | None = None


@dataclass(frozen=True)
class LossRecord(Record):
    """The network's loss: its class name (``ChordalLoss``) and rotation weight k (None: learned)."""

    name: str | None = field(metadata={"key": "class"})
    k: float | None


@dataclass(frozen=True)
class SourceRecord(Record):
    """One dataset of several: the ``layout`` its sequences are read in
    (:data:`lossvo.data.layouts.LAYOUTS`), its ``root`` folder, every how-many-th frame it kept, and whether
    it is the synthetic town ``rendered`` in that layout (its sequences' two digits are then named as the
    layout names them, :func:`lossvo.data.synthetic.layouts.sequence_name`)."""

    layout: str
    root: str
    keep_every: int = 1
    rendered: bool = False


SOURCE_FIELDS = ("sources", "train_sources")
"""The fields of :class:`DataRecord` that list the datasets of data of several."""


@dataclass(frozen=True)
class DataRecord(Record):
    """The data of an evaluation: the evaluated dataset (``kind``: its datamodule's class path;
    ``root``: its absolute KITTI-layout folder, ``sequences/NN/...`` and ``poses/NN.txt``; its ``test``
    and ``unseen`` sequences) and the data the network was trained on (``train_root``, the training
    split ``train``) with its input settings (``height``, ``width`` in pixels, ``seq_len`` in frames,
    ``normalization``, per-channel ``mean`` and ``std`` of pixel values in [0, 1]), and both datasets'
    layouts (``layout``, ``train_layout``: :data:`lossvo.data.layouts.LAYOUTS`) and every how-many-th frame of
    each was kept (``keep_every``, ``train_keep_every``); where absent, read as KITTI's, every
    frame. Data of several datasets has the layout :data:`MULTI_LAYOUT`, sequences named
    ``<source>/<sequence>`` and each source in ``sources`` (evaluated) or ``train_sources`` (trained on);
    both are left out of the file for one dataset. Roots are as recorded; they may no longer exist."""

    kind: str | None
    root: str
    test: list[str] = field(metadata=NAMES)
    unseen: list[str] = field(metadata=NAMES)
    train_root: str | None
    train: list[str] = field(metadata=NAMES)
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


_TRANSLATION = {
    "required": True,
    "what": " or ".join(repr(v) for v in TRANSLATIONS.values()),
    "fits": lambda value: value in TRANSLATIONS.values(),
}
TIDY_COLUMNS = ("sequence", "metric", "part", "statistic", "value")
"""The columns of ``results.csv`` (:meth:`Results.tidy_rows`)."""
RESULTS_KEYS = ("schema_version", "checkpoint", "loss", "align", "delta", "seq_len", "carry_state",
                "mirror_average", "translation", "threads", "data", "sequences", "overall")  # fmt: skip
"""The keys of ``results.json``, in the file's order."""


@dataclass(frozen=True)
class Results(Record):
    """The content of a run's ``results.json``.

    ``checkpoint``: the weights evaluated (None: the last weights of a fit); ``loss``; ``align`` and
    ``delta``: the APE alignment and RPE delta (frames) of every score; ``seq_len``: the window length
    (frames) inferred with; ``carry_state``: whether the recurrent state was carried between windows;
    ``mirror_average``: whether each pose is the average with the mirrored inputs' (absent:
    False);
    ``threads``: the CPU thread count the network was trained with (None: not recorded); ``data``;
    ``sequences``: per evaluated sequence; ``overall``: pooled over the sequences with ground truth;
    ``translation``: :data:`TRANSLATION_METRIC`, the predicted steps as the network gave them, or
    :data:`TRANSLATION_SCALED`, each predicted step scaled to the ground-truth step length before
    chaining and scoring (a network trained with ``loss.translation=direction``; optimistic, as the ORB+E
    baseline with ground-truth scale).
    """

    checkpoint: str | None
    loss: LossRecord
    align: str
    delta: int
    seq_len: int
    carry_state: bool
    data: DataRecord
    sequences: dict[str, SequenceResult]
    overall: Overall
    threads: int | None = field(default=None, metadata=REQUIRED)
    translation: str = field(default=TRANSLATION_METRIC, metadata=_TRANSLATION)
    mirror_average: bool = False
    schema_version: int = SCHEMA_VERSION

    def scored(self) -> dict[str, Scores]:
        """The sequences with ground truth and their scores, in order."""
        return {name: s.scores for name, s in self.sequences.items() if s.scores is not None}

    def unseen(self) -> set[str]:
        """The unseen-motion sequences: those flagged and those the data record lists."""
        return {name for name, s in self.sequences.items() if s.unseen} | set(self.data.unseen)

    def to_json(self) -> dict[str, Any]:
        out = super().to_json()
        return {key: out[key] for key in RESULTS_KEYS}

    @classmethod
    def from_json(cls, obj: Any, where: str = "") -> Results:
        """From parsed JSON of this :data:`SCHEMA_VERSION`; ValueError naming the key path of the first
        field that does not fit."""
        version = _object(obj, where).get("schema_version")
        if version != SCHEMA_VERSION:
            found = "no schema_version" if version is None else f"schema_version {version!r} is not supported"
            raise _MalformedError(
                f"{found} (supported: {SCHEMA_VERSION}); evaluate the checkpoint again "
                "(python -m lossvo.eval ckpt_path=...)"
            )
        return super().from_json(obj, where)

    def tidy_rows(self) -> list[tuple[str, str, str, str, float | None]]:
        """The scores as a tidy table (:data:`TIDY_COLUMNS`): one row per scored sequence (then
        ``overall``, the pooled scores) × metric (``ape``, ``rpe``, ``rpe_scaled``, ``kitti``) × part
        (``trans`` m, ``rot_rad`` rad; KITTI's ``t_err_pct`` %, ``r_err_deg_per_100m``) × statistic
        (KITTI's: ``mean``)."""
        pooled = {"overall": self.overall.scores} if self.overall.scores is not None else {}
        rows: list[tuple[str, str, str, str, float | None]] = []
        for name, scores in {**self.scored(), **pooled}.items():
            for metric, errors in (
                ("ape", scores.ape),
                ("rpe", scores.rpe),
                ("rpe_scaled", scores.rpe_scaled),
            ):
                for part, stats in (("trans", errors.trans), ("rot_rad", errors.rot_rad)) if errors else ():
                    rows += [(name, metric, part, f.name, getattr(stats, f.name)) for f in fields(stats)]
            kitti = scores.kitti
            rows += [(name, "kitti", "t_err_pct", "mean", kitti.t_err_pct),
                     (name, "kitti", "r_err_deg_per_100m", "mean", kitti.r_err_deg_per_100m)]  # fmt: skip
        return rows

    def write(self, path: str | os.PathLike) -> None:
        """Write ``path`` (JSON, NaN allowed) atomically, and beside it, atomically too, the same scores as
        a tidy table (``results.csv``, :meth:`tidy_rows`; an empty value where KITTI has no segment)."""
        write_text_atomic(Path(path), json.dumps(self.to_json(), indent=2, allow_nan=True) + "\n")
        table = io.StringIO()
        writer = csv.writer(table, lineterminator="\n")
        writer.writerow(TIDY_COLUMNS)
        for *keys, value in self.tidy_rows():
            writer.writerow([*keys, "" if value is None else repr(value)])
        write_text_atomic(Path(path).with_name(RESULTS_TABLE), table.getvalue())

    @classmethod
    def read(cls, path: str | os.PathLike) -> Results:
        """Read ``path``.

        Raises:
            JobFolderError: one line naming the file and what is wrong: missing, unreadable, not JSON,
                another schema version, or a field missing or of another type.
        """
        return _read(Path(path), cls)


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
