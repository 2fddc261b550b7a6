"""The GPU path: training throughput of the study's networks on one GPU, and the study's cost in GPU-hours.

Run on a machine with a CUDA GPU, from the repository root, either in lossvo's venv or with only Python,
torch and numpy there and lossvo's pure-Python dependencies carried in ``.gpu-deps/``
(``benchmarks/gpu_deps.sh``; see docs/gpu.md)::

    PYTHONPATH=src:.gpu-deps python benchmarks/gpu_path.py --out gpu.json

Check it on a CPU (tiny sizes, one round, under a minute):
``.venv/bin/python benchmarks/gpu_path.py --quick --device cpu --out /tmp/gpu.json``.

The settings are the shipped configs' (read from ``src/lossvo/conf``): full DeepVO (``model/deepvo.yaml``)
on windows of ``data/kitti.yaml``'s length and batch size, and FlowVO (``model/flowvo.yaml``: frame
pairs, flow and K in, its own batch size), each at the study's image size (``experiment/paper.yaml``) and
at KITTI's full resolution (370x1226, the smallest frame of the odometry sequences). For each network and
size:

- Training rate in fp32 and under bf16 autocast, with the encoder channels-last and contiguous: a step is
  the forward pass, the chordal loss (the study's k), backward and Adam (the experiment's learning rate) on
  one batch resident on the device, with cudnn.benchmark as ``trainer/gpu.yaml`` sets it. Each
  measurement runs warm-up steps, sizes its timed run from two probe steps, and times that run between
  two synchronisations; the settings alternate in interleaved rounds (order reversed every other round)
  and each is reported as the median, min and max over rounds. Peak memory is
  ``torch.cuda.max_memory_allocated`` over one measurement: the model, its gradients, Adam's state, the
  batch and the activations (the model lives on the host between measurements). A setting that runs out
  of memory or fails is recorded and not tried again.
- Evaluation rate (``model.eval()``, no gradients, same precision), for the validation part of an epoch.
- For DeepVO at the first size (the study's by default), the three study losses at the best setting
  (their heads differ; the projection then sums each loss's runs).
- Whether the frame cache keeps up: windows assembled by a DataLoader (the experiment's ``num_workers``
  and ``pin_memory``, shuffled) from a uint8 ``.npy`` memory map of frames (and, for FlowVO, float16 flow),
  one copy out of each map per window as ``lossvo.data.datamodules.WindowDataset`` does, copied to the
  device and normalised there; then training at the best setting fed by that loader. Both are reported
  against the resident-batch rate.
- The study projected: ``len(losses) x max_epochs`` epochs of every training window of
  ``data/kitti.yaml``'s training sequences (one starting at every frame, ``lossvo.data.windows``) plus its
  validation sequences' tiled windows, at the measured rates, in GPU-hours.

Prints one table per network and size and writes every number, with the device, the versions and the date,
to ``--out`` (JSON, rewritten after each network and size, so an interrupted run keeps what it measured).
No measurement starts after ``--deadline`` seconds; those left are recorded as skipped.
"""

from __future__ import annotations

import argparse
import datetime
import gc
import json
import os
import platform
import shutil
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import OmegaConf
from torch import Tensor, nn
from torch.utils.data import DataLoader, Dataset

import lossvo
from lossvo import geometry as g
from lossvo import losses, models
from lossvo.data import specs, windows

CONF = Path(lossvo.__file__).parent / "conf"

KITTI_FRAMES = {
    "00": 4541,
    "01": 1101,
    "02": 4661,
    "03": 801,
    "04": 271,
    "05": 2761,
    "06": 1101,
    "07": 1101,
    "08": 4071,
    "09": 1591,
    "10": 1201,
}
"""Frames of each KITTI odometry sequence with ground truth."""
FULL_SIZE = (370, 1226)
"""KITTI's full resolution: the smallest frame of the odometry sequences (04-10; 00-03 are ~376x1241)."""
STUDY_LOSSES = ("euler", "quat", "chordal")
MEASURED_LOSS = "chordal"
"""The loss of the setting comparison (the study's losses differ only in the head size and the loss)."""
LAYOUTS = {"channels_last": True, "contiguous": False}
QUICK = {
    "sizes": ["64x128"],
    "rounds": 1,
    "seconds": 0.15,
    "eval_seconds": 0.05,
    "warmup": 1,
    "loader_seconds": 0.3,
    "cache_frames": 24,
    "workers": 2,
    "networks": {
        "deepvo": {"batch_size": 2, "seq_len": 3, "model": {"width_mult": 0.125, "hidden_size": 64}},
        "flowvo": {"batch_size": 4},
    },
}
"""--quick: tiny sizes, batches and DeepVO, short measurements (a CPU check that the script runs)."""


# -- settings from the shipped configs -----------------------------------------------------------------


def config(name: str) -> Any:
    return OmegaConf.load(CONF / name)


def plain(node: Any) -> dict[str, Any]:
    """A config node's entries that are plain values: interpolations (which the train entry resolves
    from other groups: the size, the head) left out."""
    values = OmegaConf.to_container(node, resolve=False)
    assert isinstance(values, dict)
    return {key: value for key, value in values.items() if not OmegaConf.is_interpolation(node, key)}


@dataclass
class Network:
    name: str
    cls: type[nn.Module]
    kwargs: dict[str, Any]
    """The model config's plain entries, without ``_target_`` and ``channels_last``."""
    shipped_layout: str
    """The layout the model config sets (``channels_last`` or ``contiguous``)."""
    seq_len: int
    batch_size: int


def study_settings() -> dict[str, Any]:
    """What the study runs (``experiment=paper``, ``trainer=gpu``, ``data=kitti``), read from the configs."""
    paper, kitti, gpu = config("experiment/paper.yaml"), config("data/kitti.yaml"), config("trainer/gpu.yaml")
    base, flowvo = OmegaConf.structured(specs.Windows), config("model/flowvo.yaml")  # the schema's defaults
    return {
        "size": [kitti.frames.height, kitti.frames.width],
        "networks": {
            "deepvo": {
                "model": plain(config("model/deepvo.yaml")),
                "seq_len": kitti.windows.seq_len,
                "batch_size": base.batch_size,
            },
            "flowvo": {
                "model": plain(flowvo.model),
                "seq_len": flowvo.reads.seq_len,
                "batch_size": flowvo.reads.batch_size,
            },
        },
        "num_workers": paper.data.loader.num_workers,
        "pin_memory": paper.data.loader.pin_memory,
        "lr": paper.optimizer.lr,
        "max_epochs": paper.trainer.max_epochs,
        "precision": gpu.precision,
        "cudnn_benchmark": gpu.benchmark,
        "train": list(kitti.splits.train),
        "val": list(kitti.splits.val),
        "losses": {name: config(f"loss/{name}.yaml")["_target_"] for name in STUDY_LOSSES},
    }


def network(name: str, settings: dict[str, Any], quick: bool) -> Network:
    spec = settings["networks"][name]
    kwargs = dict(spec["model"])
    cls = getattr(models, kwargs.pop("_target_").rsplit(".", 1)[1])
    layout = "channels_last" if kwargs.pop("channels_last", False) else "contiguous"
    sizes = {"seq_len": spec["seq_len"], "batch_size": spec["batch_size"]}
    if quick:
        tiny = dict(QUICK["networks"][name])
        kwargs |= tiny.pop("model", {})
        sizes |= tiny
    return Network(name, cls, kwargs, layout, **sizes)


def loss_of(target: str) -> losses.PoseLoss:
    """The loss class named by a loss config's ``_target_``, with the study's k (``weighting=paper``)."""
    cls = getattr(losses, target.rsplit(".", 1)[1])
    return cls(k=cls.paper_k)


def build(net: Network, size: tuple[int, int], loss: losses.PoseLoss, channels_last: bool) -> nn.Module:
    """The network (on the host) with the loss's head; the same weights for every layout (seed 0)."""
    torch.manual_seed(0)
    head = {"out_dim": loss.dim, "head_bias": loss.identity_output().tolist()}
    return net.cls(**net.kwargs, **head, height=size[0], width=size[1], channels_last=channels_last)


def kitti_like_K(height: int, width: int) -> Tensor:
    """Intrinsics of KITTI's proportions (focal length 0.58 of the width, principal point at the centre)."""
    f = 0.58 * width
    return torch.tensor([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def resident_batch(model: nn.Module, net: Network, size: tuple[int, int]) -> dict[str, Tensor]:
    """One batch of what the network reads (normalised frames, or float flow and K) and pose targets."""
    gen = torch.Generator().manual_seed(1)
    B, L, (H, W) = net.batch_size, net.seq_len, size
    steps = 0.05 * torch.randn(B, L - 1, 6, generator=gen, dtype=torch.float64)
    inputs = {
        "frames": lambda: torch.randn(B, L, 3, H, W, generator=gen),
        "flow": lambda: 3.0 * torch.randn(B, L - 1, 2, H, W, generator=gen),
        "K": lambda: kitti_like_K(H, W).expand(B, 3, 3).contiguous(),
    }
    batch = {name: inputs[name]() for name in models.inputs_of(model)}
    return {**batch, "targets": g.se3_exp(steps).float()}


# -- timing ------------------------------------------------------------------------------------------


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def rate(run: Callable[[int], None], device: torch.device, seconds: float, warmup: int) -> tuple[float, int]:
    """Calls per second of ``run(n)`` (n calls): ``warmup`` untimed calls, two probe calls that size the
    timed run to about ``seconds``, then that run between two synchronisations."""
    run(warmup)
    sync(device)
    start = time.perf_counter()
    run(2)
    sync(device)
    probe = (time.perf_counter() - start) / 2
    n = max(2, min(100_000, round(seconds / max(probe, 1e-6))))
    start = time.perf_counter()
    run(n)
    sync(device)
    return n / (time.perf_counter() - start), n


def autocast(device: torch.device, bf16: bool) -> torch.autocast:
    return torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16)


def train_step(
    model: nn.Module, loss: nn.Module, optimizer: torch.optim.Optimizer, batch: dict, bf16: bool
) -> None:
    device = batch["targets"].device
    with autocast(device, bf16):
        out = loss(models.apply(model, batch), batch["targets"])
    optimizer.zero_grad(set_to_none=True)
    out["loss"].backward()
    optimizer.step()


def free(device: torch.device) -> None:
    gc.collect()
    if device.type == "cuda":
        torch.cuda.empty_cache()


def measure(
    model: nn.Module, loss: nn.Module, batch: dict, bf16: bool, args: argparse.Namespace, lr: float
) -> dict[str, Any]:
    """Training and evaluation steps/s of one setting, and its peak memory; the model is moved to the
    batch's device for the measurement and back to the host after it."""
    device = batch["targets"].device
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    model.to(device).train()
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)

    def train(n: int) -> None:
        for _ in range(n):
            train_step(model, loss, optimizer, batch, bf16)

    @torch.no_grad()
    def evaluate(n: int) -> None:
        for _ in range(n):
            with autocast(device, bf16):
                loss(models.apply(model, batch), batch["targets"])

    try:
        training, steps = rate(train, device, args.seconds, args.warmup)
        model.eval()
        evaluation, _ = rate(evaluate, device, args.eval_seconds, 1)
        peak = torch.cuda.max_memory_allocated(device) if device.type == "cuda" else None
        return {
            "steps_per_s": training,
            "eval_steps_per_s": evaluation,
            "timed_steps": steps,
            "peak_bytes": peak,
        }
    finally:
        optimizer.state.clear()
        optimizer.zero_grad(set_to_none=True)
        model.to("cpu").train()
        free(device)


def failure(error: RuntimeError) -> str:
    if isinstance(error, torch.cuda.OutOfMemoryError):
        return "out of memory"
    return f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}"


def spread(values: list[float]) -> dict[str, float]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


# -- the frame cache ---------------------------------------------------------------------------------


class CachedWindows(Dataset):
    """Training windows out of memory-mapped ``.npy`` arrays, as ``lossvo.data.datamodules.WindowDataset``
    reads them: ``frames`` (L, 3, H, W) uint8 and, with a flow file, ``flow`` (L-1, 2, H, W) float16, each
    one copy out of its map, with targets (L-1, 4, 4) and K. The maps are opened in each worker. (Its own
    class: the data module's imports, OpenCV and Lightning, are not on a machine with torch alone.)"""

    def __init__(self, frames: Path, flow: Path | None, seq_len: int, targets: Tensor, K: Tensor) -> None:
        self.files, self.seq_len, self.targets, self.K = (frames, flow), seq_len, targets, K
        self.maps: tuple[np.ndarray, np.ndarray | None] | None = None
        self.n = len(targets) + 1

    def __len__(self) -> int:
        return self.n - self.seq_len + 1

    def __getitem__(self, i: int) -> dict[str, Tensor]:
        if self.maps is None:
            frames, flow = self.files
            self.maps = (
                np.load(frames, mmap_mode="r"),
                None if flow is None else np.load(flow, mmap_mode="r"),
            )
        frames, flow = self.maps
        stop = i + self.seq_len
        item = {
            "frames": torch.from_numpy(np.array(frames[i:stop])),
            "targets": self.targets[i : stop - 1],
            "K": self.K,
        }
        if flow is not None:
            item["flow"] = torch.from_numpy(np.array(flow[i : stop - 1]))
        return item


def write_array(path: Path, shape: tuple[int, ...], dtype: type, gen: np.random.Generator) -> Path:
    """A ``.npy`` file of ``shape``, filled with a repeated random block of 16 rows."""
    array = np.lib.format.open_memmap(path, mode="w+", dtype=dtype, shape=shape)
    block_shape = (min(16, shape[0]), *shape[1:])
    if np.dtype(dtype) == np.uint8:
        block = gen.integers(0, 256, block_shape, dtype=np.uint8)
    else:
        block = (3.0 * gen.standard_normal(block_shape, dtype=np.float32)).astype(dtype)
    for start in range(0, shape[0], len(block)):
        array[start : start + len(block)] = block[: shape[0] - start]
    array.flush()
    del array
    return path


def on_device(batch: dict[str, Tensor], device: torch.device) -> dict[str, Tensor]:
    """A loaded batch as the network reads it: copied to the device, frames normalised there (one multiply
    and one subtract, as the data module does), flow to float32."""
    out = {name: value.to(device, non_blocking=True) for name, value in batch.items()}
    out["frames"] = out["frames"].float().mul_(1.0 / 255.0).sub_(0.5)
    if "flow" in out:
        out["flow"] = out["flow"].float()
    return out


def forever(loader: DataLoader) -> Iterator[dict[str, Tensor]]:
    while True:
        yield from loader


def windows_per_s(
    batches: Iterator[dict[str, Tensor]],
    consume: Callable[[dict[str, Tensor]], None],
    device: torch.device,
    seconds: float,
    warmup: int,
) -> float:
    """Windows per second through ``consume`` after ``warmup`` batches, over about ``seconds``."""
    for _ in range(warmup):
        consume(next(batches))
    sync(device)
    count, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        batch = next(batches)
        consume(batch)
        count += len(batch["targets"])
    sync(device)
    return count / (time.perf_counter() - start)


def cache_keeps_up(
    model: nn.Module,
    loss: nn.Module,
    net: Network,
    size: tuple[int, int],
    bf16: bool,
    args: argparse.Namespace,
    settings: dict[str, Any],
    device: torch.device,
) -> dict:
    """Windows/s of the loader alone and of training fed by it (at the given setting)."""
    gen = np.random.default_rng(0)
    n, (H, W) = args.cache_frames, size
    steps = torch.from_numpy(0.05 * gen.standard_normal((n - 1, 6)))
    targets = g.se3_exp(steps).float()
    with tempfile.TemporaryDirectory(dir=args.tmp) as tmp:
        start = time.perf_counter()
        frames = write_array(Path(tmp) / "frames.npy", (n, 3, H, W), np.uint8, gen)
        reads_flow = "flow" in models.inputs_of(model)
        flow = write_array(Path(tmp) / "flow.npy", (n - 1, 2, H, W), np.float16, gen) if reads_flow else None
        written = time.perf_counter() - start
        dataset = CachedWindows(frames, flow, net.seq_len, targets, kitti_like_K(H, W))
        loader = DataLoader(
            dataset,
            batch_size=net.batch_size,
            shuffle=True,
            drop_last=True,
            num_workers=args.workers,
            pin_memory=loader_pin(settings, device),
            persistent_workers=args.workers > 0,
        )
        warmup = max(2, 2 * args.workers)
        batches = forever(loader)

        def load(b: dict[str, Tensor]) -> None:
            on_device(b, device)

        loaded = windows_per_s(batches, load, device, args.loader_seconds, warmup)
        model.to(device).train()
        optimizer = torch.optim.Adam(model.parameters(), lr=settings["lr"])

        def train(b: dict[str, Tensor]) -> None:
            train_step(model, loss, optimizer, on_device(b, device), bf16)

        try:
            fed = windows_per_s(batches, train, device, args.loader_seconds, warmup)
        finally:
            optimizer.state.clear()
            optimizer.zero_grad(set_to_none=True)
            model.to("cpu")
            free(device)
    mib = (n * 3 * H * W + (0 if flow is None else (n - 1) * 2 * H * W * 2)) / 2**20
    return {
        "loader_windows_per_s": loaded,
        "fed_windows_per_s": fed,
        "cache_frames": n,
        "cache_mib": mib,
        "cache_write_s": written,
        "num_workers": args.workers,
        "pin_memory": bool(loader_pin(settings, device)),
    }


def loader_pin(settings: dict[str, Any], device: torch.device) -> bool:
    return bool(settings["pin_memory"]) and device.type == "cuda"


# -- the study's cost --------------------------------------------------------------------------------


def study_windows(settings: dict[str, Any], seq_len: int) -> dict[str, int]:
    """Training windows (one at every frame) and tiled validation windows per epoch."""
    train = sum(len(windows.training_starts(KITTI_FRAMES[s], seq_len)) for s in settings["train"])
    val = sum(len(windows.tile(KITTI_FRAMES[s], seq_len)) for s in settings["val"])
    return {"train": train, "val": val}


def gpu_hours(counts: dict[str, int], train_rate: float, eval_rate: float, epochs: int, runs: int) -> dict:
    """Seconds per epoch and GPU-hours of ``runs`` trainings of ``epochs`` epochs (rates in windows/s)."""
    epoch = counts["train"] / train_rate + counts["val"] / eval_rate
    return {"epoch_s": epoch, "gpu_hours": runs * epochs * epoch / 3600}


# -- one network at one size -------------------------------------------------------------------------


def label(precision: str, layout: str) -> str:
    return f"{precision} {layout}"


def shipped_precision(settings: dict[str, Any]) -> str:
    """The precision ``trainer/gpu.yaml`` trains in: bf16 (``bf16-mixed``) or fp32."""
    return "bf16" if str(settings["precision"]).startswith("bf16") else "fp32"


def run_case(
    net: Network,
    size: tuple[int, int],
    settings: dict[str, Any],
    args: argparse.Namespace,
    device: torch.device,
    deadline: float,
    study: bool,
) -> dict[str, Any]:
    """Every setting of one network at one size, in interleaved rounds; the losses (for the study's case);
    the frame cache; the projection."""
    chordal = loss_of(settings["losses"][MEASURED_LOSS])
    built = {layout: build(net, size, chordal, cl) for layout, cl in LAYOUTS.items()}
    batch = {k: v.to(device) for k, v in resident_batch(built["contiguous"], net, size).items()}
    params = sum(p.numel() for p in built["contiguous"].parameters())
    settings_list = [(p, layout) for p in args.precisions for layout in LAYOUTS]
    rounds: dict[str, list[dict[str, Any]]] = {label(*s): [] for s in settings_list}
    errors: dict[str, str] = {}
    skipped = 0
    for r in range(args.rounds):
        for precision, layout in settings_list if r % 2 == 0 else settings_list[::-1]:
            name = label(precision, layout)
            if name in errors:
                continue
            if time.monotonic() > deadline:
                skipped += 1
                continue
            try:
                rounds[name].append(
                    measure(built[layout], chordal, batch, precision == "bf16", args, settings["lr"])
                )
            except RuntimeError as e:
                errors[name] = failure(e)
            free(device)
    counts = study_windows(settings, net.seq_len)
    results: dict[str, Any] = {}
    for name, values in rounds.items():
        entry: dict[str, Any] = {"rounds": values}
        if values:
            steps = spread([v["steps_per_s"] for v in values])
            evals = spread([v["eval_steps_per_s"] for v in values])
            peaks = [v["peak_bytes"] for v in values if v["peak_bytes"] is not None]
            entry |= {
                "steps_per_s": steps,
                "windows_per_s": {k: v * net.batch_size for k, v in steps.items()},
                "pairs_per_s": steps["median"] * net.batch_size * (net.seq_len - 1),
                "eval_windows_per_s": {k: v * net.batch_size for k, v in evals.items()},
                "peak_bytes": max(peaks) if peaks else None,
            }
            entry["study"] = gpu_hours(
                counts,
                entry["windows_per_s"]["median"],
                entry["eval_windows_per_s"]["median"],
                settings["max_epochs"],
                len(STUDY_LOSSES),
            )
        if name in errors:
            entry["error"] = errors[name]
        results[name] = entry
    measured = {name: e for name, e in results.items() if "steps_per_s" in e}
    best = max(measured, key=lambda n: measured[n]["steps_per_s"]["median"]) if measured else None
    case: dict[str, Any] = {
        "network": net.name,
        "size": list(size),
        "seq_len": net.seq_len,
        "batch_size": net.batch_size,
        "parameters": params,
        "model": {**net.kwargs},
        "windows_per_epoch": counts,
        "settings": results,
        "best": best,
        "shipped": label(shipped_precision(settings), net.shipped_layout),
        "skipped_measurements": skipped,
    }
    if best is not None and study:
        measured_model = built[best.split()[1]]
        case["losses"] = compare_losses(
            net, size, best, measured_model, batch, settings, args, deadline, counts
        )
    if best is not None and time.monotonic() < deadline:
        precision, layout = best.split()
        try:
            cache = cache_keeps_up(
                built[layout], chordal, net, size, precision == "bf16", args, settings, device
            )
            resident = measured[best]["windows_per_s"]["median"]
            cache |= {
                "loader_over_training": cache["loader_windows_per_s"] / resident,
                "fed_over_resident": cache["fed_windows_per_s"] / resident,
                "study_fed": gpu_hours(
                    counts,
                    cache["fed_windows_per_s"],
                    measured[best]["eval_windows_per_s"]["median"],
                    settings["max_epochs"],
                    len(STUDY_LOSSES),
                ),
            }
        except RuntimeError as e:
            cache = {"error": failure(e)}
        case["frame_cache"] = cache | {"setting": best}
    elif best is not None:
        case["frame_cache"] = {"skipped": "deadline"}
    del built, batch
    free(device)
    return case


def compare_losses(
    net: Network,
    size: tuple[int, int],
    best: str,
    measured: nn.Module,
    batch: dict[str, Tensor],
    settings: dict[str, Any],
    args: argparse.Namespace,
    deadline: float,
    counts: dict[str, int],
) -> dict[str, Any]:
    """Training and evaluation rates of the study's losses (each with its head; ``measured`` is the
    network of :data:`MEASURED_LOSS`) at one setting, in interleaved rounds on one batch; the study's
    GPU-hours as the sum of each loss's runs (None when a loss has no rate)."""
    precision, layout = best.split()
    device = batch["targets"].device
    built = {}
    for name in STUDY_LOSSES:
        loss = loss_of(settings["losses"][name])
        built[name] = (measured if name == MEASURED_LOSS else build(net, size, loss, LAYOUTS[layout]), loss)
    out: dict[str, Any] = {name: {"rounds": []} for name in STUDY_LOSSES}
    for r in range(args.rounds):
        for name in STUDY_LOSSES if r % 2 == 0 else STUDY_LOSSES[::-1]:
            if time.monotonic() > deadline or "error" in out[name]:
                continue
            model, loss = built[name]
            try:
                out[name]["rounds"].append(
                    measure(model, loss, batch, precision == "bf16", args, settings["lr"])
                )
            except RuntimeError as e:
                out[name]["error"] = failure(e)
            free(device)
    for entry in out.values():
        if not entry["rounds"]:
            continue
        train = statistics.median(v["steps_per_s"] for v in entry["rounds"]) * net.batch_size
        evaluation = statistics.median(v["eval_steps_per_s"] for v in entry["rounds"]) * net.batch_size
        entry |= {
            "windows_per_s": train,
            "eval_windows_per_s": evaluation,
            "run": gpu_hours(counts, train, evaluation, settings["max_epochs"], 1),
        }
    runs = [entry["run"]["gpu_hours"] for entry in out.values() if "run" in entry]
    total = sum(runs) if len(runs) == len(out) else None
    return {"setting": best, "per_loss": out, "study_gpu_hours": total}


# -- report ------------------------------------------------------------------------------------------


def machine(device: torch.device) -> dict[str, Any]:
    info: dict[str, Any] = {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cuda": torch.version.cuda,
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "device_type": device.type,
        "device": platform.processor() or platform.machine(),
    }
    if os.path.isdir("/dev/shm"):  # DataLoader workers hand batches over in shared memory
        info["dev_shm_bytes"] = shutil.disk_usage("/dev/shm").total
    if device.type == "cuda":
        props = torch.cuda.get_device_properties(device)
        info |= {
            "device": props.name,
            "device_memory_bytes": props.total_memory,
            "capability": f"{props.major}.{props.minor}",
            "multiprocessors": props.multi_processor_count,
            "cudnn": torch.backends.cudnn.version(),
            "cudnn_benchmark": torch.backends.cudnn.benchmark,
            "tf32": {
                "cudnn": torch.backends.cudnn.allow_tf32,
                "matmul": torch.backends.cuda.matmul.allow_tf32,
            },
        }
    return info


def gib(n: int | None) -> str:
    return "-" if n is None else f"{n / 2**30:.2f}"


def print_case(case: dict[str, Any]) -> None:
    H, W = case["size"]
    print(
        f"\n{case['network']} {H}x{W}: {case['parameters'] / 1e6:.1f}M parameters, batch "
        f"{case['batch_size']} x {case['seq_len']} frames, {case['windows_per_epoch']['train']} training + "
        f"{case['windows_per_epoch']['val']} validation windows an epoch"
    )
    print(
        f"  {'setting':24s} {'steps/s (min-max)':>24s} {'windows/s':>10s} {'eval win/s':>11s} "
        f"{'peak GiB':>9s} {'study GPU-h':>12s}"
    )
    for name, e in case["settings"].items():
        mark = ("*" if name == case["best"] else "") + ("s" if name == case["shipped"] else "")
        mark = f" {mark}" if mark else ""
        if "steps_per_s" not in e:
            print(f"  {name + mark:24s} {e.get('error', 'not measured (deadline)')}")
            continue
        s = e["steps_per_s"]
        print(
            f"  {name + mark:24s} {s['median']:9.2f} ({s['min']:.2f}-{s['max']:.2f}) "
            f"{e['windows_per_s']['median']:>10.1f} {e['eval_windows_per_s']['median']:>11.1f} "
            f"{gib(e['peak_bytes']):>9s} {e['study']['gpu_hours']:>12.1f}"
        )
    if "losses" in case:
        per = case["losses"]["per_loss"]
        rates = ", ".join(f"{n} {v['windows_per_s']:.1f}" for n, v in per.items() if "windows_per_s" in v)
        hours = case["losses"]["study_gpu_hours"]
        total = "not every loss measured" if hours is None else f"{hours:.1f} GPU-hours"
        print(f"  losses at {case['losses']['setting']} (windows/s): {rates}; the study: {total}")
    cache = case.get("frame_cache")
    if cache and "loader_windows_per_s" in cache:
        print(
            f"  frame cache ({cache['num_workers']} workers, {cache['cache_mib']:.0f} MiB memory-mapped): "
            f"loader {cache['loader_windows_per_s']:.1f} windows/s = {cache['loader_over_training']:.2f}x "
            f"training; training fed by it {cache['fed_windows_per_s']:.1f} windows/s = "
            f"{cache['fed_over_resident']:.2f}x the resident batch ({cache['study_fed']['gpu_hours']:.1f} "
            f"study GPU-hours)"
        )
    elif cache:
        print(f"  frame cache: {cache.get('error') or 'skipped (' + cache['skipped'] + ')'}")


def parse_size(text: str) -> tuple[int, int]:
    height, width = text.lower().split("x")
    return int(height), int(width)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="JSON file of every number")
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--networks", nargs="+", default=["deepvo", "flowvo"], choices=["deepvo", "flowvo"])
    parser.add_argument("--sizes", nargs="+", default=None, help="HxW (default: the study's and 370x1226)")
    parser.add_argument("--precisions", nargs="+", default=["fp32", "bf16"], choices=["fp32", "bf16"])
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds of every setting")
    parser.add_argument("--seconds", type=float, default=2.0, help="timed training per measurement")
    parser.add_argument("--eval-seconds", type=float, default=0.5, help="timed evaluation per measurement")
    parser.add_argument("--warmup", type=int, default=3, help="untimed training steps per measurement")
    parser.add_argument(
        "--loader-seconds", type=float, default=3.0, help="loader alone, then training fed by it"
    )
    parser.add_argument(
        "--cache-frames", type=int, default=1000, help="frames of the memory-mapped cache file"
    )
    parser.add_argument(
        "--workers", type=int, default=None, help="DataLoader workers (default: the experiment's)"
    )
    parser.add_argument("--tmp", default=None, help="folder of the temporary cache files")
    parser.add_argument("--deadline", type=float, default=420.0, help="no measurement starts after this (s)")
    parser.add_argument("--quick", action="store_true", help="tiny sizes, one round: a check that it runs")
    args = parser.parse_args()
    settings = study_settings()
    if args.quick:
        for key, value in QUICK.items():
            if key != "networks":
                setattr(args, key, value)
    if args.workers is None:
        args.workers = settings["num_workers"]
    sizes = [parse_size(s) for s in args.sizes] if args.sizes else [tuple(settings["size"]), FULL_SIZE]
    device = torch.device(args.device)
    if device.type == "cuda":
        torch.backends.cudnn.benchmark = bool(settings["cudnn_benchmark"])
    start = time.monotonic()
    deadline = start + args.deadline
    report: dict[str, Any] = {
        "machine": machine(device),
        "settings": settings,
        "arguments": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "cases": [],
    }
    info = report["machine"]
    print(
        f"{info['device']}, torch {info['torch']} (CUDA {info['cuda']}), {info['cpu_count']} CPUs, "
        f"{info['date']}; {args.rounds} round(s) of {args.seconds:g} s, settings: "
        f"{', '.join(args.precisions)} x channels_last/contiguous; study precision {settings['precision']}"
    )
    for size in sizes:  # the first size (the study's by default) first: the losses are compared there
        for name in args.networks:
            net = network(name, settings, args.quick)
            if time.monotonic() > deadline:
                report["cases"].append({"network": name, "size": list(size), "skipped": "deadline"})
                print(f"\n{name} {size[0]}x{size[1]}: skipped (deadline)")
            else:
                study = name == "deepvo" and size == sizes[0]
                report["cases"].append(run_case(net, size, settings, args, device, deadline, study))
                print_case(report["cases"][-1])
            report["wall_s"] = time.monotonic() - start
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps(report, indent=1, default=str) + "\n")
    print(f"\n{time.monotonic() - start:.0f} s in all; every number in {args.out}")


if __name__ == "__main__":
    main()
