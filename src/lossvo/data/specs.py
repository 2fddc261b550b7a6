"""The data specs (sources, splits, frames, windows, flow, loader): dataclasses that are also the ``data``
config group's schema (:class:`Data`). Each ``of`` raises UserError naming the full key it refuses;
docs/data.md has the rest.
"""

from __future__ import annotations

import dataclasses
import functools
import sys
from collections.abc import Callable, Mapping
from collections.abc import Sequence as Seq
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from hydra.core.config_store import ConfigStore
from omegaconf import SI, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from lossvo.checks import is_integer, is_number
from lossvo.console import UserError, typed_value_message
from lossvo.data import layouts
from lossvo.data.flow import FlowSetting
from lossvo.data.sequence import split_names
from lossvo.data.synthetic import layouts as synthetic_layouts
from lossvo.data.synthetic.camera import CameraRange
from lossvo.data.synthetic.writer import check_cameras

SYNTHETIC = "synthetic"
"""The layout name of the embedded synthetic dataset: rendered in the KITTI layout on first use."""
NORMALIZATIONS = ("dataset", "flownet")
SPLITS = ("train", "val", "test", "unseen")
SOURCE_KEYS = ("layout", "root", "keep_every", "camera")
_R = TypeVar("_R")
_S = TypeVar("_S")


def _fields(cls: type, value: Any, where: str) -> dict[str, Any]:
    """``value`` as a dict of ``cls``'s fields; UserError for a non-mapping or an unknown key."""
    names = [f.name for f in dataclasses.fields(cls)]
    if value is not None and not isinstance(value, Mapping):
        one = isinstance(value, str | int | float)
        hint = f" (to set one of them: {where}.{names[0]}={value})" if one else ""
        raise UserError(f"{where}: expected a mapping of {', '.join(names)}, got {value!r}{hint}")
    return _known(value or {}, names, where)


def _known(value: Mapping[str, Any], names: Seq[str], where: str) -> dict[str, Any]:
    """``value`` as a dict; UserError naming ``where`` and its first key not in ``names``."""
    unknown = sorted(set(map(str, value)) - set(names))
    if unknown:
        raise UserError(f"{where}.{unknown[0]}: unknown key (expected some of {', '.join(names)})")
    return dict(value)


def _check(where: str, key: str, value: Any, fits: bool, expected: str) -> None:
    if not fits:
        raise UserError(f"{where}.{key}: expected {expected}, got {value!r}")


def _require(spec: object, key: str, fits: Callable[[Any], bool], expected: str) -> None:
    value = getattr(spec, key)
    _check(f"data.{type(spec).__name__.lower()}", key, value, fits(value), expected)


def _camera(value: Any, key: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``{K: 3x3, distortion: [4, 5, 8, 12 or 14 numbers]}`` (distortion optional) as arrays, or None."""
    if value is None:
        return None
    if not isinstance(value, Mapping) or set(value) - {"K", "distortion"} or "K" not in value:
        raise UserError(
            f"{key}: expected {{K: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], distortion: [...]}}, got {value!r}"
        )
    try:
        K = np.asarray(value["K"], dtype=np.float64)
        distortion = np.asarray(value.get("distortion") or np.zeros(5), dtype=np.float64)
    except (TypeError, ValueError):
        K, distortion = np.zeros(0), np.zeros(0)
    fits = bool(K.shape == (3, 3) and np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0)
    _check(key, "K", value["K"], fits, "a 3x3 matrix of pixels with fx, fy > 0")
    fits = bool(distortion.shape in ((4,), (5,), (8,), (12,), (14,)) and np.isfinite(distortion).all())
    _check(key, "distortion", value.get("distortion"), fits, "4, 5, 8, 12 or 14 numbers")
    return K, distortion


@dataclass(frozen=True)
class Render:
    """How the synthetic dataset is rendered (:func:`lossvo.data.synthetic.ensure_dataset`; None: default)."""

    frame_counts: int | dict[str, int] | None = None
    render_height: int | None = None
    render_width: int | None = None
    seed: int = 0
    route_families: dict[str, Any] | None = None
    route_mixes: dict[str, Any] | None = None
    render_layout: str = "kitti"
    render_scale: float = 1.0
    cameras: CameraRange | None = None


@dataclass(frozen=True)
class Source:
    """One dataset a data module reads: a layout of :data:`lossvo.data.layouts.LAYOUTS` or ``synthetic``
    (rendered into ``root`` on first use, as ``render`` says); ``camera``: K (3, 3) pixels and OpenCV
    distortion replacing the reader's (None: the reader's)."""

    layout: str
    root: Path
    keep_every: int = 1
    camera: tuple[np.ndarray, np.ndarray] | None = None
    render: Render | None = None

    @property
    def reader(self) -> str:
        """The layout its files are read in."""
        return self.render.render_layout if self.render is not None else self.layout

    def file_name(self, name: str) -> str:
        """The name the reader knows a sequence by (a rendered one's in its layout's naming)."""
        return synthetic_layouts.sequence_name(self.reader, name) if self.render is not None else name

    @classmethod
    def of(cls, value: Any, where: str, default_root: Path) -> Source:
        """A source from its config (a synthetic one's with :class:`Render`'s fields; without a root it is
        rendered into ``default_root``)."""
        if not isinstance(value, Mapping):
            raise UserError(f"{where}: expected {{layout: ..., root: ...}}, got {value!r}")
        layout = value.get("layout")
        if layout != SYNTHETIC:
            layouts.check_layout(layout, f"{where}.layout")
        render_keys = [f.name for f in dataclasses.fields(Render)] if layout == SYNTHETIC else []
        _known(value, [*SOURCE_KEYS, *render_keys], where)
        root = value.get("root")
        if root is None and layout != SYNTHETIC:
            raise UserError(f"{where}.root: a value is required (the dataset's folder)")
        every = value.get("keep_every", 1)
        _check(where, "keep_every", every, is_integer(every, 1), "an integer >= 1 (frames)")
        render = _render(value, where) if render_keys else None
        folder = Path(str(root)).expanduser() if root is not None else default_root
        return cls(str(layout), folder, int(every), _camera(value.get("camera"), f"{where}.camera"), render)

    def config(self) -> dict[str, Any]:
        """The source as its config (primitives): what :meth:`of` takes."""
        out: dict[str, Any] = {"layout": self.layout, "root": str(self.root), "keep_every": self.keep_every}
        out["camera"] = self.camera and {"K": self.camera[0].tolist(), "distortion": self.camera[1].tolist()}
        if self.render is not None:
            out.update(dataclasses.asdict(self.render))
            out["cameras"] = None if self.render.cameras is None else self.render.cameras.manifest()
        return out


def _render(value: Mapping[str, Any], where: str) -> Render:
    fields = {f.name: plain(value[f.name]) for f in dataclasses.fields(Render) if f.name in value}
    layout = fields.get("render_layout", "kitti")
    layouts.check_layout(layout, f"{where}.render_layout")
    scale = fields.get("render_scale", 1.0)
    _check(where, "render_scale", scale, is_number(scale) and scale > 0, "a number > 0")
    if fields.get("cameras") is not None:
        check_cameras(layout, fields["cameras"], f"{where}.cameras")
        fields["cameras"] = CameraRange.of(fields["cameras"], f"{where}.cameras")
    counts = fields.get("frame_counts")
    many = isinstance(counts, Mapping) and all(is_integer(v, 2) for v in counts.values())
    fits = counts is None or is_integer(counts, 2) or many
    _check(where, "frame_counts", counts, fits, "an integer >= 2 or {sequence: frames}")
    return Render(**fields)


def plain(value: Any) -> Any:
    """A config value as plain dicts and lists: what a checkpoint may hold."""
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, Seq) and not isinstance(value, str):
        return [plain(v) for v in value]
    return value


def sources_of(value: Any, cache_dir: Path) -> dict[str, Source]:
    """``data.sources``: name -> :class:`Source`; a synthetic one without a root is rendered into
    ``<cache_dir>/synthetic`` (named ``synthetic``) or ``<cache_dir>/synthetic-<name>``."""
    if not isinstance(value, Mapping) or not value:
        raise UserError(f"data.sources: expected a mapping of names to datasets, got {value!r}")
    sources = {}
    for name, entry in value.items():
        if not isinstance(name, str) or not name or "/" in name:
            raise UserError(f"data.sources: expected names without '/', got {name!r}")
        folder = SYNTHETIC if name == SYNTHETIC else f"{SYNTHETIC}-{name}"
        sources[name] = Source.of(entry, f"data.sources.{name}", cache_dir / folder)
    return sources


class _Spec:
    """A spec ``data.<its class, lower case>`` built from a mapping by :meth:`of`."""

    @classmethod
    def of(cls: type[_S], value: Any) -> _S:
        """The spec from its mapping, the keys it lacks taking their defaults."""
        name = cls.__name__.lower()
        given = _fields(cls, value, f"data.{name}")
        try:
            merged = OmegaConf.merge(OmegaConf.structured(cls), given)
            return cls(**OmegaConf.to_container(merged, resolve=True))  # type: ignore[arg-type]
        except OmegaConfBaseException as e:
            raise UserError(f"data.{name}.{typed_value_message(e)}") from None


@dataclass
class Splits(_Spec):
    """Sequence names of each split (``<source>/<sequence>`` with several sources). A value may be
    ``["00", "07"]``, ``"00,07"``, ``[0, 7]`` or ``7`` (typed ``Any`` for that), each a tuple of names."""

    train: Any = field(default_factory=list)
    val: Any = field(default_factory=list)
    test: Any = field(default_factory=list)
    unseen: Any = field(default_factory=list)

    def __post_init__(self) -> None:
        for key in SPLITS:
            given = getattr(self, key)
            names = tuple(split_names(given or []))
            if "" in names:
                raise UserError(f"data.splits.{key}: empty sequence name in {given!r}")
            setattr(self, key, names)


@dataclass
class Frames(_Spec):
    """The cached frames: (height, width) pixels, cropped to that aspect ratio first with ``crop``;
    ``statistics`` ``{mean: [3], std: [3]}`` given instead of computed; ``cache_dir`` None: the default."""

    height: int = 160
    width: int = 208
    crop: bool = False
    normalization: str = "dataset"
    statistics: dict[str, list[float]] | None = None
    cache_dir: str | None = None

    def __post_init__(self) -> None:
        for key in ("height", "width"):
            _require(self, key, lambda v: is_integer(v, 16), "an integer >= 16 pixels")
        _require(self, "normalization", lambda v: v in NORMALIZATIONS, f"one of {', '.join(NORMALIZATIONS)}")
        if self.statistics is None:
            return
        try:
            mean, std = (np.asarray(self.statistics[key], dtype=np.float64) for key in ("mean", "std"))
        except (KeyError, TypeError, ValueError):
            mean = std = np.zeros(0)
        fits = bool(mean.shape == std.shape == (3,) and np.all(std > 0) and np.isfinite(mean).all())
        _require(self, "statistics", lambda _: fits, "{mean: [3 floats], std: [3 floats > 0]}")
        self.statistics = {"mean": mean.tolist(), "std": std.tolist()}


@dataclass
class Windows(_Spec):
    """Training windows: ``seq_len`` frames at each of ``frame_steps``, ``per_epoch`` drawn afresh each
    epoch (None: all). Three defaults are the network's ``reads:`` where it declares them (interpolations
    that a composed config resolves, so that a ``Windows`` made directly names them)."""

    seq_len: int = SI("${oc.select:reads.seq_len,6}")
    frame_steps: list[int] = field(default_factory=lambda: [1])
    per_epoch: int | None = SI("${oc.select:reads.windows_per_epoch,null}")
    batch_size: int = SI("${oc.select:reads.batch_size,8}")

    def __post_init__(self) -> None:
        _require(self, "seq_len", lambda v: is_integer(v, 2), "an integer >= 2 frames")
        _require(self, "batch_size", lambda v: is_integer(v, 1), "an integer >= 1")
        _require(self, "per_epoch", lambda v: v is None or is_integer(v, 1), "null or an integer >= 1")
        steps = "a list of integers >= 1 like [1, 2]"
        _require(self, "frame_steps", lambda v: bool(v) and all(is_integer(s, 1) for s in v), steps)
        self.frame_steps = list(dict.fromkeys(self.frame_steps))


@dataclass
class Flow(_Spec):
    """``data.flow``: the flow cached beside the frames, checked by :class:`lossvo.data.flow.FlowSetting`."""

    method: str = SI("${oc.select:reads.flow,none}")
    scale: float = 1.5


def flow_of(value: Any) -> FlowSetting:
    """``data.flow`` ``{method, scale}`` as a :class:`lossvo.data.flow.FlowSetting`."""
    return FlowSetting(**dataclasses.asdict(Flow.of(value)))


@dataclass
class Loader(_Spec):
    """Where batches are assembled: the host loader's settings; ``on_device`` ``auto``, ``true`` or
    ``false`` (typed ``Any``), :mod:`lossvo.data.resident` within ``device_budget_gb`` GiB."""

    num_workers: int = 2
    pin_memory: bool = False
    on_device: Any = "auto"
    device_budget_gb: float = 8.0

    def __post_init__(self) -> None:
        _require(self, "num_workers", lambda v: is_integer(v, 0), "an integer >= 0")
        _require(self, "on_device", lambda v: v == "auto" or isinstance(v, bool), "auto, true or false")
        _require(self, "device_budget_gb", lambda v: is_number(v) and v >= 0, "a number of GiB >= 0")
        self.device_budget_gb = float(self.device_budget_gb)


@dataclass
class Data:
    """The ``data`` config group's schema: :class:`lossvo.data.datamodules.VODataModule`'s arguments
    (``sources`` and ``transforms`` are checked by the data module). Each spec's default is a typed node
    built without calling the dataclass, whose defaults may be interpolations."""

    _target_: str = "lossvo.data.datamodules.VODataModule"
    splits: Splits = field(default_factory=functools.partial(OmegaConf.structured, Splits))
    frames: Frames = field(default_factory=functools.partial(OmegaConf.structured, Frames))
    windows: Windows = field(default_factory=functools.partial(OmegaConf.structured, Windows))
    flow: Flow = field(default_factory=functools.partial(OmegaConf.structured, Flow))
    loader: Loader = field(default_factory=functools.partial(OmegaConf.structured, Loader))
    transforms: list[Any] = field(default_factory=list)
    sources: dict[str, Any] = field(default_factory=dict)


ConfigStore.instance().store(group="data/shared", name="schema", node=Data)

SPECS: dict[str, type] = {spec.__name__.lower(): spec for spec in (Splits, Frames, Windows, Flow, Loader)}


def refusing_scalar_specs(main: Callable[[], _R]) -> Callable[[], _R]:
    """A Hydra entry point that refuses, before Hydra composes the config, a spec given a value that is no
    mapping (``data.flow=dis``), naming the key to set instead."""

    @functools.wraps(main)
    def wrapped() -> _R:
        for line in sys.argv[1:]:
            key, _, value = line.lstrip("+~").partition("=")
            spec = SPECS.get(key.removeprefix("data.")) if key.startswith("data.") else None
            if spec is not None and value not in ("", "null") and not value.startswith(("{", "$")):
                _fields(spec, value, key)
        return main()

    return wrapped
