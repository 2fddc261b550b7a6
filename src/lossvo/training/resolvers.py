"""The OmegaConf resolvers lossvo's configs use (:data:`RESOLVERS`), registered by :func:`register`."""

from __future__ import annotations

import functools
import hashlib
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException
from omegaconf import ListConfig, OmegaConf

from lossvo import weighting

PATH_SAFE = str.maketrans("/=,", "_-+", " '\"[]{}()")
"""Characters that Hydra's override grammar does not take unquoted (or would nest folders), replaced."""

MAX_NAME = 64
"""Longest folder name :func:`path_safe` returns."""


def dim_of(target: str) -> int:
    """Head size of a loss class given its ``_target_``."""
    return int(weighting.loss_class(target).dim)


def identity_of(target: str) -> ListConfig:
    """The output of a loss class that decodes to no motion."""
    return ListConfig(weighting.loss_class(target)(k=1.0).identity_output().tolist())


def path_safe(text: str) -> str:
    """A folder name from overrides, e.g. ``loss-euler+seed-0``, pasteable unquoted into an override; a
    longer one than :data:`MAX_NAME` keeps its beginning and ends in ``-h`` and 10 hex digits of a hash."""
    name = str(text).translate(PATH_SAFE)
    if len(name) <= MAX_NAME:
        return name
    digest = hashlib.sha256(name.encode()).hexdigest()[:10]
    return f"{name[: MAX_NAME - 12]}-h{digest}"


SWEPT_KEYS = "LOSSVO_SWEPT_KEYS"
"""The environment variable holding the keys a multirun's command line sweeps, comma-separated."""


def swept_keys(argv: Sequence[str]) -> list[str]:
    """The keys of a command line's sweep overrides, sorted; what does not parse is skipped (Hydra says)."""
    parser = OverridesParser.create()
    keys = set()
    for arg in argv:
        if arg.startswith("-"):
            continue
        try:
            override = parser.parse_override(arg)
        except HydraException:
            continue
        if override.is_sweep_override():
            keys.add(override.key_or_group)
    return sorted(keys)


def names_swept_jobs(main: Callable[[], Any]) -> Callable[[], Any]:
    """A Hydra entry point recording its command line's swept keys in :data:`SWEPT_KEYS` for its jobs."""

    @functools.wraps(main)
    def wrapped() -> Any:
        os.environ[SWEPT_KEYS] = ",".join(swept_keys(sys.argv[1:]))
        return main()

    return wrapped


def job_name(overrides: Sequence[str], swept: str = "", exclude: Sequence[str] = ()) -> str:
    """A sweep job's folder name from its overrides: the ``swept`` keys (comma-separated) first, then the
    others, each group sorted, without ``exclude``, through :func:`path_safe`."""
    lead = set(swept.split(",")) - {""}
    parsed = OverridesParser.create().parse_overrides(list(overrides))
    kept = [o for o in parsed if o.key_or_group not in exclude]
    lines = sorted((o.key_or_group not in lead, o.input_line or "") for o in kept)  # the swept (False) first
    return path_safe(",".join(line for _, line in lines))


def sweep_group(mode: Any, sweep_dir: str) -> str | None:
    """A logger's group of runs: the sweep folder in a sweep (``mode``: ``${hydra:mode}``), else None."""
    return sweep_dir if str(mode).endswith("MULTIRUN") else None


def sqlite_storage(path: str) -> str:
    """An SQLite URL for ``path``, its folder created first (the sweeper opens it before the sweep folder)."""
    db = Path(path).expanduser().resolve()
    db.parent.mkdir(parents=True, exist_ok=True)
    return f"sqlite:///{db}"


RESOLVERS: dict[str, Callable[..., Any]] = {
    **{f.__name__: f for f in (dim_of, identity_of, path_safe, job_name, sqlite_storage, sweep_group)},
    "matched_k": lambda target, c, squared=True: weighting.preset_k(target, "matched", c, squared),
    "paper_k": lambda target: weighting.preset_k(target, "paper"),
}


def register() -> None:
    """Register lossvo's resolvers with OmegaConf (idempotent)."""
    for name, resolver in RESOLVERS.items():
        if not OmegaConf.has_resolver(name):
            OmegaConf.register_new_resolver(name, resolver)
