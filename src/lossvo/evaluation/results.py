"""A trained network evaluated on whole sequences, and ``results.json``: the contract between evaluation and
everything that reads a run (the report, the baselines, users).

:func:`evaluate_run` writes into a run's folder, per sequence, ``trajectories/<sequence>.txt`` (KITTI format,
first pose the ground truth's), the estimate and its ground truth in TUM format (``<sequence>.tum``,
``<sequence>_gt.tum``: ``evo_ape tum`` gives lossvo's APE), ``plots/<sequence>.png`` (a ``/`` in a name
written ``_``, :func:`file_stem`), and ``results.json``: a :class:`Results` (scores per sequence and pooled,
the data evaluated and trained on, the evaluation settings, :data:`SCHEMA_VERSION`), written by
:meth:`Results.write` and read by :meth:`Results.read` only; a file that cannot be read as one raises
:class:`ResultsError`, one line naming the file and the problem. The fields: docs/training.md.

Units: APE / RPE translation in m, rotation in rad (``rot_rad``); KITTI errors in % and deg per 100 m, null
where no 100 m segment exists.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import torch
from torch import Tensor, nn

from lossvo import geometry
from lossvo.atomic import write_text_atomic
from lossvo.checks import is_integer, is_number
from lossvo.console import UserError
from lossvo.data import layouts
from lossvo.data.kitti import KittiFormatError, pose_path
from lossvo.data.pose_files import write_poses
from lossvo.data.sequence import sequence_names
from lossvo.data.windows import gaps
from lossvo.evaluation import metrics
from lossvo.evaluation.inference import predict_sequence
from lossvo.evaluation.job_folder import RESULTS, RESULTS_TABLE
from lossvo.evaluation.plots import plot_birdseye
from lossvo.evaluation.trajectories import integrate, scale_steps, write_tum

if TYPE_CHECKING:
    from lossvo.data.datamodules import VODataModule
    from lossvo.losses import PoseLoss

log = logging.getLogger("lossvo")

SCHEMA_VERSION = 2
"""The version of :class:`Results` that this code writes and reads."""
TRANSLATION_METRIC = "metric"
TRANSLATION_SCALED = "direction (scaled to the ground-truth step length)"
TRANSLATIONS = {"metric": TRANSLATION_METRIC, "direction": TRANSLATION_SCALED, "cue": TRANSLATION_METRIC}
"""``Results.translation`` for each ``loss.translation`` (:data:`lossvo.losses.TRANSLATIONS`): a network
trained on the direction only is scored with each predicted step scaled to the ground-truth step length;
one trained on metric steps where a platform gives scale a cue chains its steps as predicted, and each
sequence's ``metric_scale`` says whether its metric or its scale-given RPE is the one to read."""
NO_SEGMENT_NOTE = "sequence too short for any KITTI segment (100-800 m): no KITTI error"
NO_GT_NOTE = "no ground truth (no pose file): trajectory starts at identity, no metrics"
NO_METRICS_NOTE = "no sequence with ground truth: no metrics"


class ResultsError(UserError):
    """A results.json that cannot be read as :class:`Results`; the message is one line,
    ``"<path>: <reason>"``."""

    def __init__(self, path: str | os.PathLike, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path, self.reason = Path(path), reason


class _MalformedError(ValueError):
    """A field of the JSON being read that does not fit the contract (the message names its key path)."""


# --------------------------------------------------------------------------------------------------
# Reading typed fields out of parsed JSON
# --------------------------------------------------------------------------------------------------


def _key(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def _object(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise _MalformedError(f"{where or 'the file'}: expected an object, got {type(value).__name__}")
    return value


def _field(obj: dict[str, Any], key: str, where: str) -> Any:
    if key not in obj:
        raise _MalformedError(f"{_key(where, key)} is missing")
    return obj[key]


def _expect(value: Any, where: str, fits: bool, what: str, optional: bool = False) -> Any:
    """``value`` where it ``fits`` (or is None and ``optional``); else ``<where>: expected <what>``."""
    if fits or (value is None and optional):
        return value
    raise _MalformedError(f"{where}: expected {what}{' or null' if optional else ''}, got {value!r:.40}")


def _number(value: Any, where: str, optional: bool = False) -> float | None:
    value = _expect(value, where, is_number(value), "a number", optional)
    return None if value is None else float(value)


def _integer(value: Any, where: str, optional: bool = False) -> int | None:
    return _expect(value, where, is_integer(value), "an integer", optional)


def _text(value: Any, where: str, optional: bool = False) -> str | None:
    return _expect(value, where, isinstance(value, str), "a string", optional)


def _flag(value: Any, where: str) -> bool:
    return _expect(value, where, isinstance(value, bool), "true or false")


def _names(value: Any, where: str) -> list[str]:
    fits = isinstance(value, list) and all(isinstance(v, str) for v in value)
    return list(_expect(value, where, fits, "a list of sequence names"))


def _translation(value: Any, where: str) -> str:
    fits = isinstance(value, str) and value in TRANSLATIONS.values()
    return _expect(value, where, fits, " or ".join(repr(v) for v in TRANSLATIONS.values()))


def _numbers(value: Any, where: str) -> list[float] | None:
    if _expect(value, where, isinstance(value, list), "a list of numbers", optional=True) is None:
        return None
    return [cast("float", _number(v, f"{where}[{i}]")) for i, v in enumerate(value)]


# --------------------------------------------------------------------------------------------------
# The contract
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Statistics:
    """evo's statistics of an error vector (:func:`lossvo.evaluation.metrics.statistics`), in its unit."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float

    @classmethod
    def from_json(cls, obj: Any, where: str) -> Statistics:
        obj = _object(obj, where)
        values = {f.name: _number(_field(obj, f.name, where), _key(where, f.name)) for f in fields(cls)}
        return cls(**cast("dict[str, float]", values))

    def to_json(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class PoseErrors:
    """APE or RPE: statistics of the translation errors (m) and of the rotation angles (rad)."""

    trans: Statistics
    rot_rad: Statistics

    @classmethod
    def from_json(cls, obj: Any, where: str) -> PoseErrors:
        obj = _object(obj, where)
        trans, rot = (
            Statistics.from_json(_field(obj, k, where), _key(where, k)) for k in ("trans", "rot_rad")
        )
        return cls(trans, rot)

    def to_json(self) -> dict[str, Any]:
        return {"trans": self.trans.to_json(), "rot_rad": self.rot_rad.to_json()}


@dataclass(frozen=True)
class KittiError:
    """The KITTI odometry error (mean over 100-800 m segments): translation in %, rotation in deg per
    100 m; both None with a ``note`` where no segment exists."""

    t_err_pct: float | None
    r_err_deg_per_100m: float | None
    note: str | None = None

    @classmethod
    def from_json(cls, obj: Any, where: str) -> KittiError:
        obj = _object(obj, where)
        t, r = (
            _number(_field(obj, k, where), _key(where, k), optional=True)
            for k in ("t_err_pct", "r_err_deg_per_100m")
        )
        return cls(t, r, _text(obj.get("note"), _key(where, "note"), optional=True))

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"t_err_pct": self.t_err_pct, "r_err_deg_per_100m": self.r_err_deg_per_100m}
        return out | ({"note": self.note} if self.note is not None else {})


@dataclass(frozen=True)
class Scores:
    """One trajectory (or several pooled) against its ground truth: APE, RPE and the KITTI error, as
    :func:`lossvo.evaluation.metrics.evaluate` computes them, and the scale-given RPE ``rpe_scaled``
    (each step scaled to the ground-truth step length; None: not recorded)."""

    ape: PoseErrors
    rpe: PoseErrors
    kitti: KittiError
    rpe_scaled: PoseErrors | None = None

    @classmethod
    def from_json(cls, obj: Any, where: str = "") -> Scores:
        """From :func:`lossvo.evaluation.metrics.evaluate_relative`'s dict (or its JSON); ValueError naming
        the key path of a field that does not fit."""
        obj = _object(obj, where)
        ape, rpe = (PoseErrors.from_json(_field(obj, k, where), _key(where, k)) for k in ("ape", "rpe"))
        kitti = KittiError.from_json(_field(obj, "kitti", where), _key(where, "kitti"))
        scaled = obj.get("rpe_scaled")
        scaled = None if scaled is None else PoseErrors.from_json(scaled, _key(where, "rpe_scaled"))
        return cls(ape, rpe, kitti, scaled)

    def to_json(self) -> dict[str, Any]:
        out = {"ape": self.ape.to_json(), "rpe": self.rpe.to_json(), "kitti": self.kitti.to_json()}
        return out | ({"rpe_scaled": self.rpe_scaled.to_json()} if self.rpe_scaled is not None else {})


@dataclass(frozen=True)
class SequenceResult:
    """One evaluated sequence: its frame count, trajectory and plot files (relative to the run folder),
    the ground-truth pose file it was scored against (absolute; None without one), whether it is of a
    route family never trained on, its :class:`Scores` (None, with a ``note``, without ground
    truth) and ``K``, the (3, 3) intrinsics of the frames the network saw (pixels; None: not recorded);
    ``rate_hz``, the frames a second it was given (of the frames kept); ``rate_from``, ``"timestamps"``
    or ``"assumed"`` (a layout without timestamps: its reader's rate,
    :data:`lossvo.data.layouts.ASSUMED_RATE_HZ`); ``metric_scale``, whether the sequence's platform gives
    metric scale a cue (:data:`lossvo.data.layouts.METRIC_SCALE_LAYOUTS`): its translation is read as the
    metric RPE where true, as the scale-given RPE where false (each None: not recorded)."""

    frames: int
    trajectory: str
    plot: str
    ground_truth: str | None
    unseen: bool
    scores: Scores | None = None
    note: str | None = None
    K: list[list[float]] | None = None
    rate_hz: float | None = None
    rate_from: str | None = None
    metric_scale: bool | None = None

    @classmethod
    def from_json(cls, obj: Any, where: str) -> SequenceResult:
        obj = _object(obj, where)
        scores = Scores.from_json(obj, where) if "ape" in obj else None
        note = _text(obj.get("note"), _key(where, "note"), optional=True)
        if scores is None and note is None:
            raise _MalformedError(f"{where}: neither scores (ape, rpe, kitti) nor a note")
        return cls(
            frames=cast("int", _integer(_field(obj, "frames", where), _key(where, "frames"))),
            trajectory=cast("str", _text(_field(obj, "trajectory", where), _key(where, "trajectory"))),
            plot=cast("str", _text(_field(obj, "plot", where), _key(where, "plot"))),
            ground_truth=_text(_field(obj, "ground_truth", where), _key(where, "ground_truth"), True),
            unseen=_flag(_field(obj, "unseen", where), _key(where, "unseen")),
            scores=scores,
            note=note,
            K=_intrinsics(obj.get("K"), _key(where, "K")),
            rate_hz=_number(obj.get("rate_hz"), _key(where, "rate_hz"), optional=True),
            rate_from=_text(obj.get("rate_from"), _key(where, "rate_from"), optional=True),
            metric_scale=_optional_flag(obj.get("metric_scale"), _key(where, "metric_scale")),
        )

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"frames": self.frames, "trajectory": self.trajectory, "plot": self.plot}
        out |= {"note": self.note} if self.scores is None else self.scores.to_json()
        optional = {"K": self.K, "rate_hz": self.rate_hz, "rate_from": self.rate_from}
        optional["metric_scale"] = self.metric_scale
        out |= {key: value for key, value in optional.items() if value is not None}
        return out | {"ground_truth": self.ground_truth, "unseen": self.unseen}


def _optional_flag(value: Any, where: str) -> bool | None:
    return None if value is None else _flag(value, where)


def _intrinsics(value: Any, where: str) -> list[list[float]] | None:
    """A 3x3 matrix of finite numbers (or None)."""
    fits = value is None or (
        isinstance(value, list)
        and len(value) == 3
        and all(isinstance(row, list) and len(row) == 3 and all(is_number(v) for v in row) for row in value)
    )
    return cast("list[list[float]] | None", _expect(value, where, fits, "a 3x3 matrix (pixels)", True))


@dataclass(frozen=True)
class Overall:
    """Scores pooled over the evaluated ``sequences`` that have ground truth (None, with a ``note``,
    when none has)."""

    sequences: list[str]
    scores: Scores | None = None
    note: str | None = None

    @classmethod
    def from_json(cls, obj: Any, where: str = "overall") -> Overall:
        obj = _object(obj, where)
        scores = Scores.from_json(obj, where) if "ape" in obj else None
        note = _text(obj.get("note"), _key(where, "note"), optional=True)
        if scores is None and note is None:
            raise _MalformedError(f"{where}: neither scores (ape, rpe, kitti) nor a note")
        return cls(_names(_field(obj, "sequences", where), _key(where, "sequences")), scores, note)

    def to_json(self) -> dict[str, Any]:
        rest = {"note": self.note} if self.scores is None else self.scores.to_json()
        return {"sequences": list(self.sequences), **rest}


@dataclass(frozen=True)
class LossRecord:
    """The network's loss: its class name (``ChordalLoss``) and rotation weight k (None: learned)."""

    name: str | None
    k: float | None

    @classmethod
    def from_json(cls, obj: Any, where: str = "loss") -> LossRecord:
        obj = _object(obj, where)
        name = _text(_field(obj, "class", where), _key(where, "class"), optional=True)
        return cls(name, _number(_field(obj, "k", where), _key(where, "k"), optional=True))

    def to_json(self) -> dict[str, Any]:
        return {"class": self.name, "k": self.k}


MULTI_LAYOUT = "multi"
"""The training layout recorded for a network trained on several datasets (their sources:
:attr:`DataRecord.train_sources`)."""


@dataclass(frozen=True)
class SourceRecord:
    """One dataset of several: the ``layout`` its sequences are read in
    (:data:`lossvo.data.layouts.LAYOUTS`), its ``root`` folder, every how-many-th frame it kept, and whether
    it is the synthetic town ``rendered`` in that layout (its sequences' two digits are then named as the
    layout names them, :func:`lossvo.data.synthetic.layouts.sequence_name`)."""

    layout: str
    root: str
    keep_every: int = 1
    rendered: bool = False

    @classmethod
    def from_json(cls, obj: Any, where: str) -> SourceRecord:
        obj = _object(obj, where)
        return cls(
            layout=cast("str", _text(_field(obj, "layout", where), _key(where, "layout"))),
            root=cast("str", _text(_field(obj, "root", where), _key(where, "root"))),
            keep_every=cast("int", _integer(obj.get("keep_every", 1), _key(where, "keep_every"))),
            rendered=_flag(obj.get("rendered", False), _key(where, "rendered")),
        )

    def to_json(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class DataRecord:
    """The data of an evaluation: the evaluated dataset (``kind``: its datamodule's class path;
    ``root``: its absolute KITTI-layout folder, ``sequences/NN/...`` and ``poses/NN.txt``; its ``test``
    and ``unseen`` sequences) and the data the network was trained on (``train_root``, the training
    split ``train``) with its input settings (``height``, ``width`` in pixels, ``seq_len`` in frames,
    ``normalization``, per-channel ``mean`` and ``std`` of pixel values in [0, 1]), and both datasets'
    layouts (``layout``, ``train_layout``: :data:`lossvo.data.layouts.LAYOUTS`) and every how-many-th frame of
    each was kept (``keep_every``, ``train_keep_every``); where absent, read as KITTI's, every
    frame. Data of several datasets has the layout :data:`MULTI_LAYOUT`, sequences named
    ``<source>/<sequence>`` and each source in ``sources`` (evaluated) or ``train_sources`` (trained on);
    both are empty for one dataset. Roots are as recorded; they may no longer exist."""

    kind: str | None
    root: str
    test: list[str]
    unseen: list[str]
    train_root: str | None
    train: list[str]
    height: int | None = None
    width: int | None = None
    seq_len: int | None = None
    normalization: str | None = None
    mean: list[float] | None = None
    std: list[float] | None = None
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
        return identity | self._sources_json()

    @classmethod
    def from_json(cls, obj: Any, where: str = "data") -> DataRecord:
        obj = _object(obj, where)

        def get(key: str) -> tuple[Any, str]:
            return _field(obj, key, where), _key(where, key)

        return cls(
            kind=_text(*get("kind"), optional=True),
            root=cast("str", _text(*get("root"))),
            test=_names(*get("test")),
            unseen=_names(*get("unseen")),
            train_root=_text(*get("train_root"), optional=True),
            train=_names(*get("train")),
            height=_integer(*get("height"), optional=True),
            width=_integer(*get("width"), optional=True),
            seq_len=_integer(*get("seq_len"), optional=True),
            normalization=_text(*get("normalization"), optional=True),
            mean=_numbers(*get("mean")),
            std=_numbers(*get("std")),
            layout=cast("str", _text(obj.get("layout", "kitti"), _key(where, "layout"))),
            train_layout=cast("str", _text(obj.get("train_layout", "kitti"), _key(where, "train_layout"))),
            keep_every=cast("int", _integer(obj.get("keep_every", 1), _key(where, "keep_every"))),
            train_keep_every=cast(
                "int", _integer(obj.get("train_keep_every", 1), _key(where, "train_keep_every"))
            ),
            sources=_source_records(obj.get("sources", {}), _key(where, "sources")),
            train_sources=_source_records(obj.get("train_sources", {}), _key(where, "train_sources")),
        )

    def to_json(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in SOURCE_FIELDS}
        return out | self._sources_json()

    def _sources_json(self) -> dict[str, Any]:
        """``sources`` and ``train_sources`` as JSON, each only where it lists datasets (data of several)."""
        return {
            key: {k: s.to_json() for k, s in getattr(self, key).items()}
            for key in SOURCE_FIELDS
            if getattr(self, key)
        }


SOURCE_FIELDS = ("sources", "train_sources")
"""The fields of :class:`DataRecord` that list the datasets of data of several."""


def _source_records(obj: Any, where: str) -> dict[str, SourceRecord]:
    """``{name: SourceRecord}`` of a ``sources`` or ``train_sources`` object."""
    return {
        name: SourceRecord.from_json(value, _key(where, name)) for name, value in _object(obj, where).items()
    }


TIDY_COLUMNS = ("sequence", "metric", "part", "statistic", "value")
"""The columns of ``results.csv`` (:meth:`Results.tidy_rows`)."""


@dataclass(frozen=True)
class Results:
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
    threads: int | None = None
    translation: str = TRANSLATION_METRIC
    mirror_average: bool = False
    schema_version: int = field(default=SCHEMA_VERSION)

    def scored(self) -> dict[str, Scores]:
        """The sequences with ground truth and their scores, in order."""
        return {name: s.scores for name, s in self.sequences.items() if s.scores is not None}

    def unseen(self) -> set[str]:
        """The unseen-motion sequences: those flagged and those the data record lists."""
        return {name for name, s in self.sequences.items() if s.unseen} | set(self.data.unseen)

    def to_json(self) -> dict[str, Any]:
        return {
            "schema_version": self.schema_version,
            "checkpoint": self.checkpoint,
            "loss": self.loss.to_json(),
            "align": self.align,
            "delta": self.delta,
            "seq_len": self.seq_len,
            "carry_state": self.carry_state,
            "mirror_average": self.mirror_average,
            "translation": self.translation,
            "threads": self.threads,
            "data": self.data.to_json(),
            "sequences": {name: s.to_json() for name, s in self.sequences.items()},
            "overall": self.overall.to_json(),
        }

    @classmethod
    def from_json(cls, obj: Any) -> Results:
        """From parsed JSON; ValueError naming the key path of the first field that does not fit."""
        obj = _object(obj, "")
        version = obj.get("schema_version")
        if version != SCHEMA_VERSION:
            found = "no schema_version" if version is None else f"schema_version {version!r} is not supported"
            raise _MalformedError(
                f"{found} (supported: {SCHEMA_VERSION}); evaluate the checkpoint again "
                "(python -m lossvo.eval ckpt_path=...)"
            )
        sequences = _object(_field(obj, "sequences", ""), "sequences")
        return cls(
            checkpoint=_text(_field(obj, "checkpoint", ""), "checkpoint", optional=True),
            loss=LossRecord.from_json(_field(obj, "loss", "")),
            align=cast("str", _text(_field(obj, "align", ""), "align")),
            delta=cast("int", _integer(_field(obj, "delta", ""), "delta")),
            seq_len=cast("int", _integer(_field(obj, "seq_len", ""), "seq_len")),
            carry_state=_flag(_field(obj, "carry_state", ""), "carry_state"),
            mirror_average=_flag(obj.get("mirror_average", False), "mirror_average"),
            translation=_translation(_field(obj, "translation", ""), "translation"),
            threads=_integer(_field(obj, "threads", ""), "threads", optional=True),
            data=DataRecord.from_json(_field(obj, "data", "")),
            sequences={n: SequenceResult.from_json(e, f"sequences.{n}") for n, e in sequences.items()},
            overall=Overall.from_json(_field(obj, "overall", "")),
        )

    def tidy_rows(self) -> list[tuple[str, str, str, str, float | None]]:
        """The scores as a tidy table (:data:`TIDY_COLUMNS`): one row per scored sequence (then
        ``overall``, the pooled scores) × metric (``ape``, ``rpe``, ``rpe_scaled``, ``kitti``) × part
        (``trans`` m, ``rot_rad`` rad; KITTI's ``t_err_pct`` %, ``r_err_deg_per_100m``) × statistic."""
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
        """Write ``path`` (JSON, NaN allowed) atomically, and beside it the same scores as a tidy table
        (``results.csv``, :meth:`tidy_rows`; an empty value where KITTI has no segment)."""
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
            ResultsError: one line naming the file and what is wrong: missing, unreadable, not JSON,
                another schema version, or a field missing or of another type.
        """
        try:
            text = Path(path).read_text()
        except FileNotFoundError:
            raise ResultsError(path, "no such file") from None
        except (OSError, UnicodeDecodeError) as e:
            reason = e.strerror if isinstance(e, OSError) and e.strerror else type(e).__name__
            raise ResultsError(path, f"unreadable ({reason})") from None
        try:
            obj = json.loads(text)
        except json.JSONDecodeError as e:
            raise ResultsError(path, f"invalid JSON ({e.msg} at line {e.lineno})") from None
        try:
            return cls.from_json(obj)
        except _MalformedError as e:
            raise ResultsError(path, str(e)) from None


# --------------------------------------------------------------------------------------------------
# Writing it: evaluation of a trained network
# --------------------------------------------------------------------------------------------------


def data_record(
    trained: Mapping[str, Any] | None, evaluated: Mapping[str, Any], splits: Mapping[str, Sequence[str]]
) -> DataRecord:
    """The :class:`DataRecord` of an evaluation.

    Args:
        trained: the description of the data the network was trained on, as its checkpoint records it
            (:meth:`lossvo.data.datamodules.VODataModule.description`, ``VOModule.data``); None for a
            network that was not loaded from a checkpoint: then it is ``evaluated``.
        evaluated: the evaluated datamodule's description.
        splits: the evaluated datamodule's splits (``test``, ``unseen``).
    """
    trained = trained or evaluated
    stats = trained.get("statistics") or {}
    frames = trained.get("frames") or {}
    layout, keep_every = _reading(evaluated)
    train_layout, train_keep_every = _reading(trained)
    return DataRecord(
        kind=evaluated.get("_target_"),
        root=str(evaluated["dataset_root"]),
        test=list(splits.get("test", ())),
        unseen=list(splits.get("unseen", ())),
        train_root=trained.get("dataset_root"),
        train=sequence_names((trained.get("splits") or {}).get("train")),
        height=frames.get("height"),
        width=frames.get("width"),
        seq_len=(trained.get("windows") or {}).get("seq_len"),
        normalization=frames.get("normalization"),
        mean=stats.get("mean"),
        std=stats.get("std"),
        layout=layout,
        train_layout=train_layout,
        keep_every=keep_every,
        train_keep_every=train_keep_every,
        sources=_sources(evaluated) if layout == MULTI_LAYOUT else {},
        train_sources=_sources(trained) if train_layout == MULTI_LAYOUT else {},
    )


def _sources(description: Mapping[str, Any]) -> dict[str, SourceRecord]:
    """Each source of a data description with several: its reading layout (:func:`_reading`), root
    folder and every how-many-th frame kept."""
    out = {}
    for name, source in (description.get("sources") or {}).items():
        layout, keep_every = _reading({"sources": {name: source}})
        rendered = source.get("layout") == "synthetic"
        out[name] = SourceRecord(layout, str(source.get("root")), keep_every, rendered)
    return out


def _reading(description: Mapping[str, Any]) -> tuple[str, int]:
    """The layout a data description's sequences are read in and every how-many-th frame it keeps: its
    one source's; ``multi`` and 1 for several sources (each sequence is named ``<source>/<sequence>``)."""
    sources = list((description.get("sources") or {}).values())
    if len(sources) != 1:
        return MULTI_LAYOUT, 1
    layout = str(sources[0].get("layout"))
    if layout == "synthetic":
        layout = str(sources[0].get("render_layout") or "kitti")
    return layout, int(sources[0].get("keep_every") or 1)


class PooledScores:
    """APE, RPE and the KITTI error pooled over several sequences (torchmetrics: list and sum states that
    hold every sequence scored), with the alignment and RPE delta that every sequence is scored with.

    Args:
        align, delta: APE alignment and RPE delta in frames (:func:`lossvo.evaluation.metrics.evaluate`).
        sync: whether ``compute`` gathers the states of every DDP process (torchmetrics'
            ``sync_on_compute``); False where one process scores every sequence.
    """

    def __init__(self, align: metrics.AlignMode = "none", delta: int = 1, sync: bool = True) -> None:
        self.align, self.delta = align, delta
        self.ape = metrics.APE(align=align, sync_on_compute=sync)
        self.rpe = metrics.RPE(delta=delta, align=align, sync_on_compute=sync)
        self.kitti = metrics.KittiOdometryError(sync_on_compute=sync)
        self.rpe_scaled = metrics.RPE(delta=delta, align=align, sync_on_compute=sync)

    def compute(self) -> dict[str, Any] | None:
        """:func:`lossvo.evaluation.metrics.evaluate_relative`'s dict over every sequence scored; None
        before the first."""
        if not self.ape.trans:
            return None
        computed = {"ape": self.ape.compute(), "rpe": self.rpe.compute(), "kitti": self.kitti.compute()}
        return computed | {"rpe_scaled": self.rpe_scaled.compute()}


def predict_and_score(
    module: nn.Module,
    datamodule: VODataModule,
    name: str,
    gt: np.ndarray | None,
    pooled: PooledScores,
    carry_state: bool = False,
    device: torch.device | None = None,
    mirror_average: bool = False,
) -> tuple[Tensor, dict[str, Any] | None]:
    """One sequence through the network, chained and scored: the path that validation during training
    (:class:`lossvo.training.callbacks.TrajectoryValidation`) and :func:`evaluate_run` share.

    The sequence's inputs go through :func:`lossvo.evaluation.inference.predict_sequence` (windows cut at
    the gaps in its timestamps, :func:`lossvo.data.windows.gaps`); for a network
    trained on the translation's direction only (its loss's ``translation == "direction"``) each step is
    scaled to the ground-truth step length (:func:`lossvo.evaluation.trajectories.scale_steps`); the
    relative poses are chained from the first ground-truth pose and scored against ``gt`` into ``pooled``
    (:func:`lossvo.evaluation.metrics.evaluate_relative`). Without ground truth the trajectory starts at
    the identity, its steps as predicted (there is no length to scale to), and nothing is scored.

    Args:
        module, carry_state, mirror_average: the network (with its ``loss``, a
            :class:`lossvo.losses.PoseLoss`) and :func:`predict_sequence`'s options.
        datamodule: gives the sequence's inputs, their preparation and ``seq_len``.
        name: the sequence.
        gt: (N, 4, 4) ground-truth poses, or None.
        pooled: the metrics the sequence is added to.
        device: where the trajectory is chained and scored (default: the CPU).
    Returns:
        the trajectory (N, 4, 4) float64 and the sequence's :func:`lossvo.evaluation.metrics.evaluate`
        dict (None without ground truth).
    """
    relative = predict_sequence(
        module,
        datamodule.sequence_inputs(name),
        datamodule.prepare,
        datamodule.seq_len,
        carry_state=carry_state,
        mirror_average=mirror_average,
        gap=gaps(datamodule.sequence_times(name)),
    )
    if gt is None:
        return integrate(torch.from_numpy(relative)), None
    gt_t, relative_t = (torch.as_tensor(a, dtype=torch.float64, device=device) for a in (gt, relative))
    if translation_record(module) == TRANSLATION_SCALED:
        relative_t = scale_steps(relative_t, geometry.consecutive_relative_poses(gt_t))
    pooled_metrics = (pooled.ape, pooled.rpe, pooled.kitti)
    return metrics.evaluate_relative(
        relative_t, gt_t, pooled.align, pooled.delta, pooled_metrics, (pooled.rpe_scaled,)
    )


def translation_record(module: nn.Module) -> str:
    """How ``module``'s predicted steps are scored (:data:`TRANSLATIONS` of its loss's ``translation``)."""
    return TRANSLATIONS[cast("PoseLoss", module.loss).translation]


def _ground_truth(datamodule: VODataModule, name: str) -> np.ndarray | None:
    try:
        poses = datamodule.sequence_poses(name)
    except (KittiFormatError, KeyError):
        return None
    return None if poses is None else np.asarray(poses, dtype=np.float64)


def evaluate_run(
    module: nn.Module,
    datamodule: VODataModule,
    out_dir: str | os.PathLike,
    sequences: Sequence[str],
    checkpoint: str | os.PathLike | None = None,
    align: metrics.AlignMode = "none",
    delta: int = 1,
    carry_state: bool = False,
    threads: int | None = None,
    mirror_average: bool = False,
) -> Results:
    """Integrate each sequence with ``module`` and write trajectories, plots and ``results.json``.

    Args:
        module: the trained :class:`lossvo.training.module.VOModule` (on the device to run on): its
            ``loss`` (a :class:`lossvo.losses.PoseLoss`; its ``translation`` decides
            :attr:`Results.translation`) and ``data`` (the training data's description from its
            checkpoint, or None).
        datamodule: the evaluated :class:`lossvo.data.datamodules.VODataModule` (set up here).
        out_dir: folder receiving ``trajectories/NN.txt``, ``plots/NN.png`` and ``results.json``.
        sequences: sequence names, e.g. ``datamodule.evaluated``.
        checkpoint: the checkpoint the weights came from (recorded in ``results.json``).
        align, delta: APE alignment and RPE delta (:func:`lossvo.evaluation.metrics.evaluate`).
        carry_state, mirror_average: see :func:`predict_sequence`.
        threads: the CPU thread count the network was trained with, recorded as given.
    Returns:
        The :class:`Results` written to ``out_dir/results.json``.
    """
    out_dir = Path(out_dir)
    datamodule.setup("test")
    # Evaluation runs in one process (rank 0 of a DDP run): nothing to gather from the others.
    pooled = PooledScores(align, delta, sync=False)
    loss = cast("PoseLoss", module.loss)
    record = LossRecord(type(loss).__name__, loss.k)
    translation = translation_record(module)
    unseen = set(datamodule.splits["unseen"])
    per_sequence: dict[str, SequenceResult] = {}
    for name in sequences:
        gt = _ground_truth(datamodule, name)
        est, scores = predict_and_score(
            module, datamodule, name, gt, pooled, carry_state, mirror_average=mirror_average
        )
        times = datamodule.sequence_times(name)
        entry = _sequence_result(
            name,
            est,
            gt,
            scores,
            out_dir,
            record,
            times,
            name in unseen,
            translation,
            _pose_file(datamodule, name, gt),
        )
        per_sequence[name] = replace(entry, K=datamodule.intrinsics(name).tolist(), **_rate(datamodule, name))
    evaluated = [name for name, entry in per_sequence.items() if entry.scores is not None]
    computed = pooled.compute()
    overall = Overall([], note=NO_METRICS_NOTE) if computed is None else Overall(evaluated, _scores(computed))
    result = Results(
        checkpoint=None if checkpoint is None else str(checkpoint),
        loss=record,
        align=align,
        delta=delta,
        seq_len=int(datamodule.seq_len),
        carry_state=carry_state,
        mirror_average=mirror_average,
        threads=threads,
        translation=translation,
        data=data_record(
            cast("dict[str, Any] | None", module.data), datamodule.description(), datamodule.splits
        ),
        sequences=per_sequence,
        overall=overall,
    )
    result.write(out_dir / RESULTS)
    return result


def _rate(datamodule: VODataModule, name: str) -> dict[str, Any]:
    """A sequence's ``rate_hz``, ``rate_from`` and ``metric_scale`` (:class:`SequenceResult`): the frame rate
    of its kept frames (1 / the median time step, s) and whether its layout's platform gives metric scale a
    cue."""
    layout = datamodule.sequence_layout(name)
    steps = np.diff(datamodule.sequence_times(name))
    rate = float(1.0 / np.median(steps)) if len(steps) else None
    assumed = layout in layouts.ASSUMED_RATE_HZ
    log.debug(
        "sequence %s: %s frames a second (%s)",
        name,
        f"{rate:.4g}" if rate else "?",
        "assumed: the layout has no timestamps" if assumed else "from its timestamps",
    )
    return {
        "rate_hz": rate,
        "rate_from": "assumed" if assumed else "timestamps",
        "metric_scale": datamodule.metric_scale(name),
    }


def _scores(computed: dict[str, Any]) -> Scores:
    """:func:`lossvo.evaluation.metrics.evaluate`'s dict as :class:`Scores`, the KITTI error with a note
    where no segment exists."""
    scores = Scores.from_json(computed)
    if scores.kitti.t_err_pct is None:
        return replace(scores, kitti=replace(scores.kitti, note=NO_SEGMENT_NOTE))
    return scores


def file_stem(name: str) -> str:
    """A sequence's name as a file name: ``"office/Easy/P000"`` -> ``"office_Easy_P000"``."""
    return name.replace("/", "_")


def _pose_file(datamodule: VODataModule, name: str, gt: np.ndarray | None) -> str | None:
    """The dataset's KITTI pose file of a sequence with ground truth (KITTI layout), else None."""
    if gt is None or [s.reader for s in datamodule.sources.values()] != ["kitti"]:
        return None
    return str(pose_path(datamodule.dataset_root(), name))


def _sequence_result(
    name: str,
    est: Tensor,
    gt: np.ndarray | None,
    scores: dict[str, Any] | None,
    out_dir: Path,
    loss: LossRecord,
    times: np.ndarray,
    unseen: bool,
    translation: str = TRANSLATION_METRIC,
    pose_file: str | None = None,
) -> SequenceResult:
    """One sequence's trajectory files, plot and entry in ``results.json``, from :func:`predict_and_score`'s
    trajectory and scores; ``times`` (N,) s of its frames. The entry's ground truth is ``pose_file`` (the
    dataset's KITTI pose file) where given, else the ``_gt.tum`` written here."""
    stem = file_stem(name)
    trajectory, plot = f"trajectories/{stem}.txt", f"plots/{stem}.png"
    write_tum(out_dir / f"trajectories/{stem}.tum", times, est)
    gt_file = None
    if gt is not None:
        write_tum(out_dir / f"trajectories/{stem}_gt.tum", times, gt)
        gt_file = pose_file or str((out_dir / f"trajectories/{stem}_gt.tum").resolve())
    if scores is None:
        entry = SequenceResult(len(est), trajectory, plot, gt_file, unseen, note=NO_GT_NOTE)
        log.info("sequence %s: %s", name, NO_GT_NOTE)
    else:
        typed = _scores(scores)
        entry = SequenceResult(len(est), trajectory, plot, gt_file, unseen, typed)
        log.info(
            "sequence %s: APE trans RMSE %.4g m, RPE trans RMSE %.4g m",
            name,
            typed.ape.trans.rmse,
            typed.rpe.trans.rmse,
        )
    write_poses(out_dir / trajectory, est)
    label = f"estimate ({loss.name}, k={loss.k:g})" if loss.k is not None else "estimate"
    if translation == TRANSLATION_SCALED and gt is not None:
        label += ", steps scaled to the ground truth's"
    plot_birdseye(out_dir / plot, gt, {label: est.numpy()}, f"sequence {name}")
    return entry
