"""Training: the LightningModule, callbacks, the fit and a run's life in its folder (docs/training.md)."""
