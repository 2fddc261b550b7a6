"""LightningDataModules for datasets in their own layouts (KITTI odometry, TUM RGB-D, EuRoC, TartanAir, MIMIR:
:mod:`lossvo.data.layouts`) and for the embedded synthetic KITTI-layout dataset.

A sample is a window of ``seq_len`` consecutive frames and its ``seq_len - 1`` relative-pose targets;
a batch is a dict, as the model receives it::

    "frames":  (B, seq_len, 3, H, W) float32, normalised per channel
    "targets": (B, seq_len - 1, 4, 4) float32, inv(T_w_k) @ T_w_{k+1} computed in float64
    "K":       (B, 3, 3) float32, the intrinsics of the cached frames (pixels)
    "flow":    (B, seq_len - 1, 2, H, W) float32, optical flow of each pair in pixels (with ``flow``)

The loaders carry frames as uint8 (a window is one copy out of the memory map) and the DataModule
normalises them on the training device in ``on_after_batch_transfer``, Lightning's hook for this.

Training windows start every ``stride`` frames; validation and test windows tile each sequence
(:mod:`lossvo.data.windows`), so that every consecutive pair of a sequence is seen exactly once. No window
spans a gap in a sequence's timestamps (frames its reader dropped): tiles cut there, the pair across a gap a
window of its own.
``prepare_data`` checks the dataset (one clear error naming the file) and builds the frame cache
(:mod:`lossvo.data.frame_cache`) before anything trains. Normalisation statistics come from the training
sequences only, or are FlowNet's ``x / 255 - 0.5`` when its weights are used.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
from collections.abc import Mapping
from collections.abc import Sequence as Seq
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from filelock import FileLock
from torch.utils.data import BatchSampler, DataLoader, Sampler, SequentialSampler

from lossvo.atomic import write_text_atomic
from lossvo.checks import is_integer, is_number
from lossvo.console import UserError
from lossvo.data import flow as optical_flow
from lossvo.data import frame_cache, layouts, resident, synthetic, windows
from lossvo.data import transforms as batch_transforms
from lossvo.data.sequence import Sequence, split_names
from lossvo.data.synthetic import routes
from lossvo.data.windows import EpochShuffle, WindowDataset
from lossvo.geometry import camera

log = logging.getLogger("lossvo")

PAPER_TRAIN = ("00", "02", "03", "04", "05", "06", "08")
PAPER_VAL = ("07", "09")
PAPER_TEST = ("00", "01", "02", "03", "04", "05", "06", "07", "08", "09", "10")
NORMALIZATIONS = ("dataset", "flownet")


def _names(value: str | int | Seq[str | int], key: str) -> tuple[str, ...]:
    """Sequence names from a config value: ["00", "07"], "00,07", [0, 7] or 7 (Hydra turns 07 into 7)."""
    names = split_names(value)
    if "" in names:
        raise UserError(f"data.{key}: empty sequence name in {value!r}")
    return tuple(names)


def _statistics(value: Mapping[str, Seq[float]] | None) -> tuple[np.ndarray, np.ndarray] | None:
    """(mean (3,), std (3,)) from ``{"mean": [3], "std": [3]}``; one line naming the problem otherwise."""
    if value is None:
        return None
    try:
        mean, std = (np.asarray(value[key], dtype=np.float64) for key in ("mean", "std"))
    except (KeyError, TypeError, ValueError):
        mean = std = np.zeros(0)
    if mean.shape != (3,) or std.shape != (3,) or not np.all(std > 0) or not np.isfinite(mean).all():
        raise UserError(f"data.statistics: expected {{mean: [3 floats], std: [3 floats > 0]}}, got {value!r}")
    return mean, std


def _primitive(value: Any) -> Any:
    """A config value as plain Python (lists, dicts, scalars; a transform as its config): what a checkpoint
    may hold."""
    if isinstance(value, batch_transforms.TRANSFORMS):
        return batch_transforms.spec(value)
    if isinstance(value, Mapping):
        return {str(k): _primitive(v) for k, v in value.items()}
    if isinstance(value, Seq) and not isinstance(value, str):
        return [_primitive(v) for v in value]
    return value


def _own_stream() -> torch.Generator:
    """A generator for a DataLoader's worker seeds, seeded with the run's seed: without one, every
    epoch's loader iterator draws from the global stream, which the network's dropout uses."""
    return torch.Generator().manual_seed(torch.initial_seed())


ARGUMENT_CHECKS: tuple[tuple[str, Any, str], ...] = (
    ("height", lambda v: is_integer(v, 16), "an integer >= 16 pixels"),
    ("width", lambda v: is_integer(v, 16), "an integer >= 16 pixels"),
    ("seq_len", lambda v: is_integer(v, 2), "an integer >= 2 frames"),
    ("stride", lambda v: is_integer(v, 1), "an integer >= 1"),
    ("keep_every", lambda v: is_integer(v, 1), "an integer >= 1 (frames)"),
    ("normalization", lambda v: v in NORMALIZATIONS, f"one of {NORMALIZATIONS}"),
    ("windows_per_epoch", lambda v: v is None or is_integer(v, 1), "null or an integer >= 1"),
    ("crop", lambda v: isinstance(v, bool), "true or false"),
    ("on_device", lambda v: v == "auto" or isinstance(v, bool), "auto, true or false"),
    ("device_budget_gb", lambda v: is_number(v) and v >= 0, "a number of GiB >= 0"),
)
"""(argument, test, what is expected) of the datamodule's scalar arguments."""


def _check_arguments(values: Mapping[str, Any]) -> None:
    """UserError ``data.<argument>: expected <what>, got <value>`` at the first argument of
    :data:`ARGUMENT_CHECKS` that fails its test."""
    for key, fits, expected in ARGUMENT_CHECKS:
        if not fits(values[key]):
            raise UserError(f"data.{key}: expected {expected}, got {values[key]!r}")


def _frame_steps(value: Any) -> tuple[int, ...]:
    """``data.frame_steps`` as distinct steps in order; UserError naming the key otherwise."""
    steps = list(value) if isinstance(value, Seq) and not isinstance(value, str) else []
    if not steps or any(not is_integer(v, 1) for v in steps):
        raise UserError(f"data.frame_steps: expected a list of integers >= 1 like [1, 2], got {value!r}")
    return tuple(dict.fromkeys(steps))


def _transforms(value: Any) -> tuple[batch_transforms.Transform, ...]:
    """``data.transforms`` as a tuple of batch transforms (:mod:`lossvo.data.transforms`); UserError naming
    the key otherwise."""
    items = list(value) if isinstance(value, Seq) and not isinstance(value, str) else None
    if items is None or not all(isinstance(t, batch_transforms.TRANSFORMS) for t in items):
        names = ", ".join(t.__name__ for t in batch_transforms.TRANSFORMS)
        raise UserError(f"data.transforms: expected a list of batch transforms ({names} of "
                         f"lossvo.data.transforms, each with its _target_), got {value!r}")  # fmt: skip
    return tuple(items)


@dataclass(frozen=True)
class Source:
    """One dataset a datamodule reads: its ``layout`` (:data:`lossvo.data.layouts.LAYOUTS`), its ``root``,
    every how-many-th frame of its sequences is kept (``keep_every``) and the camera that replaces the one its
    reader gives (``camera``: K (3, 3) pixels and OpenCV distortion; None: the reader's)."""

    layout: str
    root: Path
    keep_every: int = 1
    camera: tuple[np.ndarray, np.ndarray] | None = None


def _camera(value: Any, key: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``{K: 3x3, distortion: [4, 5, 8, 12 or 14 numbers]}`` (distortion optional: zeros) as arrays, or None;
    UserError naming ``key`` otherwise."""
    if value is None:
        return None
    if not isinstance(value, Mapping) or set(value) - {"K", "distortion"} or "K" not in value:
        raise UserError(f"{key}: expected {{K: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], distortion: [...]}}, "
                         f"got {value!r}")  # fmt: skip
    try:
        K = np.asarray(value["K"], dtype=np.float64)
        distortion = np.asarray(value.get("distortion") or np.zeros(5), dtype=np.float64)
    except (TypeError, ValueError):
        K, distortion = np.zeros(0), np.zeros(0)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise UserError(f"{key}.K: expected a 3x3 matrix of pixels with fx, fy > 0, got {value['K']!r}")
    if distortion.shape not in ((4,), (5,), (8,), (12,), (14,)) or not np.isfinite(distortion).all():
        raise UserError(
            f"{key}.distortion: expected 4, 5, 8, 12 or 14 numbers, got {value.get('distortion')!r}"
        )
    return K, distortion


class VODataModule(L.LightningDataModule):
    """A dataset in its own layout: cached frames, windows, the KITTI paper split by default.

    Args:
        root: the dataset's folder: for KITTI the one holding ``sequences/`` and ``poses/`` (or the folder
            holding ``dataset/``), for the other layouts the one holding the sequences.
        layout: the dataset's layout (:data:`lossvo.data.layouts.LAYOUTS`): ``kitti``, ``tum``, ``euroc``,
            ``tartanair`` or ``mimir``.
        train, val, test: sequence names as the dataset names them (``["00", "02"]`` or ``"00,02"``,
            ``["V1_02_medium"]``, ``["abandonedfactory/Easy/P000"]``).
        unseen: sequences of motion unlike the training split's (the synthetic dataset's unseen-motion
            routes), evaluated beside the test sequences and marked as such in reports; need poses.
        height, width: frame size in pixels after resizing (area interpolation).
        seq_len: frames per window (``seq_len - 1`` frame pairs).
        stride: frames between the starts of consecutive training windows.
        windows_per_epoch: if set, each epoch trains on this many windows drawn at random (without
            replacement) from all training windows: short epochs that still see every part of the data.
        batch_size, num_workers: DataLoader settings.
        cache_dir: where frames are cached; default ``$LOSSVO_CACHE`` or ``~/.cache/lossvo``.
        normalization: ``"dataset"`` (per-channel mean/std of the training sequences) or ``"flownet"``.
        transforms: the batch transforms (augmentations) of training batches, applied in this order on
            the training device (:mod:`lossvo.data.transforms`: ``Standstill``, ``Zoom``, ``Mirror``,
            ``Reverse``, ``Jitter``); empty: none.
        frame_steps: frame steps of the training windows, e.g. ``[1, 2]``: every window start at each
            step (every s-th frame, targets recomputed from the poses), so larger steps add faster motion.
            Validation and evaluation always use consecutive frames.
        statistics: ``{"mean": [3], "std": [3]}`` per channel of ``x / 255``: the normalisation of a
            trained network (its checkpoint's), used instead of computing it from the training split,
            which may then be empty (evaluation on data that holds only test sequences).
        flow: optical flow cached beside the frames (:mod:`lossvo.data.flow`): ``"dis"``,
            ``"farneback"`` or ``"none"``; for every frame pair training (each of ``frame_steps``) and
            evaluation (consecutive frames) use. flow_preset: DIS's preset (ultrafast, fast, medium).
            flow_scale: the flow is computed on the source images resized to ``flow_scale`` times
            (height, width), then resized to (height, width) (:class:`lossvo.data.flow.FlowSetting`).
        crop: cut each frame's centred window of the (height, width) aspect ratio before resizing it (K
            follows), so that pixels keep their shape; false: the whole frame, resized (anisotropically when
            the aspect ratios differ).
        camera: ``{K: 3x3, distortion: [k1, k2, p1, p2, k3]}`` replacing the camera the reader gives every
            sequence (pixels of the frames on disk; e.g. a TUM sequence recorded with another camera); null:
            the reader's.
        keep_every: keep every n-th frame of each sequence (the others are never read): matches frame rates
            across datasets (3 turns TUM's 30 Hz into KITTI's 10 Hz). Unlike ``frame_steps`` it applies to
            every split, evaluation included.
        on_device: where training and validation batches are assembled (:mod:`lossvo.data.resident`):
            ``auto``, on an accelerator (a GPU) when the splits' cached arrays fit ``device_budget_gb``
            there, else by the host loader; ``true``, on the training device whenever they fit, a CPU
            included; ``false``, always by the host loader. Both give the same batches; the run's log says
            which one assembles them. Several processes (DDP) always use the host loader.
        device_budget_gb: the most GiB of frames and flow kept on the device.

    Frames with distortion are undistorted once, when the frame cache is built
    (:func:`lossvo.data.frame_cache.undistortion`); :meth:`intrinsics` is K of the cached frames.
    :meth:`description` records the arguments, the dataset root and the normalisation statistics: a
    checkpoint stores it (:mod:`lossvo.training.checkpoints`), so that evaluation needs nothing else.
    """

    def __init__(
        self,
        root: str,
        train: Seq[str] | str = PAPER_TRAIN,
        val: Seq[str] | str = PAPER_VAL,
        test: Seq[str] | str = PAPER_TEST,
        unseen: Seq[str] | str = (),
        height: int = 184,
        width: int = 608,
        seq_len: int = 7,
        stride: int = 1,
        batch_size: int = 8,
        num_workers: int = 2,
        cache_dir: str | None = None,
        normalization: str = "dataset",
        transforms: Seq[batch_transforms.Transform] = (),
        pin_memory: bool = False,
        windows_per_epoch: int | None = None,
        frame_steps: Seq[int] = (1,),
        statistics: Mapping[str, Seq[float]] | None = None,
        flow: str = "none",
        flow_preset: str = "medium",
        flow_scale: float = 1.0,
        layout: str = "kitti",
        keep_every: int = 1,
        crop: bool = False,
        camera: Mapping[str, Any] | None = None,
        on_device: bool | str = "auto",
        device_budget_gb: float = 8.0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters(logger=False, ignore=["transforms"])  # primitives only (a checkpoint's)
        _check_arguments({
            "height": height, "width": width, "seq_len": seq_len, "stride": stride, "keep_every": keep_every,
            "normalization": normalization, "windows_per_epoch": windows_per_epoch, "crop": crop,
            "on_device": on_device, "device_budget_gb": device_budget_gb,
        })  # fmt: skip
        self.root = Path(root).expanduser()
        self.layout = layouts.check_layout(layout)
        self.sources = {"": Source(self.layout, self.root, int(keep_every), _camera(camera, "data.camera"))}
        """The datasets read, by key: one, keyed ``""``, whose sequences are named as it names them; several
        (:class:`MultiDataModule`), whose sequences are named ``<key>/<name>``."""
        self.splits = {
            "train": _names(train, "train"),
            "val": _names(val, "val"),
            "test": _names(test, "test"),
            "unseen": _names(unseen, "unseen"),
        }
        self.statistics = _statistics(statistics)
        self.flow = optical_flow.FlowSetting(flow, flow_preset, flow_scale)
        if not self.splits["train"] and self.statistics is None:
            raise UserError("data.train: expected at least one training sequence")
        self.frame_steps = _frame_steps(frame_steps)
        self.transforms = _transforms(transforms)
        if self.flow.enabled and any(isinstance(t, batch_transforms.Reverse) for t in self.transforms):
            raise UserError(f"data.transforms: Reverse is not possible with data.flow={flow} (the cache "
                             f"holds each pair's forward flow only)")  # fmt: skip
        self.height, self.width, self.seq_len, self.stride = height, width, seq_len, stride
        self.batch_size, self.num_workers, self.pin_memory = batch_size, num_workers, pin_memory
        self.windows_per_epoch = windows_per_epoch
        self.cache_dir = Path(cache_dir).expanduser() if cache_dir else frame_cache.default_cache_dir()
        self.normalization, self.crop = normalization, crop
        self.on_device, self.device_budget_gb = on_device, float(device_budget_gb)
        self.resident: dict[str, resident.ResidentWindows] | None = None  # by split, once decided
        self.sequences: dict[str, Sequence] = {}
        self.mean: np.ndarray | None = None  # per-channel statistics, set by setup
        self.std: np.ndarray | None = None
        self.datasets: dict[str, WindowDataset] = {}
        self._cameras: dict[str, np.ndarray] = {}  # K of each sequence's cached frames (intrinsics)

    # -- preparation: check everything, build the cache, compute statistics --------------------------

    @property
    def all_names(self) -> list[str]:
        return sorted(set().union(*self.splits.values()))

    @property
    def evaluated(self) -> list[str]:
        """The sequences a trained network is evaluated on: test, then unseen-motion ones."""
        return list(dict.fromkeys(self.splits["test"] + self.splits["unseen"]))

    def source_of(self, name: str) -> tuple[Source, str]:
        """The dataset a sequence is read from and the sequence's name there."""
        if "" in self.sources:
            return self.sources[""], name
        key, _, local = name.partition("/")
        return self.sources[key], local

    def _load_metadata(self) -> None:
        """Read every sequence's metadata (every ``keep_every``-th frame); only test sequences may lack
        poses (KITTI 11-21). ``sequences`` is keyed by the names of :attr:`splits`; each Sequence keeps the
        name its dataset gives it."""
        labelled = set(self.splits["train"]) | set(self.splits["val"]) | set(self.splits["unseen"])
        self.sequences, self._cameras = {}, {}
        for name in self.all_names:
            source, local = self.source_of(name)
            root = layouts.dataset_root(source.layout, source.root)
            seq = layouts.load_sequence(source.layout, root, local, require_poses=name in labelled)
            if source.camera is not None:
                seq = dataclasses.replace(seq, K=source.camera[0], distortion=source.camera[1])
            self.sequences[name] = seq.every(source.keep_every)

    def load_metadata(self) -> None:
        """Read and check every sequence's poses, calibration and image list, without building the
        frame cache (for tools that need the ground truth or the PNGs only)."""
        self._load_metadata()

    def cache_path(self, name: str | None = None) -> Path:
        """The frame-cache folder of sequence ``name``'s dataset (None: of the only dataset)."""
        source = next(iter(self.sources.values())) if name is None else self.source_of(name)[0]
        root = layouts.dataset_root(source.layout, source.root).resolve()
        folder = frame_cache.cache_folder(self.cache_dir, root, self.height, self.width)
        suffix = (f"-every{source.keep_every}" if source.keep_every > 1 else "") + (
            "-crop" if self.crop else ""
        )
        return folder.with_name(folder.name + suffix) if suffix else folder

    def _frame_files(self, name: str) -> tuple[Path, Path]:
        """The cached frames (.npy) and their manifest (.json) of sequence ``name``."""
        return frame_cache.files(self.cache_path(name), self.sequences[name].name)

    def _flow_file(self, name: str, step: int) -> Path:
        return optical_flow.flow_file(self.cache_path(name), self.sequences[name].name, step, self.flow)

    def _frames_source(self, name: str) -> dict:
        """What sequence ``name``'s cached frames were built from (``frame_cache.source_of``)."""
        return frame_cache.source_of(self.cache_path(name), self.sequences[name].name)

    def _ensure_frames(self) -> dict[str, np.ndarray]:
        """Every sequence's cached frames, built where missing or stale."""
        return {
            n: frame_cache.ensure_frames(self.cache_path(n), s, self.height, self.width, crop=self.crop)
            for n, s in self.sequences.items()
        }

    def prepare_data(self) -> None:
        """Check the dataset and build the frame cache, the normalisation statistics and the flow (once)."""
        self._prepare()

    def _prepare(self) -> None:
        """Read the metadata, then build what is missing or stale: frames, statistics (:attr:`mean`,
        :attr:`std`), flow."""
        self._load_metadata()
        frames = self._ensure_frames()
        self.mean, self.std = self._stats(frames)
        self._ensure_flow(frames)

    def _stats_path(self) -> Path:
        """Beside the first training sequence's frames, named after the training split."""
        key = hashlib.sha1(",".join(self.splits["train"]).encode()).hexdigest()[:10]
        return self.cache_path(self.splits["train"][0]) / f"stats-{key}.json"

    def _stats(self, frames: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Per-channel mean/std: given (``statistics``), FlowNet's, or of the training sequences (cached
        with the frames; pooled over every training sequence of every dataset)."""
        if self.statistics is not None:
            return self.statistics
        if self.normalization == "flownet":
            return np.full(3, 0.5), np.ones(3)  # (x/255 - 0.5) / 1
        path = self._stats_path()
        sources = {n: self._frames_source(n) for n in self.splits["train"]}
        try:
            saved = json.loads(path.read_text())
            if saved["sources"] == sources:
                return np.array(saved["mean"]), np.array(saved["std"])
        except (OSError, ValueError, KeyError):
            pass
        mean, std = frame_cache.channel_stats([frames[n] for n in self.splits["train"]])
        write_text_atomic(path, json.dumps({"train": self.splits["train"], "sources": sources,
                                            "mean": mean.tolist(), "std": std.tolist()}))  # fmt: skip
        return mean, std

    def flow_steps(self) -> dict[str, tuple[int, ...]]:
        """Sequence -> the frame steps of the pairs a network sees in it: each of ``frame_steps`` in a
        training sequence, and 1 (consecutive frames) in every sequence."""
        train = set(self.splits["train"])
        return {n: tuple(sorted({1, *(self.frame_steps if n in train else ())})) for n in self.all_names}

    def _ensure_flow(self, frames: dict[str, np.ndarray]) -> dict[tuple[str, int], np.ndarray]:
        """The cached flow of every (sequence, step) of :meth:`flow_steps`, computed where missing or
        stale; none without ``flow``."""
        if not self.flow.enabled:
            return {}
        seqs = self.sequences
        return {
            (n, step): optical_flow.ensure_flow(
                self.cache_path(n), seqs[n].name, frames[n], self._frames_source(n), step, self.flow,
                seqs[n].images, undistort=frame_cache.undistortion(seqs[n]), crop=self.crop,
            )
            for n, steps in self.flow_steps().items() for step in steps
        }  # fmt: skip

    def setup(self, stage: str | None = None) -> None:
        """Open the cache (rebuilding anything missing or stale) and build the split datasets."""
        if self.datasets:
            return
        self._prepare()
        for split, names in self.splits.items():
            labelled = [(n, p) for n in names if (p := self.sequences[n].poses) is not None]  # labelled ones
            steps = (1,) if split != "train" else self.frame_steps
            flow_files = None if not self.flow.enabled else {
                step: [self._flow_file(n, step) for n, _ in labelled] for step in steps
            }  # fmt: skip
            self.datasets[split] = WindowDataset(
                [self._frame_files(n)[0] for n, _ in labelled], [p for _, p in labelled],
                self.seq_len, self.stride, self.frame_steps, tiled=split != "train",
                intrinsics=[self.intrinsics(n) for n, _ in labelled], flow_files=flow_files,
                times=[self.sequences[n].times for n, _ in labelled],
            )  # fmt: skip
        if len(self.datasets["train"]) == 0 and self.splits["train"]:
            shortest = min(len(self.sequences[n].images) for n in self.splits["train"])
            raise UserError(f"data.seq_len: {self.seq_len} frames is longer than every training sequence "
                             f"(shortest: {shortest} frames)")  # fmt: skip

    def description(self) -> dict[str, Any]:
        """What a network trained on this data depends on, as primitives (a checkpoint's ``data``):
        ``_target_`` (this class) and the constructor's arguments (``transforms`` as their configs,
        :func:`lossvo.data.transforms.spec`), ``root`` absolute, and, after
        :meth:`setup` (None before), ``statistics`` ``{"mean": [3], "std": [3]}`` and ``intrinsics``, the
        (3, 3) K of each training sequence's cached frames (pixels)."""
        config = {key: _primitive(value) for key, value in self.hparams.items()}
        config["transforms"] = [batch_transforms.spec(t) for t in self.transforms]
        if config.get("root") is not None:
            config["root"] = str(Path(config["root"]).expanduser().resolve())
        stats = None if self.mean is None or self.std is None else {
            "mean": [float(v) for v in self.mean], "std": [float(v) for v in self.std]
        }  # fmt: skip
        target = f"{type(self).__module__}.{type(self).__qualname__}"
        cameras = {n: self.intrinsics(n).tolist() for n in self.splits["train"]} if self.datasets else None
        return {"_target_": target, **config, "statistics": stats, "dataset_root": str(self.dataset_root()),
                "intrinsics": cameras}  # fmt: skip

    def dataset_root(self) -> Path:
        """The absolute folder the layout's reader reads (for KITTI the one holding ``sequences/``); with
        several datasets, the folder their roots share."""
        roots = [str(layouts.dataset_root(s.layout, s.root).resolve()) for s in self.sources.values()]
        return Path(os.path.commonpath(roots))

    def intrinsics(self, name: str) -> np.ndarray:
        """(3, 3) float64 K of a sequence's cached frames: its camera's K (of the undistorted frames where
        they are undistorted: :func:`lossvo.data.frame_cache.source_intrinsics`), resized from the source
        images' size to (height, width) (:func:`lossvo.geometry.camera.resized_intrinsics`); after
        :meth:`setup`; read once a sequence."""
        if name in self._cameras:
            return self._cameras[name].copy()
        manifest = json.loads(self._frame_files(name)[1].read_text())
        source = tuple(manifest["source_size_hw"])
        K = frame_cache.source_intrinsics(self.sequences[name])
        if self.crop:
            box = frame_cache.centre_crop(source, (self.height, self.width))
            K, source = frame_cache.cropped_intrinsics(K, box), box[2:]
        self._cameras[name] = camera.resized_intrinsics(K, source, (self.height, self.width))
        return self._cameras[name].copy()

    # -- where batches are assembled -----------------------------------------------------------------

    def resident_windows(self, split: str) -> resident.ResidentWindows | None:
        """The split's windows kept on the training device, or None where the host loader assembles its
        batches (:attr:`on_device`). Decided once, for the training and validation splits together, and
        said in the log."""
        if self.resident is None:
            self.resident = self._make_resident(self._training_device())
        if self.resident and split not in self.resident:  # the test split, asked for later
            self.resident[split] = self._resident_split(split, next(iter(self.resident.values())).device)
        return self.resident.get(split)

    def _training_device(self) -> torch.device:
        """The device the attached trainer trains on; the CPU without one."""
        strategy = getattr(self.trainer, "strategy", None)
        return getattr(strategy, "root_device", torch.device("cpu"))

    def _make_resident(self, device: torch.device) -> dict[str, resident.ResidentWindows]:
        """The training and validation splits' windows on ``device`` where :attr:`on_device` and the budget
        allow, else nothing (the host loader); one log line either way."""
        splits = [s for s in ("train", "val") if s in self.datasets]
        size = sum(resident.resident_bytes(*self._arrays(s)) for s in splits) / resident.GIB
        setting = f"data.on_device={str(self.on_device).lower()}"
        reason = None
        if self.on_device is False:
            reason = setting
        elif self.on_device == "auto" and device.type == "cpu":
            reason = f"{setting} on a CPU"
        elif getattr(self.trainer, "world_size", 1) > 1:
            reason = f"{getattr(self.trainer, 'world_size', 1)} processes"
        elif size > self.device_budget_gb:
            reason = f"the arrays exceed data.device_budget_gb={self.device_budget_gb:g}"
        if reason is not None:
            log.info("data: batches from the host loader (%s; %.2f GiB of frames and flow)", reason, size)
            return {}
        log.info("data: batches gathered on %s from %.2f GiB of frames and flow kept there (%s)",
                 device, size, setting)  # fmt: skip
        return {s: self._resident_split(s, device) for s in splits}

    def _arrays(self, split: str) -> tuple[list[np.ndarray], dict[int, list[np.ndarray]] | None]:
        """The split's frames and flow arrays (memory maps), per sequence."""
        dataset = self.datasets[split]
        return dataset.frames, (dataset.flow if dataset.flow_files is not None else None)

    def _resident_split(self, split: str, device: torch.device) -> resident.ResidentWindows:
        data = self.datasets[split]
        frames, flow = self._arrays(split)
        return resident.ResidentWindows(data.index, frames, data.targets, data.intrinsics, flow, device)

    # -- loaders --------------------------------------------------------------------------------------

    def _loader(self, split: str, sampler: Sampler | None = None) -> DataLoader:
        return DataLoader(
            self.datasets[split], batch_size=self.batch_size, sampler=sampler, num_workers=self.num_workers,
            pin_memory=self.pin_memory, persistent_workers=self.num_workers > 0, generator=_own_stream(),
        )  # fmt: skip

    def _batches(self, split: str, batches: BatchSampler) -> DataLoader:
        """The split's windows in the given batches: items of the host loader, or index batches that
        :meth:`on_after_batch_transfer` gathers on the device (:mod:`lossvo.data.resident`)."""
        windows = self.resident_windows(split)
        if windows is None:
            return DataLoader(self.datasets[split], batch_sampler=batches, num_workers=self.num_workers,
                              pin_memory=self.pin_memory, persistent_workers=self.num_workers > 0,
                              generator=_own_stream())  # fmt: skip
        return DataLoader(resident.IndexBatches(windows, split), batch_sampler=batches,
                          collate_fn=resident.as_is, generator=_own_stream())  # fmt: skip

    def _tiled_loader(self, split: str) -> DataLoader:
        """Validation or test windows in order, batched by length (a sequence's last may be shorter)."""
        dataset = self.datasets[split]
        batches = windows.SameLengthBatches(
            SequentialSampler(dataset), self.batch_size, lengths=dataset.lengths.tolist()
        )
        return self._batches(split, batches)

    def train_dataloader(self) -> DataLoader:
        """Shuffled training windows; with ``windows_per_epoch``, a fresh random subset every epoch.

        Each epoch's order comes from a generator of its own, seeded with torch's initial seed (the run's
        ``seed``) and the epoch (:class:`EpochShuffle`), so it depends on the seed, the epoch and the data
        alone: not on the network, its head or the loss, which draw from other streams, and a resumed run
        sees the order an uninterrupted one would. Host loader and device gathering give the same batches."""
        dataset = self.datasets["train"]
        count = min(self.windows_per_epoch or len(dataset), len(dataset))
        order = EpochShuffle(len(dataset), count, torch.initial_seed())
        if self.resident_windows("train") is None:
            return self._loader("train", order)
        return self._batches("train", BatchSampler(order, self.batch_size, drop_last=False))

    def val_dataloader(self) -> DataLoader:
        return self._tiled_loader("val")

    def test_dataloader(self) -> DataLoader:
        return self._tiled_loader("test")

    # -- whole sequences (evaluation) -----------------------------------------------------------------

    def normalize(self, frames: torch.Tensor) -> torch.Tensor:
        """uint8 frames (..., 3, H, W) -> float32 ``(x / 255 - mean) / std``, per channel."""
        mean = torch.as_tensor(self.mean, dtype=torch.float32, device=frames.device).view(3, 1, 1)
        std = torch.as_tensor(self.std, dtype=torch.float32, device=frames.device).view(3, 1, 1)
        return frames.float().mul_(1.0 / (255.0 * std)).sub_(mean / std)  # in place: one pass less

    def prepare(self, inputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Loaded inputs, on their device, as a network reads them: frames normalised (:meth:`normalize`),
        flow as float32; the other entries as they are."""
        prepared = {**inputs, "frames": self.normalize(inputs["frames"])}
        if "flow" in inputs:
            prepared["flow"] = inputs["flow"].float()
        return prepared

    def on_after_batch_transfer(
        self, batch: dict[str, torch.Tensor], dataloader_idx: int
    ) -> dict[str, torch.Tensor]:
        """On the training device: an index batch gathered (:mod:`lossvo.data.resident`), when training
        the :attr:`transforms` applied in order, then :meth:`prepare`."""
        if "frame_index" in batch:  # an index batch of windows kept on the device
            windows = self.resident_windows(str(batch["split"]))
            assert windows is not None
            batch = windows.gather(batch)
        inputs = {k: v for k, v in batch.items() if k != "targets"}
        targets = batch["targets"]
        if self.trainer is not None and self.trainer.training:
            for transform in self.transforms:
                inputs, targets = transform(inputs, targets, None)
        return self.prepare({**batch, **inputs, "targets": targets})

    def sequence_inputs(self, name: str) -> dict[str, np.ndarray]:
        """A whole sequence's inputs: ``frames`` (N, 3, H, W) uint8 (memory map), ``K`` (3, 3) float32 and,
        with flow, ``flow`` (N - 1, 2, H, W) float16 (memory map), each consecutive pair's."""
        inputs = {"frames": self.sequence_frames(name), "K": self.intrinsics(name).astype(np.float32)}
        if self.flow.enabled:
            inputs["flow"] = np.load(self._flow_file(name, 1), mmap_mode="r")
        return inputs

    def sequence_frames(self, name: str) -> np.ndarray:
        """(N, 3, H, W) uint8 RGB cached frames of one sequence (memory map; every frame, in order)."""
        self.setup()
        return np.load(self._frame_files(name)[0], mmap_mode="r")

    def sequence_poses(self, name: str) -> np.ndarray | None:
        """(N, 4, 4) float64 ground-truth camera-to-world poses of one sequence (None without a pose file)."""
        self.setup()
        return self.sequences[name].poses

    def sequence_times(self, name: str) -> np.ndarray:
        """(N,) float64 timestamps (s) of one sequence's frames."""
        self.setup()
        return self.sequences[name].times


class KittiDataModule(VODataModule):
    """KITTI odometry (``data=kitti``): :class:`VODataModule` in its default layout, ``kitti``."""


DATASET_KEYS = ("layout", "root", "train", "val", "test", "unseen", "keep_every", "camera")
"""What an entry of :class:`MultiDataModule`'s ``datasets`` may set: the :class:`VODataModule` arguments
it derives from them."""


def _dataset_entries(datasets: Any) -> dict[str, dict[str, Any]]:
    """``data.datasets`` checked: a mapping of keys (no ``/``) to entries with a ``layout`` and a ``root`` and
    only :data:`DATASET_KEYS`; UserError naming the key otherwise."""
    if not isinstance(datasets, Mapping) or not datasets:
        raise UserError(f"data.datasets: expected a mapping of names to datasets, got {datasets!r}")
    entries = {}
    for key, entry in datasets.items():
        where = f"data.datasets.{key}"
        if not isinstance(key, str) or not key or "/" in key:
            raise UserError(f"data.datasets: expected names without '/', got {key!r}")
        if not isinstance(entry, Mapping):
            raise UserError(f"{where}: expected {{layout: ..., root: ..., train: [...]}}, got {entry!r}")
        unknown = sorted(set(entry) - set(DATASET_KEYS))
        if unknown:
            raise UserError(f"{where}.{unknown[0]}: unknown key (expected some of {', '.join(DATASET_KEYS)})")
        for required in ("layout", "root"):
            if entry.get(required) is None:
                raise UserError(f"{where}.{required}: a value is required")
        layouts.check_layout(entry["layout"], f"{where}.layout")
        every = entry.get("keep_every", 1)
        if not is_integer(every, 1):
            raise UserError(f"{where}.keep_every: expected an integer >= 1 (frames), got {every!r}")
        entries[key] = dict(entry)
    return entries


class MultiDataModule(VODataModule):
    """Several datasets in one run: windows from each (each with its own K), one normalisation pooled over
    every training sequence, and the sequences of each evaluated.

    Args:
        datasets: name -> ``{layout, root, train, val, test, unseen, keep_every}``, each as
            :class:`VODataModule` takes it; the run's sequences are named ``<name>/<sequence>``
            (``tum/rgbd_dataset_freiburg1_xyz``).
        Other arguments as :class:`VODataModule` (frame size, windows, loader, flow), shared by the datasets.
    """

    def __init__(self, datasets: Mapping[str, Mapping[str, Any]], **kwargs: Any) -> None:
        entries = _dataset_entries(datasets)
        shared = {k: v for k, v in kwargs.items() if k not in DATASET_KEYS}
        train, val, test, unseen = (
            [f"{key}/{name}" for key, e in entries.items()
             for name in _names(e.get(split) or [], f"datasets.{key}.{split}")]
            for split in ("train", "val", "test", "unseen")
        )  # fmt: skip
        first = next(iter(entries.values()))
        super().__init__(str(first["root"]), train, val, test, unseen, layout=first["layout"], **shared)
        self.sources = {
            key: Source(
                e["layout"],
                Path(e["root"]).expanduser(),
                int(e.get("keep_every", 1)),
                _camera(e.get("camera"), f"data.datasets.{key}.camera"),
            )
            for key, e in entries.items()
        }
        self.layout = "multi"

    def description(self) -> dict[str, Any]:
        """:meth:`VODataModule.description` with ``layout`` ``multi``, the run's ``train`` names and the
        ``datasets``, without the arguments derived from them."""
        described = super().description()
        dropped = set(DATASET_KEYS) - {"train", "layout"}
        return {k: v for k, v in described.items() if k not in dropped} | {"layout": "multi"}


class SyntheticDataModule(VODataModule):
    """The embedded synthetic KITTI-layout dataset, rendered into ``root`` on first use.

    Args:
        root: where the dataset is (or will be) written; default ``<cache_dir>/synthetic``.
        frames: frames per sequence (None: the generator's defaults).
        render_height, render_width: resolution the generator writes (None: its default).
        seed: the generator's seed (a different seed is a different set of worlds and routes).
        route_families: route families added or changed, name -> parameters of
            :class:`lossvo.data.synthetic.routes.Family` (None: the built-in ones).
        route_mixes: sequence -> {family: weight} for the sequences whose routes differ from the
            built-in mixes (None: none).
        Other arguments as :class:`KittiDataModule`.
    """

    def __init__(self, root: str | None = None, frames: int | dict[str, int] | None = None,
                 render_height: int | None = None, render_width: int | None = None,
                 seed: int = 0, route_families: Mapping | None = None, route_mixes: Mapping | None = None,
                 **kwargs) -> None:  # fmt: skip
        cache_dir = kwargs.get("cache_dir")
        base = Path(cache_dir).expanduser() if cache_dir else frame_cache.default_cache_dir()
        super().__init__(root=str(root or base / "synthetic"), **kwargs)
        spec = routes.route_spec(route_families, route_mixes, prefix="data.")
        self.generator_args: dict[str, Any] = {  # synthetic.ensure_dataset's keyword arguments
            "frames": dict(frames) if isinstance(frames, Mapping) else frames,
            "height": render_height or synthetic.DEFAULT_HEIGHT,
            "width": render_width or synthetic.DEFAULT_WIDTH, "seed": seed, "spec": spec,
        }  # fmt: skip
        self._check_names()

    def _check_names(self) -> None:
        """UserError ``data.<split>: sequence 'NN' not found (available: ...)`` for a sequence that
        ``frames`` gives no frame count (the dataset cannot hold it)."""
        counts = self.generator_args["frames"]
        if not isinstance(counts, Mapping):
            return
        for split, names in self.splits.items():
            for name in names:
                if name not in counts:
                    raise UserError(f"data.{split}: sequence {name!r} not found (available: "
                                     f"{', '.join(sorted(counts))})")  # fmt: skip

    def _load_metadata(self) -> None:
        """Render the dataset unless it is there (a lock lets parallel sweep jobs share it); read it."""
        self.root.mkdir(parents=True, exist_ok=True)
        with FileLock(self.root.parent / f".{self.root.name}.lock"):
            synthetic.ensure_dataset(self.root, sequences=self.all_names, **self.generator_args)
        super()._load_metadata()
