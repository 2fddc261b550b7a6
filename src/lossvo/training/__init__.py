"""Training: the LightningModule (:mod:`~lossvo.training.module`), the selection score
(:mod:`~lossvo.training.selection`), callbacks, checkpoints as the contract with evaluation
(:mod:`~lossvo.training.checkpoints`) and the ``python -m lossvo.train`` entry
(:mod:`~lossvo.training.train`)."""
