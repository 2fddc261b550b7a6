"""``python -m lossvo.train [overrides]``: train a VO network, sweeps with ``-m``.

Examples::

    python -m lossvo.train                                   # chordal loss, embedded synthetic data
    python -m lossvo.train -m loss=euler,quat,chordal        # the study's three-way comparison
    python -m lossvo.train -m loss=euler,quat,chordal seed=0,1,2 hydra/launcher=joblib
    python -m lossvo.train experiment=paper data.sources.kitti.root=/data/kitti trainer=gpu

A run writes to ``outputs/runs/<time>/``, a sweep job to ``outputs/multirun/<time>/<num>_<overrides>/``
(docs/training.md); the run's life: :mod:`lossvo.training.lifecycle`; its training: ``fitting``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import hydra
from omegaconf import DictConfig

from lossvo import output_folders
from lossvo.console import one_line_errors, quiet_lightning
from lossvo.data.specs import refusing_scalar_specs
from lossvo.processes import restore_start_method
from lossvo.training import fitting, lifecycle, resolvers

log = logging.getLogger("lossvo")

resolvers.register()  # at import: a launcher's worker process unpickles main and composes configs there

CONFIG_DIR = str(Path(__file__).resolve().parent / "conf")


@one_line_errors
@output_folders.leaving_as_found
@resolvers.names_swept_jobs
@refusing_scalar_specs
@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="train")
def main(cfg: DictConfig) -> float | None:
    """Train in this Hydra job's folder; returns ``cfg.optimized_metric`` for hyperparameter sweepers."""
    quiet_lightning()
    restore_start_method()  # a joblib-launched job: let its loader workers and renderer start
    with lifecycle.job(cfg) as run:
        if run.completed is None:
            log.info("%s: preparing the data and the network", run.label)
            fitting.train(cfg, run)
    return run.optimized_metric()


if __name__ == "__main__":
    main()
