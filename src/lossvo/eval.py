"""``python -m lossvo.eval``: evaluate a checkpoint (Hydra, ``lossvo/conf/eval.yaml``)::

    python -m lossvo.eval ckpt_path=outputs/multirun/<time>/0_loss-euler+seed-0/checkpoints/best.ckpt
    python -m lossvo.eval ckpt_path=... data=kitti data.sources.kitti.root=/data/kitti \
        data.splits.test=[09,10]

The checkpoint's training data is evaluated unless ``data=...`` or ``data.KEY=...`` chooses otherwise
(:mod:`lossvo.evaluation.checkpoints`); the output folder receives what
:func:`lossvo.evaluation.results.evaluate_run` writes (docs/training.md).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, cast

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import DictConfig, OmegaConf

from lossvo import output_folders
from lossvo.console import (
    UserError,
    end_in_one_line,
    full_error,
    log_to_files,
    one_line_errors,
    quiet_lightning,
    remove_refused,
    user_message,
)
from lossvo.data.sequence import sequence_names
from lossvo.data.specs import refusing_scalar_specs
from lossvo.evaluation import checkpoints
from lossvo.evaluation.job_folder import Results
from lossvo.evaluation.metrics import ALIGN_MODES, is_rpe_delta
from lossvo.evaluation.results import evaluate_run
from lossvo.processes import restore_start_method
from lossvo.training.config_checks import (
    check_added_keys,
    check_checkpoint_path,
    check_source_roots,
    check_values,
    instantiate_checked,
    resolved_config,
)

log = logging.getLogger("lossvo")

CONFIG_DIR = str(Path(__file__).resolve().parent / "conf")

SCALARS: tuple[tuple[str, Callable[[Any], bool], str], ...] = (
    ("align", lambda v: v in ALIGN_MODES, f"one of {', '.join(ALIGN_MODES)}"),
    ("delta", is_rpe_delta, "an integer >= 1 (frames)"),
    ("carry_state", lambda v: isinstance(v, bool), "true or false"),
    ("mirror_average", lambda v: isinstance(v, bool), "true or false"),
)
"""(key, test, what is expected) of the scalar settings checked (:func:`check_values`)."""


def check_config(cfg: Any) -> None:
    """``UserError`` for a config of ``python -m lossvo.eval`` that would fail after the checkpoint loads."""
    if OmegaConf.is_missing(cfg, "ckpt_path"):
        raise UserError("ckpt_path is required: python -m lossvo.eval ckpt_path=PATH")
    resolved_config(cfg)  # an interpolation that does not resolve: one line naming its key
    check_added_keys(cfg, list(HydraConfig.get().overrides.task), "eval")
    check_checkpoint_path(Path(str(cfg.ckpt_path)))
    check_source_roots(cfg.get("data"))
    check_values(cfg, SCALARS)
    device = cfg.get("device", "auto")
    if device != "auto":
        try:
            kind = torch.device(str(device)).type
        except RuntimeError:
            raise UserError(f"device: expected auto, cpu, cuda or cuda:N, got {device!r}") from None
        if kind == "cuda" and not torch.cuda.is_available():
            raise UserError(f"device: {device!r}, but CUDA is not available here (expected auto or cpu)")


def data_overrides(overrides: Sequence[str]) -> tuple[bool, list[str]]:
    """From command-line overrides: whether a data config was chosen (``data=kitti``) and the data keys
    set, dotted below ``data`` (``data.frames.cache_dir=...`` gives ``frames.cache_dir``)."""
    keys = [o.key_or_group for o in OverridesParser.create().parse_overrides(list(overrides))]
    data = [key.removeprefix("data.") for key in keys if key.startswith("data.")]
    return "data" in keys, list(dict.fromkeys(data))


def run(cfg: Any, out_dir: Path, overrides: Sequence[str] = ()) -> Results:
    """Load the checkpoint, build the data it describes (with the command line's data ``overrides``) and
    evaluate the test and unseen-motion sequences."""
    name = str(cfg.get("device", "auto"))
    auto = "cuda" if torch.cuda.is_available() else "cpu"
    network = checkpoints.load_network(cfg.ckpt_path, torch.device(auto if name == "auto" else name))
    chosen, keys = data_overrides(overrides)
    given = cast("dict[str, Any]", OmegaConf.to_container(cfg.data, resolve=True))
    recorded = checkpoints.recorded_data(cfg.ckpt_path, network)
    explicit = {k: checkpoints.lookup(given, k) for k in keys}
    data_cfg = checkpoints.evaluation_data(recorded, given if chosen else None, explicit)
    datamodule = instantiate_checked(data_cfg, _convert_="all")
    datamodule.prepare_data()
    datamodule.setup("test")
    sequences = sequence_names(cfg.sequences if cfg.get("sequences") else datamodule.evaluated)
    available = list(getattr(datamodule, "sequences", None) or sequences)
    unknown = [s for s in sequences if s not in available]
    if unknown:
        raise UserError(
            f"sequences: {unknown[0]!r} is not a sequence of the evaluated data (expected one "
            f"of {', '.join(available)}; data.splits.test=[...] chooses them)"
        )
    return evaluate_run(
        network,
        datamodule,
        out_dir,
        sequences,
        checkpoint=Path(cfg.ckpt_path).resolve(),
        align=cfg.get("align", "none"),
        delta=int(cfg.get("delta", 1)),
        carry_state=bool(cfg.get("carry_state", False)),
        threads=network.threads,
        mirror_average=bool(cfg.get("mirror_average", False)),
    )


@one_line_errors
@output_folders.leaving_as_found
@refusing_scalar_specs
@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="eval")
def main(cfg: DictConfig) -> None:
    """Evaluate ``cfg.ckpt_path`` into this Hydra job's folder; bad input leaves no output folder behind."""
    quiet_lightning()
    restore_start_method()  # a joblib-launched job: let its loader workers start
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    try:
        check_config(cfg)
        result = run(cfg, out_dir, HydraConfig.get().overrides.task)
    except Exception as e:  # in the job: Hydra would print a line of its own before a raised error's
        message = user_message(e, out_dir)
        if message is not None and not full_error():
            log_to_files(log, message)
        if message is not None and output_folders.was_empty(out_dir):
            made = {".hydra", f"{HydraConfig.get().job.name}.log"}
            remove_refused(out_dir, made, keep_folder=output_folders.existed(out_dir))
        end_in_one_line(e, out_dir)
        raise
    overall = result.overall
    if overall.scores is not None:
        names = ", ".join(overall.sequences)
        ape, rpe = overall.scores.ape.trans.rmse, overall.scores.rpe.trans.rmse
        log.info("overall (%s): APE trans RMSE %.4g m, RPE trans RMSE %.4g m", names, ape, rpe)
    log.info("results: %s", out_dir / "results.json")


if __name__ == "__main__":
    main()
