"""Training: the LightningModule (:mod:`~lossvo.training.module`), the selection score
(:mod:`~lossvo.training.selection`), callbacks, the fit (:mod:`~lossvo.training.fitting`), the run's
life in its job folder (:mod:`~lossvo.training.lifecycle`) and ``metrics.csv``
(:mod:`~lossvo.training.metrics_log`).
The command line is :mod:`lossvo.train`."""
