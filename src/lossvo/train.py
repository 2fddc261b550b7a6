"""``python -m lossvo.train [overrides]``: train a VO network, sweeps with ``-m``.

Examples::

    python -m lossvo.train                                   # chordal loss, embedded synthetic data
    python -m lossvo.train -m loss=euler,quat,chordal        # the study's three-way comparison
    python -m lossvo.train -m loss=euler,quat,chordal seed=0,1,2 hydra/launcher=joblib
    python -m lossvo.train experiment=paper data.sources.kitti.root=/data/kitti trainer=gpu

A run writes to ``outputs/runs/<time>/``, a sweep job to ``outputs/multirun/<time>/<num>_<overrides>/`` (what
a job folder holds: docs/training.md; ``+evaluate=false`` and ``trainer.fast_dev_run`` skip the final
evaluation). A run's life in its folder: :mod:`lossvo.training.lifecycle`; what it builds and trains:
:mod:`lossvo.training.fitting`.
"""

from __future__ import annotations

import logging
from pathlib import Path

import hydra
from omegaconf import DictConfig

from lossvo import output_folders
from lossvo.console import one_line_errors, quiet_lightning
from lossvo.data.specs import refusing_flat_keys
from lossvo.processes import restore_start_method
from lossvo.training import fitting, lifecycle, resolvers

log = logging.getLogger("lossvo")

resolvers.register()  # at import: a launcher's worker process unpickles main and composes configs there

CONFIG_DIR = str(Path(__file__).resolve().parent / "conf")


@one_line_errors
@output_folders.leaving_as_found
@resolvers.names_swept_jobs
@refusing_flat_keys
@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="train")
def main(cfg: DictConfig) -> float | None:
    """Train in this Hydra job's folder; returns ``cfg.optimized_metric`` for hyperparameter sweepers.

    A user error (a config value, a data file, a checkpoint that does not fit, a full or read-only disk)
    ends the job in one line with exit status 2, before anything is written where the config alone
    tells; ``LOSSVO_FULL_ERROR=1`` shows its traceback instead. In a sweep the other jobs go on.
    """
    quiet_lightning()
    restore_start_method()  # a joblib-launched job: let its loader workers and renderer start
    with lifecycle.job(cfg) as run:
        if run.completed is None:
            log.info("%s: preparing the data and the network", run.label)
            fitting.train(cfg, run)
    return run.optimized_metric()


if __name__ == "__main__":
    main()
