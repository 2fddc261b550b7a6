"""The LightningDataModule of datasets in their own layouts (:mod:`lossvo.data.layouts`) or rendered, as
cached frames and windows of them (docs/data.md). A batch, as the model receives it::

    "frames":  (B, seq_len, 3, H, W) float32, normalised per channel
    "targets": (B, seq_len - 1, 4, 4) float32, inv(T_w_k) @ T_w_{k+1} computed in float64
    "K":       (B, 3, 3) float32, the intrinsics of the cached frames (pixels)
    "metric":  (B,) bool, whether the window's platform gives metric scale a cue (a KITTI-layout car)
    "flow":    (B, seq_len - 1, 2, H, W) float32, optical flow of each pair in pixels (with ``flow``)

The loaders carry frames as uint8; ``on_after_batch_transfer`` normalises them on the training device.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
import os
from collections.abc import Mapping
from collections.abc import Sequence as Seq
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from filelock import FileLock
from torch.utils.data import DataLoader, SequentialSampler

from lossvo.atomic import write_text_atomic
from lossvo.console import UserError
from lossvo.data import flow as optical_flow
from lossvo.data import frame_cache, layouts, resident, specs, synthetic, windows
from lossvo.data import transforms as batch_transforms
from lossvo.data.sequence import DatasetFormatError, Sequence, UnknownCameraError
from lossvo.data.synthetic import routes
from lossvo.data.windows import EpochShuffle, WindowDataset
from lossvo.geometry import camera

log = logging.getLogger("lossvo")

PAPER_TRAIN = ("00", "02", "03", "04", "05", "06", "08")
PAPER_VAL = ("07", "09")
PAPER_TEST = ("00", "01", "02", "03", "04", "05", "06", "07", "08", "09", "10")


def _transforms(value: Any) -> tuple[batch_transforms.Transform, ...]:
    """``data.transforms`` as a tuple of batch transforms (:mod:`lossvo.data.transforms`)."""
    items = list(value) if isinstance(value, Seq) and not isinstance(value, str) else None
    if items is None or not all(isinstance(t, batch_transforms.TRANSFORMS) for t in items):
        names = ", ".join(t.__name__ for t in batch_transforms.TRANSFORMS)
        raise UserError(
            f"data.transforms: expected a list of batch transforms ({names} of "
            f"lossvo.data.transforms, each with its _target_), got {value!r}"
        )
    return tuple(items)


class VODataModule(L.LightningDataModule):
    """Datasets in their own layouts (or rendered), as cached frames and windows of them; each argument is
    the config of its spec in :mod:`lossvo.data.specs` (``transforms``: applied in order to training
    batches). With several sources, the run names sequences ``<source>/<sequence>``."""

    def __init__(
        self,
        sources: Mapping[str, Any],
        splits: Mapping[str, Any] | None = None,
        frames: Mapping[str, Any] | None = None,
        windows: Mapping[str, Any] | None = None,
        flow: Mapping[str, Any] | None = None,
        loader: Mapping[str, Any] | None = None,
        transforms: Seq[batch_transforms.Transform] = (),
    ) -> None:
        super().__init__()
        self.frames = specs.Frames.of(frames)
        self.cache_dir = Path(self.frames.cache_dir or frame_cache.default_cache_dir()).expanduser()
        self.sources = specs.sources_of(sources, self.cache_dir)
        self.splits: dict[str, tuple[str, ...]] = dataclasses.asdict(specs.Splits.of(splits))
        self.windows = specs.Windows.of(windows)
        self.flow = specs.flow_of(flow)
        self.loader = specs.Loader.of(loader)
        self.transforms = _transforms(transforms)
        if not self.splits["train"] and self.frames.statistics is None:
            raise UserError("data.splits.train: expected at least one training sequence")
        self._check_names()
        self.resident: dict[str, resident.ResidentWindows] = {}  # by split, on the resident device
        self.sequences: dict[str, Sequence] = {}
        self._manifests: dict[str, dict] = {}  # the frame caches' manifests, by sequence
        self.mean: np.ndarray | None = None  # per-channel statistics, set by setup
        self.std: np.ndarray | None = None
        self.datasets: dict[str, WindowDataset] = {}

    @property
    def seq_len(self) -> int:
        """Frames a window."""
        return self.windows.seq_len

    def _check_names(self) -> None:
        """UserError for a sequence no source can hold (of an unknown source, or not rendered)."""
        for split, names in self.splits.items():
            for name in names:
                key, local = self._split_name(name)
                if key not in self.sources:
                    raise UserError(
                        f"data.splits.{split}: {name!r} names no source (expected "
                        f"<source>/<sequence> with a source of {', '.join(self.sources)})"
                    )
                counts = getattr(self.sources[key].render, "frame_counts", None)
                if isinstance(counts, Mapping) and local not in counts:
                    raise UserError(
                        f"data.splits.{split}: sequence {name!r} not found (available: "
                        f"{', '.join(sorted(counts))})"
                    )

    @property
    def all_names(self) -> list[str]:
        return sorted(set().union(*self.splits.values()))

    @property
    def evaluated(self) -> list[str]:
        """The sequences a trained network is evaluated on: test, then unseen-motion ones."""
        return list(dict.fromkeys(self.splits["test"] + self.splits["unseen"]))

    def _split_name(self, name: str) -> tuple[str, str]:
        """(source name, the sequence's name there) of a run's sequence name."""
        if len(self.sources) == 1:
            return next(iter(self.sources)), name
        key, _, local = name.partition("/")
        return key, local

    def _render(self) -> None:
        """Render each synthetic source's sequences that are not on disk yet, under a lock."""
        for key, source in self.sources.items():
            names = [local for n in self.all_names for k, local in [self._split_name(n)] if k == key]
            if (render := source.render) is None or not names:  # not rendered, or read by no split
                continue
            spec = routes.route_spec(render.route_families, render.route_mixes, prefix=f"data.sources.{key}.")
            source.root.mkdir(parents=True, exist_ok=True)
            with FileLock(source.root.parent / f".{source.root.name}.lock"):
                synthetic.ensure_dataset(
                    source.root,
                    sequences=names,
                    frames=render.frame_counts,
                    height=render.render_height,
                    width=render.render_width,
                    seed=render.seed,
                    spec=spec,
                    layout=render.render_layout,
                    scale=render.render_scale,
                    cameras=render.cameras,
                )

    def load_metadata(self) -> None:
        """Read and check every sequence's metadata (no frame cache), rendering synthetic sources first;
        only test sequences may lack poses."""
        self._render()
        labelled = set(self.splits["train"]) | set(self.splits["val"]) | set(self.splits["unseen"])
        self.sequences, self._manifests = {}, {}
        for name in self.all_names:
            key, local = self._split_name(name)
            source = self.sources[key]
            root = layouts.dataset_root(source.reader, source.root)
            try:
                seq = layouts.load_sequence(
                    source.reader,
                    root,
                    source.file_name(local),
                    require_poses=name in labelled,
                    camera=source.camera,
                )
            except UnknownCameraError as e:
                raise UserError(f"data.sources.{key}.camera: {e}") from e
            except DatasetFormatError as e:
                found = layouts.list_sequences(source.reader, root)
                if source.file_name(local) not in found:
                    split = next(k for k, names in self.splits.items() if name in names)
                    raise UserError(
                        f"data.splits.{split}: no sequence {name!r} in {root} ({source.reader} layout; "
                        f"it has {', '.join(found) or 'none'})"
                    ) from e
                raise
            self.sequences[name] = seq.every(source.keep_every)

    def cache_path(self, name: str | None = None) -> Path:
        """The frame-cache folder of sequence ``name``'s dataset (None: of the only dataset)."""
        source = self.sources[next(iter(self.sources)) if name is None else self._split_name(name)[0]]
        root = layouts.dataset_root(source.reader, source.root).resolve()
        folder = frame_cache.cache_folder(self.cache_dir, root, self.frames.height, self.frames.width)
        suffix = f"-every{source.keep_every}" if source.keep_every > 1 else ""
        return folder.with_name(folder.name + suffix + ("-crop" if self.frames.crop else ""))

    def _frame_files(self, name: str) -> tuple[Path, Path]:
        """The cached frames (.npy) and their manifest (.json) of sequence ``name``."""
        return frame_cache.files(self.cache_path(name), self.sequences[name].name)

    def _flow_file(self, name: str, step: int) -> Path:
        return optical_flow.flow_file(self.cache_path(name), self.sequences[name].name, step, self.flow)

    def _manifest(self, name: str) -> dict:
        """The manifest of sequence ``name``'s cached frames: what they were built from."""
        if name not in self._manifests:  # read once per load_metadata: K and the sources ask for it often
            self._manifests[name] = json.loads(self._frame_files(name)[1].read_text())
        return self._manifests[name]

    def prepare_data(self) -> None:
        """Check the dataset, then build what is missing or stale: frames, statistics and flow."""
        self.load_metadata()
        size = (self.frames.height, self.frames.width)
        frames = {
            n: frame_cache.ensure_frames(self.cache_path(n), s, *size, crop=self.frames.crop)
            for n, s in self.sequences.items()
        }
        self.mean, self.std = self._stats(frames)
        if not self.flow.enabled:
            return
        for n, steps in self.flow_steps().items():
            seq, source = self.sequences[n], self._manifest(n)["source"]
            undistort = frame_cache.undistortion(seq)
            for step in steps:
                args = (self.cache_path(n), seq.name, frames[n], source, step, self.flow, seq.images)
                optical_flow.ensure_flow(*args, undistort=undistort, crop=self.frames.crop)

    def _stats(self, frames: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Per-channel mean/std: given, FlowNet's, or of the training sequences (cached with the frames)."""
        if (given := self.frames.statistics) is not None:
            return np.asarray(given["mean"], dtype=np.float64), np.asarray(given["std"], dtype=np.float64)
        if self.frames.normalization == "flownet":
            return np.full(3, 0.5), np.ones(3)  # (x/255 - 0.5) / 1
        train = self.splits["train"]
        key = hashlib.sha1(",".join(train).encode()).hexdigest()[:10]
        path = self.cache_path(train[0]) / f"stats-{key}.json"  # beside the frames
        sources = {n: self._manifest(n)["source"] for n in train}
        try:
            saved = json.loads(path.read_text())
            if saved["sources"] == sources:
                return np.array(saved["mean"]), np.array(saved["std"])
        except (OSError, ValueError, KeyError):
            pass
        mean, std = frame_cache.channel_stats([frames[n] for n in train])
        record = {"train": train, "sources": sources, "mean": mean.tolist(), "std": std.tolist()}
        write_text_atomic(path, json.dumps(record))
        return mean, std

    def flow_steps(self) -> dict[str, tuple[int, ...]]:
        """Sequence -> the frame steps of the pairs a network sees in it (1, and a training one's steps)."""
        train = set(self.splits["train"])
        return {
            n: tuple(sorted({1, *(self.windows.frame_steps if n in train else ())})) for n in self.all_names
        }

    def setup(self, stage: str | None = None) -> None:
        """Open the cache (rebuilding anything missing or stale) and build the split datasets."""
        if self.datasets:
            return
        self.prepare_data()
        for split, names in self.splits.items():
            labelled = [(n, p) for n in names if (p := self.sequences[n].poses) is not None]  # labelled ones
            steps = (1,) if split != "train" else self.windows.frame_steps
            flow_files = {step: [self._flow_file(n, step) for n, _ in labelled] for step in steps}
            self.datasets[split] = WindowDataset(
                [self._frame_files(n)[0] for n, _ in labelled],
                [p for _, p in labelled],
                self.seq_len,
                steps,
                tiled=split != "train",
                intrinsics=[self.intrinsics(n) for n, _ in labelled],
                flow_files=flow_files if self.flow.enabled else None,
                times=[self.sequences[n].times for n, _ in labelled],
                metric=[self.metric_scale(n) for n, _ in labelled],
            )
        if len(self.datasets["train"]) == 0 and self.splits["train"]:
            shortest = min(len(self.sequences[n].images) for n in self.splits["train"])
            raise UserError(
                f"data.windows.seq_len: {self.seq_len} frames is longer than every training sequence "
                f"(shortest: {shortest} frames)"
            )

    def description(self) -> dict[str, Any]:
        """What a network trained on this data depends on, as primitives (a checkpoint's ``data``): the
        specs' configs and, after :meth:`setup` (None before), ``statistics`` and each training sequence's
        ``intrinsics``."""
        sources = {k: s.config() | {"root": str(s.root.resolve())} for k, s in self.sources.items()}
        stats = None
        if self.mean is not None and self.std is not None:
            stats = {"mean": self.mean.tolist(), "std": self.std.tolist()}
        cameras = {n: self.intrinsics(n).tolist() for n in self.splits["train"]} if self.datasets else None
        settings = ("frames", "windows", "flow", "loader")  # the specs' fields
        return {
            "_target_": f"{type(self).__module__}.{type(self).__qualname__}",
            "sources": sources,
            "splits": {k: list(v) for k, v in self.splits.items()},
            **{k: specs.plain(dataclasses.asdict(getattr(self, k))) for k in settings},
            "transforms": [batch_transforms.spec(t) for t in self.transforms],
            "statistics": stats,
            "dataset_root": str(self.dataset_root()),
            "intrinsics": cameras,
        }

    def dataset_root(self) -> Path:
        """The absolute folder the layout's reader reads; with several datasets, the one they share."""
        roots = [str(layouts.dataset_root(s.reader, s.root).resolve()) for s in self.sources.values()]
        return Path(os.path.commonpath(roots))

    def intrinsics(self, name: str) -> np.ndarray:
        """(3, 3) float64 K of a sequence's cached frames (pixels); after :meth:`setup`."""
        size = (self.frames.height, self.frames.width)
        source = tuple(self._manifest(name)["source_size_hw"])
        K = frame_cache.source_intrinsics(self.sequences[name])
        if self.frames.crop:
            box = frame_cache.centre_crop(source, size)
            K, source = frame_cache.cropped_intrinsics(K, box), box[2:]
        return camera.resized_intrinsics(K, source, size)

    def resident_windows(self, split: str) -> resident.ResidentWindows | None:
        """The split's windows kept on the training device, or None (the host loader): the device decided
        once, each split's arrays copied there when first asked for."""
        if self._resident_device is not None and split not in self.resident:
            data = self.datasets[split]
            arrays = (data.index, data.frames, data.targets, data.intrinsics, data.metric, data.flow or None)
            self.resident[split] = resident.ResidentWindows(*arrays, self._resident_device)
        return self.resident.get(split)

    @functools.cached_property
    def _resident_device(self) -> torch.device | None:
        """The training device where the settings allow keeping windows there, else None; a log line."""
        device = getattr(getattr(self.trainer, "strategy", None), "root_device", torch.device("cpu"))
        data = [self.datasets[s] for s in ("train", "val") if s in self.datasets]
        size = sum(a.nbytes for d in data for arrays in [d.frames, *d.flow.values()] for a in arrays) / 2**30
        setting = f"data.loader.on_device={str(self.loader.on_device).lower()}"
        reason = None
        if self.loader.on_device is False:
            reason = setting
        elif self.loader.on_device == "auto" and device.type == "cpu":
            reason = f"{setting} on a CPU"
        elif getattr(self.trainer, "world_size", 1) > 1:
            reason = f"{getattr(self.trainer, 'world_size', 1)} processes"
        elif size > self.loader.device_budget_gb:
            reason = f"the arrays exceed data.loader.device_budget_gb={self.loader.device_budget_gb:g}"
        if reason is not None:
            log.info("data: batches from the host loader (%s; %.2f GiB of frames and flow)", reason, size)
            return None
        log.info(
            "data: batches gathered on %s from %.2f GiB of frames and flow kept there (%s)",
            device,
            size,
            setting,
        )
        return device

    def _loader(self, split: str, **sampling: Any) -> DataLoader:
        """The split's windows (``sampling``: DataLoader's sampler arguments): from the host loader, or as
        index batches of windows kept on the device (gathered by :meth:`on_after_batch_transfer`)."""
        generator = torch.Generator().manual_seed(torch.initial_seed())  # not the global one: dropout's
        windows = self.resident_windows(split)
        if windows is not None:  # window indices -> their index batch, tagged with its split
            return DataLoader(
                range(len(self.datasets[split])),  # type: ignore[arg-type]  # indices serve as a dataset
                collate_fn=lambda indices: {"split": split, **windows.index_batch(indices)},
                generator=generator,
                **sampling,
            )
        return DataLoader(
            self.datasets[split],
            num_workers=self.loader.num_workers,
            pin_memory=self.loader.pin_memory,
            persistent_workers=self.loader.num_workers > 0,
            generator=generator,
            **sampling,
        )

    def _tiled_loader(self, split: str) -> DataLoader:
        """Validation or test windows in order, batched by length (a sequence's last may be shorter)."""
        lengths = self.datasets[split].lengths.tolist()
        batches = windows.SameLengthBatches(SequentialSampler(lengths), self.windows.batch_size, lengths)
        return self._loader(split, batch_sampler=batches)

    def train_dataloader(self) -> DataLoader:
        """Shuffled training windows (a fresh subset each epoch with ``per_epoch``), in an order that depends
        on the run's seed, the epoch and the data alone (:class:`EpochShuffle`); the sampler, not a batch
        sampler's, so that Lightning wraps it for several processes."""
        dataset = self.datasets["train"]
        count = min(self.windows.per_epoch or len(dataset), len(dataset))
        order = EpochShuffle(len(dataset), count, torch.initial_seed())
        return self._loader("train", sampler=order, batch_size=self.windows.batch_size)

    def val_dataloader(self) -> DataLoader:
        return self._tiled_loader("val")

    def test_dataloader(self) -> DataLoader:
        return self._tiled_loader("test")

    def normalize(self, frames: torch.Tensor) -> torch.Tensor:
        """uint8 frames (..., 3, H, W) -> float32 ``(x / 255 - mean) / std``, per channel."""
        mean = torch.as_tensor(self.mean, dtype=torch.float32, device=frames.device).view(3, 1, 1)
        std = torch.as_tensor(self.std, dtype=torch.float32, device=frames.device).view(3, 1, 1)
        return frames.float().mul_(1.0 / (255.0 * std)).sub_(mean / std)  # in place: one pass less

    def prepare(self, inputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Loaded inputs as a network reads them: frames normalised, flow as float32."""
        prepared = {**inputs, "frames": self.normalize(inputs["frames"])}
        if "flow" in inputs:
            prepared["flow"] = inputs["flow"].float()
        return prepared

    def on_after_batch_transfer(
        self, batch: dict[str, torch.Tensor], dataloader_idx: int
    ) -> dict[str, torch.Tensor]:
        """On the device: an index batch gathered, training transforms applied, then :meth:`prepare`."""
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

    def sequence_layout(self, name: str) -> str:
        """The layout one sequence is read in (a synthetic source's: the layout it is rendered in)."""
        return self.sources[self._split_name(name)[0]].reader

    def metric_scale(self, name: str) -> bool:
        """Whether one sequence's platform gives metric scale a cue (:data:`layouts.METRIC_SCALE_LAYOUTS`)."""
        return self.sequence_layout(name) in layouts.METRIC_SCALE_LAYOUTS

    def sequence_times(self, name: str) -> np.ndarray:
        """(N,) float64 timestamps (s) of one sequence's frames."""
        self.setup()
        return self.sequences[name].times
