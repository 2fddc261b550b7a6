"""The version of the code that trains and evaluates a job, recorded in its ``status.json``: the package
version and a SHA-256 of its Python and YAML files less :data:`READERS` (no git: a wheel has the same)."""

from __future__ import annotations

import hashlib
from functools import cache
from importlib import metadata
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
READERS = ("report", "study.py")
"""Paths under the package that only read or start runs: changing them changes no job's numbers."""
SUFFIXES = (".py", ".yaml")


def _hashed(path: Path) -> bool:
    relative = path.relative_to(PACKAGE)
    return (
        path.suffix in SUFFIXES and relative.parts[0] not in READERS and "__pycache__" not in relative.parts
    )


@cache
def code_version() -> str:
    """``"0.1.0+3f2a9c1b7d4e"``: the package's version and a digest of its training and evaluation code."""
    digest = hashlib.sha256()
    for path in sorted(p for p in PACKAGE.rglob("*") if p.is_file() and _hashed(p)):
        digest.update(path.relative_to(PACKAGE).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    try:
        version = metadata.version("lossvo")
    except metadata.PackageNotFoundError:
        version = "0+unknown"
    return f"{version}+{digest.hexdigest()[:12]}"
