"""The processor a job's arithmetic ran on, recorded beside its code version in ``status.json``: one code
and seed give the same numbers on one machine and different ones on another, whose kernels round
differently (experiments/2026-12-07-camera-arm-one-machine.md), so jobs paired by seed share a start only
where they also share a machine."""

from __future__ import annotations

import hashlib
import platform
from functools import cache
from pathlib import Path

import torch

CPUINFO = Path("/proc/cpuinfo")


def describe(cpuinfo: str, capability: str) -> str:
    """``"AMD EPYC, AVX512, flags 3f2a9c1b"``: the first ``model name`` of a ``/proc/cpuinfo`` text, torch's
    CPU kernel set and a digest of the CPU's feature flags (which pick the kernels); the platform's
    processor string where the text has none."""
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
