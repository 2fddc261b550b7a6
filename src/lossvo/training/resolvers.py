"""The OmegaConf resolvers lossvo's configs use; the entry points register them (:func:`register`).

- ``dim_of``, ``identity_of``: a loss class's head size and its no-motion output (the model's ``out_dim``
  and ``head_bias`` interpolate them);
- ``matched_k``, ``paper_k``: ``weighting=matched`` and ``weighting=paper``'s k
  (:func:`lossvo.weighting.preset_k`);
- ``path_safe``: a folder name from overrides, short and pasteable into an override; ``job_name``: a
  sweep job's folder name, the swept keys first (:func:`job_name`);
- ``sqlite_storage``: an SQLite URL for an Optuna study, its folder created first.
"""

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
"""Characters of overrides that Hydra's override grammar does not take unquoted (or that would nest
folders), and what they become in a job folder's name."""

MAX_NAME = 64
"""Longest folder name :func:`path_safe` returns (file systems allow 255 bytes a name)."""


def dim_of(target: str) -> int:
    """Head size of a loss class given its ``_target_``."""
    return int(weighting.loss_class(target).dim)


def identity_of(target: str) -> ListConfig:
    """The output of a loss class that decodes to no motion."""
    return ListConfig(weighting.loss_class(target)(k=1.0).identity_output().tolist())


def matched_k(target: str, c: Any, squared: bool = True) -> float | None:
    """``weighting=matched``'s k for a loss class."""
    return weighting.preset_k(target, "matched", c, squared)


def paper_k(target: str) -> float | None:
    """``weighting=paper``'s k for a loss class."""
    return weighting.preset_k(target, "paper")


def path_safe(text: str) -> str:
    """A sweep job's folder name from its overrides, e.g. ``loss-euler+seed-0``, that can be pasted
    unquoted into an override (``ckpt_path=.../0_loss-euler+seed-0/checkpoints/best.ckpt``). A name
    longer than :data:`MAX_NAME` keeps its beginning and ends in a hash of the whole (``-h`` and 10 hex
    digits): stable for the same overrides, and the full overrides stay in ``.hydra/overrides.yaml``."""
    name = str(text).translate(PATH_SAFE)
    if len(name) <= MAX_NAME:
        return name
    digest = hashlib.sha256(name.encode()).hexdigest()[:10]
    return f"{name[: MAX_NAME - 12]}-h{digest}"


SWEPT_KEYS = "LOSSVO_SWEPT_KEYS"
"""The environment variable holding the keys a multirun's command line sweeps (``loss`` in
``-m loss=euler,chordal``), comma-separated, for :func:`job_name` in the launched jobs."""


def swept_keys(argv: Sequence[str]) -> list[str]:
    """The keys of a command line's sweep overrides (``loss=euler,chordal``, ``seed=range(3)``), sorted;
    arguments that are no override, or do not parse, are skipped (Hydra reports them)."""
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
    """A Hydra entry point that records the keys its command line sweeps (:func:`swept_keys`) in
    :data:`SWEPT_KEYS` for the jobs it launches (child processes inherit it) to name their folders."""

    @functools.wraps(main)
    def wrapped() -> Any:
        os.environ[SWEPT_KEYS] = ",".join(swept_keys(sys.argv[1:]))
        return main()

    return wrapped


def job_name(overrides: Sequence[str], swept: str = "", exclude: Sequence[str] = ()) -> str:
    """A sweep job's folder name from its overrides (``hydra.overrides.task``): the swept keys first
    (``swept``, comma-separated: the ones that differ between the sweep's jobs), then the others, each
    group sorted, without the ``exclude`` keys, made short and pasteable by :func:`path_safe`, e.g.
    ``loss-euler+data.splits.test-07+data.splits.unseen-11+trainer.max_epochs-1``."""
    first = set(swept.split(",")) - {""}
    lines = [
        o.input_line or ""
        for o in OverridesParser.create().parse_overrides(list(overrides))
        if o.key_or_group not in exclude
    ]
    keys = {line: line.lstrip("+~").split("=", 1)[0].split("@", 1)[0] for line in lines}
    ordered = sorted(line for line in lines if keys[line] in first)
    ordered += sorted(line for line in lines if keys[line] not in first)
    return path_safe(",".join(ordered))


def sweep_group(mode: Any, sweep_dir: str) -> str | None:
    """A logger's group of runs (W&B's ``group``): the sweep folder in a sweep (``mode``: Hydra's
    ``${hydra:mode}``), none for a single run."""
    return sweep_dir if str(mode).endswith("MULTIRUN") else None


def sqlite_storage(path: str) -> str:
    """An SQLite URL for an Optuna study stored at ``path``, whose folder is created first (the sweep
    folder does not exist yet when the sweeper opens its study)."""
    db = Path(path).expanduser().resolve()
    db.parent.mkdir(parents=True, exist_ok=True)
    return f"sqlite:///{db}"


RESOLVERS: dict[str, Callable[..., Any]] = {
    "dim_of": dim_of,
    "identity_of": identity_of,
    "matched_k": matched_k,
    "paper_k": paper_k,
    "path_safe": path_safe,
    "job_name": job_name,
    "sqlite_storage": sqlite_storage,
    "sweep_group": sweep_group,
}


def register() -> None:
    """Register lossvo's resolvers with OmegaConf (idempotent)."""
    for name, resolver in RESOLVERS.items():
        if not OmegaConf.has_resolver(name):
            OmegaConf.register_new_resolver(name, resolver)
