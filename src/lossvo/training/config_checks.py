"""Checks of a composed training config before anything is built, each failure a one-line
:class:`~lossvo.console.UserError` naming the key, the value and what was expected (docs/bad-input.md).
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import torch
from hydra import compose
from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException, InstantiationException
from hydra.experimental.callback import Callback
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf, open_dict
from omegaconf.errors import OmegaConfBaseException

from lossvo import weighting
from lossvo.checks import is_integer, is_number
from lossvo.console import UserError, exit_in_one_line, one_line, typed_value_message

_ABSENT = object()


def _finite(value: Any, low: float) -> bool:
    return is_number(value) and math.isfinite(value) and value >= low


def _limit(value: Any) -> bool:
    return is_integer(value, 1) or (is_integer(value, -1) and value == -1)


NO_LIMIT = "an integer >= 1, or -1 for no limit"

SCALARS: tuple[tuple[str, Callable[[Any], bool], str], ...] = (
    ("seed", lambda v: v is None or (is_integer(v, 0) and v < 2**32), "null or an integer in [0, 2**32)"),
    ("trainer.max_epochs", _limit, NO_LIMIT),
    ("trainer.max_steps", _limit, NO_LIMIT),
    ("trainer.log_every_n_steps", lambda v: is_integer(v, 1), "an integer >= 1"),
    ("trainer.check_val_every_n_epoch", lambda v: v is None or is_integer(v, 1), "null or an integer >= 1"),
    ("trainer.gradient_clip_val", lambda v: v is None or _finite(v, 0.0), "null or a finite number >= 0"),
    ("optimizer.lr", lambda v: _finite(v, 0.0) and v > 0, "a finite number > 0"),
    ("optimizer.weight_decay", lambda v: _finite(v, 0.0), "a finite number >= 0"),
    ("resume", lambda v: isinstance(v, bool), "true or false"),
    ("evaluate", lambda v: isinstance(v, bool), "true or false"),
    ("mirror_average", lambda v: isinstance(v, bool), "true or false"),
    (
        "scheduler.T_max",
        lambda v: is_integer(v, 1),
        "an integer >= 1 (the cosine schedule's length in epochs, trainer.max_epochs by default)",
    ),
)
"""(key, test, what is expected) of the scalar settings checked; a key the config lacks is skipped."""


CUDA_ACCELERATORS = ("gpu", "cuda")
"""``trainer.accelerator`` values that train on a CUDA GPU."""


def resolved_config(cfg: DictConfig) -> dict[str, Any]:
    """The config as plain containers, resolved; UserError naming the key of one that does not resolve."""
    try:
        return cast("dict[str, Any]", OmegaConf.to_container(cfg, resolve=True))
    except OmegaConfBaseException as e:  # an interpolation that does not resolve, or to a wrong type
        raise UserError(typed_value_message(e)) from None


def check_train_config(cfg: DictConfig, machine: bool = True) -> None:
    """UserError (one line) for a config that would fail under way; ``machine=False``: no GPU checks."""
    if cfg.get("weighting") is not None:
        weighting.check_config(cfg.weighting, cfg.loss)
    resolved_config(cfg)
    check_values(cfg, SCALARS)
    _check_flow(cfg)
    check_source_roots(cfg.get("data"))
    check_devices(_select(cfg, "trainer.devices"), _select(cfg, "trainer.strategy"))
    accelerator = _select(cfg, "trainer.accelerator")
    if machine and accelerator in CUDA_ACCELERATORS:
        choice = HydraConfig.get().runtime.choices.get("trainer") if HydraConfig.initialized() else None
        check_accelerator(accelerator, torch.cuda.is_available(), choice)
    ckpt_path = cfg.get("ckpt_path")
    if ckpt_path is not None:
        check_checkpoint_path(Path(str(ckpt_path)).expanduser())
        if not Path(str(ckpt_path)).expanduser().is_file():
            raise UserError(f"ckpt_path: checkpoint not found: {ckpt_path}")
    check_data(cfg)


def check_values(cfg: DictConfig, scalars: Sequence[tuple[str, Callable[[Any], bool], str]]) -> None:
    """UserError naming the first key without a value (``???``), else the first of ``scalars`` (key, test,
    what is expected) the config holds that fails its test."""
    missing = sorted(OmegaConf.missing_keys(cfg))
    if missing:
        raise UserError(f"{missing[0]}: a value is required: add {missing[0]}=... to the command line")
    for key, test, expected in scalars:
        value = _select(cfg, key)
        if value is not _ABSENT and not test(value):
            raise UserError(f"{key}: expected {expected}, got {value!r}")


def _select(cfg: DictConfig, key: str) -> Any:
    """The resolved value at a dotted ``key``, lists and mappings as plain containers; absent: _ABSENT."""
    value = OmegaConf.select(cfg, key, default=_ABSENT)
    return OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value


def instantiate_checked(config: Any, key: str | None = None, **kwargs: Any) -> Any:
    """Hydra's ``instantiate``; a constructor's UserError raised as it is, and with ``key`` its ValueError
    as one line naming ``key`` (Lightning's Trainer refuses a value so)."""
    try:
        return instantiate(config, **kwargs)
    except InstantiationException as e:
        if key is not None and isinstance(e.__cause__, ValueError):
            raise UserError(f"{key}: {one_line(e.__cause__)}") from e.__cause__
        if isinstance(e.__cause__, UserError):
            raise e.__cause__ from None
        raise


def check_data(cfg: DictConfig) -> None:
    """The data module's constructor's checks, without reading any data."""
    if cfg.get("data") is not None:
        instantiate_checked(cfg.data, _convert_="all")


def check_checkpoint_path(path: Path) -> None:
    """Refuse a ``ckpt_path`` that is a folder, naming the checkpoint files in it."""
    if not path.is_dir():
        return
    found = sorted(str(p.relative_to(path)) for p in path.rglob("*.ckpt"))
    inside = f"in it: {', '.join(found[:4])}{', ...' if len(found) > 4 else ''}" if found else "it holds none"
    raise UserError(f"ckpt_path: {path} is a folder, expected a .ckpt file ({inside})")


def check_source_roots(data: Any) -> None:
    """Refuse a ``data.sources.<name>.root`` that is a file (a dataset is a folder)."""
    sources = data.get("sources") if isinstance(data, Mapping) else None
    for name, source in (sources or {}).items():
        root = source.get("root") if isinstance(source, Mapping) else None
        if isinstance(root, str) and Path(root).expanduser().is_file():
            raise UserError(f"data.sources.{name}.root: {root} is a file, expected the dataset's folder")


def _check_flow(cfg: DictConfig) -> None:
    """A network that reads optical flow (its config names one: ``model.flow``) needs data with flow."""
    needs, has = _select(cfg, "model.flow"), _select(cfg, "data.flow.method")
    if needs is not _ABSENT and needs is not None and has in ("none", None):
        raise UserError(
            f"model.flow: the network reads optical flow ({needs}) but data.flow.method={has} caches "
            f"none: expected data.flow.method=dis"
        )


def check_devices(devices: Any, strategy: Any) -> None:
    """Several devices need a distributed strategy (else each device's process runs the whole command)."""
    several = (is_integer(devices, 2)) or (isinstance(devices, list) and len(devices) > 1)
    if several and strategy in (_ABSENT, None, "auto"):
        raise UserError(
            f"trainer.devices={devices}: several devices need a distributed strategy: add "
            f"trainer=ddp (or trainer.devices=1)"
        )


def check_accelerator(accelerator: Any, cuda_available: bool, trainer_choice: str | None = None) -> None:
    """Refuse a trainer asking for a CUDA GPU where there is none, naming ``trainer=gpu`` where that is
    ``trainer_choice`` (the trainer config chosen), else the accelerator."""
    if str(accelerator) not in CUDA_ACCELERATORS or cuda_available:
        return
    named = "trainer=gpu" if trainer_choice == "gpu" else f"trainer.accelerator={accelerator}"
    raise UserError(
        f"{named}: no CUDA GPU here (torch.cuda.is_available() is false): use trainer=default "
        f"to train on the CPU"
    )


ADDED_KEYS = {"train": ("evaluate",), "eval": ()}
"""Top-level keys a command reads that its config does not set, by config: training's ``+evaluate=false``."""

CONFIG_DIR = Path(__file__).resolve().parent.parent / "conf"


def _added_keys(overrides: Sequence[str], allowed: Sequence[str]) -> list[tuple[str, str]]:
    """(override, key) of each ``+key=...`` / ``++key=...`` adding a top-level key, no group."""
    added = []
    for text in overrides:
        match = re.match(r"\+\+?([A-Za-z_][\w-]*)=", text)
        if match and match.group(1) not in allowed and not (CONFIG_DIR / match.group(1)).is_dir():
            added.append((text, match.group(1)))
    return added


def dotted_keys(node: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """(dotted key, value) of each key of a plain config, its mappings' keys included, each before its own."""
    for key, value in node.items() if isinstance(node, Mapping) else ():
        yield f"{prefix}{key}", value
        yield from dotted_keys(value, f"{prefix}{key}.")


def check_added_keys(cfg: DictConfig, overrides: Sequence[str], config_name: str = "train") -> None:
    """Refuse a top-level key that a ``+key=value`` override adds and nothing reads (``+epochs=3``, which
    Hydra suggests for ``epochs=3``), naming the close keys there are and the top-level ones."""
    allowed = ADDED_KEYS.get(config_name, ())
    added = _added_keys(overrides, allowed)
    if not added:
        return
    rest = [o for o in overrides if o not in {text for text, _ in added}]
    base = compose(config_name, rest)
    for text, key in added:
        if key in base:
            continue
        known = sorted(str(k) for k in base)
        leaves: dict[str, str] = {}  # each key's last part -> its first dotted key
        for dotted, _ in dotted_keys(OmegaConf.to_container(base, resolve=False)):
            leaves.setdefault(dotted.rsplit(".", 1)[-1], dotted)
        close = [leaves[k] for k in difflib.get_close_matches(key, list(leaves), n=3)]
        hint = f" (did you mean {' or '.join(close)}?)" if close else ""
        extra = f" (and +{allowed[0]}=..., which no config sets)" if allowed else ""
        raise UserError(
            f"{text}: no key {key!r} is read{hint}; the top-level keys are {', '.join(known)}{extra}"
        )


def check_job(cfg: DictConfig, out_dir: Path, machine: bool = True) -> None:
    """A job's checks on its composed config (Hydra's node included), as in a job writing to ``out_dir``."""
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(out_dir)
    job = cfg.copy()
    with open_dict(job):
        del job.hydra
    hydra, previous = HydraConfig.instance(), HydraConfig.instance().cfg
    hydra.set_config(cfg)
    try:
        check_train_config(job, machine)
        check_added_keys(job, list(cfg.hydra.overrides.task))
    finally:
        hydra.cfg = previous


def sweep_jobs(overrides: list[str]) -> list[list[str]]:
    """Each job's overrides in a basic sweep of the command line's ``overrides`` (Hydra's own expansion)."""
    parsed = OverridesParser.create().parse_overrides(overrides)
    return [job for batch in BasicSweeper.split_arguments(parsed, None) for job in batch]


class SweepConfigCheck(Callback):
    """Before a sweep creates anything: where every job's config fails :func:`check_job`, end the sweep in
    that one line, exit status 2. Jobs are checked in order until one passes; an Optuna sweep checks its
    base config."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        basic = str(config.hydra.sweeper.get("_target_", "")).endswith("BasicSweeper")
        task = list(config.hydra.overrides.task)
        jobs = sweep_jobs(task) if basic else [task]
        out_dir = Path(str(config.hydra.sweep.dir)) / "check"
        first: UserError | None = None
        for overrides in jobs:
            try:
                cfg = compose(str(kwargs.get("config_name") or "train"), overrides, return_hydra_config=True)
                check_job(cfg, out_dir, machine=False)  # the GPU: GpuJobsCheck, where jobs run
                return
            except UserError as e:
                first = first or e
            except HydraException:  # a job that does not compose: Hydra says so when it runs
                return
        if first is not None:
            many = f" (every one of the sweep's {len(jobs)} jobs)" if len(jobs) > 1 else ""
            exit_in_one_line(UserError(f"{one_line(first)}{many}; nothing was created"))
