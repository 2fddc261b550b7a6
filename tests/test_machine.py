"""The machine a job ran on: what tells two CPUs' arithmetic apart."""

from __future__ import annotations

from lossvo.machine import describe, machine

CPUINFO = """processor\t: 0
model name\t: AMD EPYC
flags\t\t: fpu avx2 fma
processor\t: 1
model name\t: AMD EPYC
flags\t\t: fpu avx2 fma
"""


def test_a_machine_is_its_model_its_kernels_and_its_flags() -> None:
    one = describe(CPUINFO, "AVX2")
    assert one.startswith("AMD EPYC, AVX2, flags ") and len(one.rsplit(" ", 1)[1]) == 8
    assert describe(CPUINFO.replace("fma", "fma avx512f"), "AVX2") != one  # other flags: another machine
    assert describe(CPUINFO.replace("fpu avx2 fma", "fma fpu avx2"), "AVX2") == one  # in any order
    assert describe(CPUINFO, "AVX512") != one


def test_without_cpuinfo_the_platform_names_the_processor() -> None:
    assert describe("", "DEFAULT").endswith(", DEFAULT, flags unknown")
    assert machine() == machine() and machine().count(", ") >= 2
