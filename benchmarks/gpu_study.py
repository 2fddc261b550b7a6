"""The decided study on one GPU: the training step's rate, one job end to end, full DeepVO's precision and
FLOP rate, and the study's jobs sharing the GPU; one prepared run of at most ``--deadline`` seconds.

Run on a GPU machine from the repository root, with lossvo's venv or with torch, Lightning, torchmetrics,
OpenCV and scipy there and the other pure-Python dependencies carried in ``.gpu-deps/``
(``benchmarks/gpu_deps.sh``; docs/gpu.md)::

    PYTHONPATH=src:.gpu-deps python benchmarks/gpu_study.py --out $OUT

Check it on a CPU (tiny sizes, eager steps, one seed of the study; ``tests/test_gpu_study_script.py``)::

    .venv/bin/python benchmarks/gpu_study.py --quick --device cpu --out /tmp/gpu-study \\
        --job-overrides data=kitti data.sources.kitti.root=<a tiny KITTI-layout folder> ...

Stages, each skipped (and recorded as such) when the time left is below its estimate, every number written
to ``<out>/gpu_study.json`` after each stage (beside it the commands' logs and the study's report; the runs'
folders go to ``--work``, so that ``<out>`` stays a handful of files):

1. **The chip's matrix rate**: bf16 and TF32 matrix products of 8192x8192, TFLOP/s.
2. **The embedded data and a warm-up job**, in the background from the start: ``python -m lossvo.train
   model=flowvo trainer=gpu trainer.max_epochs=1 evaluate=false`` renders the synthetic dataset, caches its
   frames and flow and fills torch.compile's cache (later stages wait for it before they time anything).
3. **FlowVO's training step at 64x208** (its config: pairs, 20 a batch, the chordal loss): a batch resident
   on the GPU, and batches gathered there from resident arrays with the mirror augmentation, as
   ``data.loader.on_device`` does; eager, and compiled (``default``, ``reduce-overhead``: CUDA graphs), in
   fp32 and bf16 autocast (``trainer=gpu``'s precision); the fused Adam and the step's record as the module
   has them. Steps/s over interleaved rounds, compile seconds, peak memory, and the host synchronisations of a
   step counted by ``torch.cuda.set_sync_debug_mode``.
4. **One default FlowVO job end to end**: ``python -m lossvo.train model=flowvo trainer=gpu`` (10 epochs and
   the evaluation of 13 sequences) on the cached data: wall seconds, the epochs' seconds from its log.
5. **Full DeepVO at 184x608** (7 frames x 8): fp32 and bf16 (the LSTM under autocast, or in fp32 with TF32),
   channels-last; FLOPs of a step (``torch.utils.flop_counter``), the fraction of the measured bf16 rate,
   the top kernels of a profiled bf16 step (``torch.profiler``), and the study (3 losses x 200 epochs of
   KITTI's training windows) in GPU-hours.
6. **The study's jobs sharing the GPU**: ``python -m lossvo.study`` with the seeds that fit the time left
   (all 10: the 60 jobs of ``make study``), wall seconds, jobs at once, each job's peak GPU memory
   (``nvidia-smi``) and the report's path.
7. **FlowVO's step at 184x608**: eager and ``reduce-overhead``, bf16.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import shlex
import shutil
import subprocess
import sys
import threading
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

import gpu_path
import lossvo
from lossvo import models
from lossvo.data import resident
from lossvo.data.transforms import Mirror
from lossvo.evaluation import job_folder
from lossvo.training.module import VOModule
from lossvo.training.step import StepRecord, compiled

ROOT = Path(__file__).resolve().parent.parent
CONF = Path(lossvo.__file__).parent / "conf"
FLOWVO_MODES = (("eager", None, "fp32"), ("reduce-overhead", "reduce-overhead", "bf16"),
                ("reduce-overhead", "reduce-overhead", "fp32"), ("default", "default", "bf16"))  # fmt: skip
"""(label, torch.compile mode, precision) of the FlowVO step variants; the second is what ``trainer=gpu``
trains with (``compile=auto``, ``bf16-mixed``)."""
QUICK_MODES = (("eager", None, "fp32"), ("eager", None, "bf16"))
"""--quick: no compilation (tests/test_step.py checks the compiled step on a CPU)."""
QUICK_BATCH = 4
"""--quick: FlowVO's step on this many windows, not its config's batch (a CPU check of the plumbing)."""


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", flush=True)


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


# -- 1. the chip's matrix rate ----------------------------------------------------------------------------


def matrix_rate(device: torch.device, n: int, seconds: float) -> dict[str, float]:
    """TFLOP/s of n x n matrix products in bf16 and in fp32 with TF32 tensor cores (float32 on a CPU)."""
    out = {}
    for name, dtype in (("bf16", torch.bfloat16), ("tf32", torch.float32)):
        previous = torch.backends.cuda.matmul.allow_tf32
        torch.backends.cuda.matmul.allow_tf32 = name == "tf32"
        a, b = (torch.randn(n, n, device=device, dtype=dtype) for _ in range(2))
        for _ in range(3):
            a @ b
        sync(device)
        count, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds:
            for _ in range(10):
                a @ b
            count += 10
            sync(device)
        out[f"{name}_tflops"] = 2 * n**3 * count / (time.perf_counter() - start) / 1e12
        torch.backends.cuda.matmul.allow_tf32 = previous
        del a, b
    return out


# -- 2. data and warm-up; 4. a job end to end; 7. the study ------------------------------------------------


def command_env(cache: Path) -> dict[str, str]:
    path = os.pathsep.join([str(ROOT / "src"), str(ROOT / ".gpu-deps"), os.environ.get("PYTHONPATH", "")])
    return {**os.environ, "PYTHONPATH": path, "LOSSVO_CACHE": str(cache), "PYTHONUNBUFFERED": "1"}


class Command:
    """A command run in the background, its output in a log file; :meth:`wait` returns its record."""

    def __init__(self, args: list[str], log_file: Path, env: dict[str, str], timeout: float) -> None:
        self.args, self.log_file, self.timeout = args, log_file, timeout
        self.start = time.monotonic()
        self.file = log_file.open("w")
        self.process = subprocess.Popen(args, cwd=ROOT, env=env, stdout=self.file, stderr=subprocess.STDOUT)
        self.peaks: dict[int, int] = {}
        self._watch = threading.Thread(target=self._gpu_memory, daemon=True)
        self._watch.start()

    def _gpu_memory(self) -> None:
        """Each process's largest GPU memory (MiB) while the command runs, from nvidia-smi every second."""
        while self.process.poll() is None:
            try:
                text = subprocess.run(
                    ["nvidia-smi", "--query-compute-apps=pid,used_memory", "--format=csv,noheader,nounits"],
                    capture_output=True, text=True, timeout=10,
                ).stdout  # fmt: skip
            except (OSError, subprocess.TimeoutExpired):
                return
            for line in text.splitlines():
                pid, _, used = line.partition(",")
                if pid.strip().isdigit() and used.strip().isdigit():
                    self.peaks[int(pid)] = max(self.peaks.get(int(pid), 0), int(used))
            time.sleep(1.0)

    def wait(self) -> dict[str, Any]:
        left = self.timeout - (time.monotonic() - self.start)
        try:
            code = self.process.wait(timeout=max(left, 1.0))
        except subprocess.TimeoutExpired:
            self.process.kill()
            code = "timeout"
        self.file.close()
        tail = self.log_file.read_text(errors="replace").splitlines()[-15:]
        peaks = [v for pid, v in self.peaks.items() if pid != os.getpid()]
        return {"command": shlex.join(self.args), "exit": code, "wall_s": time.monotonic() - self.start,
                "log": str(self.log_file), "tail": tail if code != 0 else tail[-3:],
                "gpu_mib_per_process": sorted(peaks, reverse=True)}  # fmt: skip


def epoch_seconds(run_dir: Path) -> list[float]:
    """Each epoch's seconds from a run's ``train.log`` (the ``epoch k/n (s s)`` lines)."""
    log_file = run_dir / "train.log"
    if not log_file.is_file():
        return []
    out = []
    for line in log_file.read_text(errors="replace").splitlines():
        if "] - epoch " in line and " s) " in line:
            out.append(float(line.split("(", 1)[1].split(" s)", 1)[0]))
    return out


def train_command(run_dir: Path, trainer: str, overrides: list[str]) -> list[str]:
    job = ["model=flowvo", f"trainer={trainer}", f"hydra.run.dir={run_dir}", *overrides]
    return [sys.executable, "-m", "lossvo.train", *job]


# -- 3, 6. FlowVO's step; 5. DeepVO's precision -------------------------------------------------------------


def module_of(model: str, size: tuple[int, int], loss: str = "ChordalLoss") -> VOModule:
    """The VOModule a run builds: the shipped model config's plain entries, the loss's head (matched k)."""
    from lossvo import losses

    node = gpu_path.config(f"model/{model}.yaml")
    spec = gpu_path.plain(node.model if "model" in node else node)  # flowvo.yaml is a global package
    cls = getattr(losses, loss)
    head = {
        "out_dim": cls.dim,
        "head_bias": cls().identity_output().tolist(),
        "height": size[0],
        "width": size[1],
    }
    model_cfg = {k: v for k, v in spec.items() if k != "flownet"} | head
    optimizer = {"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1e-3}
    torch.manual_seed(0)
    return VOModule(model=model_cfg, loss={"_target_": f"lossvo.losses.{loss}"}, optimizer=optimizer)


def random_windows(size: tuple[int, int], frames: int, device: torch.device) -> resident.ResidentWindows:
    """Pair windows of one sequence of random frames and flow, resident on ``device``."""
    generator = np.random.default_rng(0)
    H, W = size
    image = generator.integers(0, 256, (frames, 3, H, W), dtype=np.uint8)
    flow = (3 * generator.standard_normal((frames - 1, 2, H, W), dtype=np.float32)).astype(np.float16)
    from lossvo import geometry as g

    targets = g.se3_exp(0.05 * torch.randn(frames - 1, 6, dtype=torch.float64)).float()
    starts = np.arange(frames - 1)
    index = np.stack([np.zeros_like(starts), starts, starts + 2, np.ones_like(starts)], axis=1)
    K = gpu_path.kitti_like_K(H, W)
    return resident.ResidentWindows(
        index, [image], {1: [targets]}, [K], [torch.tensor(True)], {1: [flow]}, device
    )


class Gathered:
    """Batches as ``data.loader.on_device`` gives them: index batches built on the host, gathered on the
    device, half of them mirrored (frames, targets, flow, K), frames normalised and flow made float."""

    def __init__(self, windows: resident.ResidentWindows, batch_size: int, width: int) -> None:
        self.windows, self.batch_size, self.width = windows, batch_size, width
        self.order = np.random.default_rng(1).permutation(len(windows.index))
        self.position = 0
        self.scale = torch.full((3, 1, 1), 1 / (255 * 0.25), device=windows.device)  # std 0.25, mean 0.5
        self.shift = torch.full((3, 1, 1), 0.5 / 0.25, device=windows.device)

    def __call__(self) -> dict[str, Tensor]:
        if self.position + self.batch_size > len(self.order):
            self.position = 0
        chosen = self.order[self.position : self.position + self.batch_size]
        self.position += self.batch_size
        batch = self.windows.gather(self.windows.index_batch(chosen.tolist()))
        inputs = {k: batch[k] for k in ("frames", "flow", "K")}
        inputs, targets = Mirror(0.5)(inputs, batch["targets"])
        return {"frames": inputs["frames"].float().mul_(self.scale).sub_(self.shift),
                "flow": inputs["flow"].float(), "K": inputs["K"], "targets": targets}  # fmt: skip


def step_runner(module: VOModule, mode: str | None, bf16: bool, device: torch.device,
                batches: Callable[[], dict[str, Tensor]]) -> Callable[[int], None]:  # fmt: skip
    """``run(n)``: n training steps as the module takes them (compiled in ``mode``, fused Adam, the
    record), on batches from ``batches``."""
    module.to(device).train()
    step = compiled(module.losses, mode)
    optimizer = module.configure_optimizers()
    records = [StepRecord(1024, module.loss.output_keys(), device)]
    reads = models.inputs_of(module.model)

    def run(n: int) -> None:
        for _ in range(n):
            record = records[-1]
            batch = batches()
            if mode is not None:
                torch.compiler.cudagraph_mark_step_begin()
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
                loss, row = step({k: batch[k] for k in reads}, batch["targets"])
            loss.backward()
            optimizer.step()
            optimizer.zero_grad(set_to_none=True)
            if record.steps >= len(record.table):  # an epoch's end: a fresh record
                records[-1] = record = StepRecord(1024, module.loss.output_keys(), device)
            record.write(row)

    return run


def host_syncs(run: Callable[[int], None], device: torch.device, steps: int) -> int | None:
    """Host synchronisations in ``steps`` steps, as CUDA's sync debug mode reports them."""
    if device.type != "cuda":
        return None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        torch.cuda.set_sync_debug_mode("warn")
        try:
            run(steps)
        finally:
            torch.cuda.set_sync_debug_mode("default")
    return sum("synchroniz" in str(w.message) for w in caught)


def flowvo_steps(size: tuple[int, int], modes: tuple, args: argparse.Namespace, device: torch.device,
                 ready: Callable[[], None]) -> dict[str, Any]:  # fmt: skip
    """FlowVO's step in each mode: compiled and warmed first, then timed in interleaved rounds once
    ``ready()`` returns (the background preparation done)."""
    batch_size = QUICK_BATCH if args.quick else int(gpu_path.config("model/flowvo.yaml").reads.batch_size)
    windows = random_windows(size, args.frames, device)
    gathered = Gathered(windows, batch_size, size[1])
    fixed = gathered()
    runners: dict[str, dict[str, Callable[[int], None]]] = {}
    out: dict[str, Any] = {"size": list(size), "batch_size": batch_size, "modes": {}}
    for label, mode, precision in modes:
        name = f"{label} {precision}"
        entry: dict[str, Any] = {"compile_mode": mode, "precision": precision}
        try:
            module = module_of("flowvo", size)
            bf16 = precision == "bf16"
            runners[name] = {
                "resident": step_runner(module, mode, bf16, device, lambda: fixed),
                "gathered": step_runner(module, mode, bf16, device, gathered),
            }
            start = time.perf_counter()
            runners[name]["resident"](3)
            runners[name]["gathered"](3)
            sync(device)
            entry["first_steps_s"] = time.perf_counter() - start  # compilation included
            entry["syncs_per_5_steps"] = host_syncs(runners[name]["resident"], device, 5)
            entry["syncs_per_5_gathered_steps"] = host_syncs(runners[name]["gathered"], device, 5)
        except Exception as e:  # a mode that fails is recorded, the others still run
            entry["error"] = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
            runners.pop(name, None)
        out["modes"][name] = entry
        log(f"flowvo {size[0]}x{size[1]} {name}: {entry}")
    ready()
    rounds: dict[str, dict[str, list[float]]] = {n: {"resident": [], "gathered": []} for n in runners}
    for r in range(args.rounds):
        for name in sorted(runners, reverse=r % 2 == 1):
            for kind in ("resident", "gathered"):
                if device.type == "cuda":
                    torch.cuda.reset_peak_memory_stats(device)
                steps_per_s, _ = gpu_path.rate(runners[name][kind], device, args.seconds, 3)
                rounds[name][kind].append(steps_per_s)
                if device.type == "cuda":
                    out["modes"][name]["peak_bytes"] = torch.cuda.max_memory_allocated(device)
    for name, kinds in rounds.items():
        for kind, values in kinds.items():
            out["modes"][name][f"{kind}_steps_per_s"] = gpu_path.spread(values)
    return out


class FP32LSTM(nn.Module):
    """An LSTM run outside autocast, in fp32 (TF32 tensor cores), whatever the surrounding precision."""

    def __init__(self, lstm: nn.LSTM) -> None:
        super().__init__()
        self.lstm = lstm

    def forward(self, x: Tensor, state: Any = None) -> Any:
        with torch.autocast(x.device.type, enabled=False):
            return self.lstm(x.float(), state)


def deepvo_precision(args: argparse.Namespace, device: torch.device, peak: float | None) -> dict[str, Any]:
    """Full DeepVO's training rate at the study's size in fp32 and bf16 (LSTM in bf16 or in fp32), its
    FLOPs per step and their rate against the chip's, the top kernels of a bf16 step, the study's cost."""
    from torch.utils.flop_counter import FlopCounterMode

    settings = gpu_path.study_settings()
    size = tuple(args.deepvo_size or settings["size"])
    net = gpu_path.network("deepvo", settings, args.quick)
    loss = gpu_path.loss_of(settings["losses"]["chordal"])
    model = gpu_path.build(net, size, loss, channels_last=True)
    batch = {k: v.to(device) for k, v in gpu_path.resident_batch(model, net, size).items()}
    variants = {"fp32": (False, False), "bf16": (True, False), "bf16 lstm-fp32": (True, True)}
    original_lstm = model.lstm
    parameters = sum(p.numel() for p in model.parameters())
    out: dict[str, Any] = {"size": list(size), "batch_size": net.batch_size, "seq_len": net.seq_len,
                           "parameters": parameters, "variants": {}}  # fmt: skip
    torch.backends.cuda.matmul.allow_tf32 = True  # fp32 matrix products on TF32 tensor cores
    with FlopCounterMode(display=False) as flops:
        gpu_path.train_step(model.to(device), loss, torch.optim.SGD(model.parameters(), lr=0.0), batch, False)
    out["flops_counted_per_step"] = flops.get_total_flops()  # cuDNN's LSTM is not among the counted ops
    out["lstm_flops_per_step"] = lstm_flops(model, net.batch_size, net.seq_len - 1)
    out["flops_per_step"] = out["flops_counted_per_step"] + out["lstm_flops_per_step"]
    rounds: dict[str, list[float]] = {v: [] for v in variants}
    for r in range(args.rounds):
        for name in sorted(variants, reverse=r % 2 == 1):
            bf16, lstm_fp32 = variants[name]
            model.lstm = FP32LSTM(original_lstm) if lstm_fp32 else original_lstm
            try:
                measured = gpu_path.measure(model, loss, batch, bf16, args, settings["lr"])
            except RuntimeError as e:
                out["variants"][name] = {"error": gpu_path.failure(e)}
                continue
            rounds[name].append(measured["steps_per_s"])
            out["variants"].setdefault(name, {})["peak_bytes"] = measured["peak_bytes"]
            out["variants"][name]["eval_steps_per_s"] = measured["eval_steps_per_s"]
    counts = gpu_path.study_windows(settings, net.seq_len)
    for name, values in rounds.items():
        if not values:
            continue
        entry = out["variants"][name]
        entry["steps_per_s"] = gpu_path.spread(values)
        median = entry["steps_per_s"]["median"]
        entry["achieved_tflops"] = out["flops_per_step"] * median / 1e12
        if peak:
            entry["fraction_of_bf16_rate"] = entry["achieved_tflops"] / peak
        rates = (median * net.batch_size, entry["eval_steps_per_s"] * net.batch_size)
        entry["study"] = gpu_path.gpu_hours(
            counts, *rates, settings["max_epochs"], len(gpu_path.STUDY_LOSSES)
        )
    out["windows_per_epoch"] = counts
    model.lstm = original_lstm
    out["top_kernels_bf16"] = top_kernels(model, loss, batch, device, settings["lr"])
    model.to("cpu")
    return out


def lstm_flops(model: nn.Module, batch: int, steps: int) -> int:
    """FLOPs of the LSTM's matrix products in a training step: forward ``2 * 4H * (I + H)`` per layer, window
    and time step, backward twice that."""
    lstm = model.lstm
    inputs = [lstm.input_size] + [lstm.hidden_size] * (lstm.num_layers - 1)
    forward = sum(2 * 4 * lstm.hidden_size * (i + lstm.hidden_size) for i in inputs) * batch * steps
    return 3 * forward


def top_kernels(
    model: nn.Module, loss: nn.Module, batch: dict, device: torch.device, lr: float
) -> list[dict]:
    """The 15 kernels of most device time in 3 profiled bf16 training steps."""
    from torch.profiler import ProfilerActivity, profile

    model.to(device).train()
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    gpu_path.train_step(model, loss, optimizer, batch, True)
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    with profile(activities=activities) as prof:
        for _ in range(3):
            gpu_path.train_step(model, loss, optimizer, batch, True)
        sync(device)
    key = "self_device_time_total" if device.type == "cuda" else "self_cpu_time_total"
    events = sorted(prof.key_averages(), key=lambda e: getattr(e, key, 0), reverse=True)[:15]
    return [{"name": e.key[:120], "ms_per_step": getattr(e, key, 0) / 1e3 / 3, "calls": e.count // 3}
            for e in events]  # fmt: skip


# -- the run ------------------------------------------------------------------------------------------------


def write(report: dict[str, Any], out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "gpu_study.json").write_text(json.dumps(report, indent=1, default=str) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="folder of gpu_study.json and the logs")
    parser.add_argument("--device", default="cuda")
    parser.add_argument(
        "--deadline", type=float, default=450.0, help="seconds: no stage starts past its share"
    )
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=1.5, help="timed steps per measurement")
    parser.add_argument("--eval-seconds", type=float, default=0.3)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--frames", type=int, default=1000, help="frames of the random resident sequence")
    parser.add_argument("--deepvo-size", type=int, nargs=2, default=None, help="H W (default: the study's)")
    parser.add_argument("--cache", type=Path, default=Path("/tmp/lossvo-gpu-study-cache"))
    parser.add_argument(
        "--work", type=Path, default=Path("/tmp/lossvo-gpu-study-runs"), help="the runs' folders"
    )
    parser.add_argument("--job-overrides", nargs="*", default=[], help="for every lossvo.train/study command")
    parser.add_argument("--study-models", default="deepvo_small,flowvo", help="the study stage's --models")
    parser.add_argument("--quick", action="store_true", help="tiny sizes, eager steps, one seed: a CPU check")
    args = parser.parse_args()
    device = torch.device(args.device)
    trainer = "gpu" if device.type == "cuda" else "default"
    size, large = ((64, 208), (184, 608)) if not args.quick else ((32, 64), (32, 96))
    modes = FLOWVO_MODES if not args.quick else QUICK_MODES
    if args.quick:
        args.rounds, args.seconds, args.eval_seconds, args.warmup, args.frames = 1, 0.2, 0.05, 1, 40
        args.deepvo_size = args.deepvo_size or [64, 64]
    if device.type == "cuda":
        torch.backends.cudnn.benchmark = True
    start = time.monotonic()
    left = lambda: args.deadline - (time.monotonic() - start)  # noqa: E731
    env = command_env(args.cache)
    args.out.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(args.work, ignore_errors=True)  # the runs start afresh (the data cache is kept)
    report: dict[str, Any] = {"machine": gpu_path.machine(device), "arguments": vars(args), "stages": {}}
    report["machine"]["date"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    stages = report["stages"]
    log(f"{report['machine']['device']}, torch {torch.__version__}, deadline {args.deadline:g} s")

    warm = Command(train_command(args.work / "warmup-job", trainer,
                                 ["trainer.max_epochs=1", "+evaluate=false", *args.job_overrides]),
                   args.out / "warmup-job.log", env, timeout=max(left() - 60, 30))  # fmt: skip
    waited: dict[str, Any] = {}

    def ready() -> None:
        if not waited:
            waited.update(warm.wait())
            stages["warmup_job"] = waited
            log(f"warm-up job: exit {waited['exit']} after {waited['wall_s']:.0f} s")

    plan: list[tuple[str, float, Callable[[], Any]]] = [
        ("matrix_rate", 15, lambda: matrix_rate(device, *((8192, 2.0) if not args.quick else (256, 0.2)))),
        ("flowvo_step", 90, lambda: flowvo_steps(size, modes, args, device, ready)),
        ("job", 60, lambda: job(args, trainer, env, left, ready)),
        (
            "deepvo",
            60,
            lambda: deepvo_precision(args, device, stages.get("matrix_rate", {}).get("bf16_tflops")),
        ),
        ("study", 120, lambda: study(args, env, left, device)),
        ("flowvo_step_large", 60, lambda: flowvo_steps(large, modes[:2], args, device, ready)),
    ]
    for name, needs, stage in plan:
        if left() < needs:
            stages[name] = {"skipped": f"{left():.0f} s left, {needs:g} s needed"}
            log(f"{name}: skipped ({left():.0f} s left)")
            continue
        log(f"{name} ...")
        try:
            stages[name] = stage()
        except Exception as e:  # one stage's failure is recorded, the others still run
            stages[name] = {"error": f"{type(e).__name__}: {e}"}
        if device.type == "cuda":
            torch.cuda.empty_cache()
        report["wall_s"] = time.monotonic() - start
        write(report, args.out)
        log(f"{name}: {json.dumps(stages[name], default=str)[:400]}")
    ready()
    report["wall_s"] = time.monotonic() - start
    write(report, args.out)
    log(f"{report['wall_s']:.0f} s in all; every number in {args.out / 'gpu_study.json'}")


def job(args: argparse.Namespace, trainer: str, env: dict[str, str], left: Callable[[], float],
        ready: Callable[[], None]) -> dict[str, Any]:  # fmt: skip
    """The default FlowVO job on the cached data, after the warm-up job."""
    ready()
    run_dir = args.work / "job"
    result = Command(train_command(run_dir, trainer, list(args.job_overrides)), args.out / "job.log", env,
                     timeout=max(left() - 30, 30)).wait()  # fmt: skip
    result["epoch_s"] = epoch_seconds(run_dir)
    return result


def study(args: argparse.Namespace, env: dict[str, str], left: Callable[[], float],
          device: torch.device) -> dict[str, Any]:  # fmt: skip
    """``python -m lossvo.study`` with as many seeds as the time left allows (10: ``make study``)."""
    seeds = 2 if args.quick else 10 if left() > 600 else 3 if left() > 200 else 2  # a study has >= 2 seeds
    sweep = args.work / "study"
    command = [sys.executable, "-m", "lossvo.study", "--seeds", ",".join(map(str, range(seeds))),
               "--models", args.study_models, "--sweep-dir", str(sweep), *args.job_overrides]  # fmt: skip
    result = Command(command, args.out / "study.log", env, timeout=max(left() - 15, 30)).wait()
    statuses = [job_folder.read_status(p.parent) for p in sweep.glob(f"*/{job_folder.STATUS}")]
    result |= {"seeds": seeds, "jobs": len(statuses),
               "completed": sum(s is not None and s.state == "completed" for s in statuses),
               "report": next((str(p) for p in sweep.glob("report/report.md")), None)}  # fmt: skip
    if result["report"]:
        shutil.copy(result["report"], args.out / "study-report.md")
    return result


if __name__ == "__main__":
    main()
