"""The processor a job's arithmetic ran on, recorded in ``status.json``: kernels round differently on
another machine (experiments/2026-12-07-camera-arm-one-machine.md)."""

from __future__ import annotations

import hashlib
import platform
from functools import cache
from pathlib import Path

import torch

CPUINFO = Path("/proc/cpuinfo")


def describe(cpuinfo: str, capability: str) -> str:
    """``"AMD EPYC, AVX512, flags 3f2a9c1b"``: a ``/proc/cpuinfo`` text's first ``model name``, torch's CPU
    kernel set and a digest of the CPU's feature flags."""
    fields = dict(
        (key.strip(), value.strip())
        for key, _, value in (line.partition(":") for line in reversed(cpuinfo.splitlines()))
        if value
    )
    model = fields.get("model name") or platform.processor() or platform.machine()
    flags = " ".join(sorted(fields.get("flags", "").split()))
    digest = hashlib.sha256(flags.encode()).hexdigest()[:8] if flags else "unknown"
    return f"{model}, {capability}, flags {digest}"


@cache
def machine() -> str:
    """This machine's :func:`describe` (the CPU only: a GPU's arithmetic is not described)."""
    text = CPUINFO.read_text() if CPUINFO.is_file() else ""
    return describe(text, torch.backends.cpu.get_cpu_capability())
