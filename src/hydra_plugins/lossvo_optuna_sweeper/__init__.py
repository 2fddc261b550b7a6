"""lossvo's Optuna sweeper for Hydra (``hydra/sweeper=lossvo_optuna``): :mod:`.optuna_sweeper`."""
