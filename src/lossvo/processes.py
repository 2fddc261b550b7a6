"""Child processes of a training or evaluation job: in a joblib "loky" worker (``hydra/launcher=joblib``)
the default start method is ``"loky"``, with which neither DataLoader workers nor spawned children start.
"""

from __future__ import annotations

import multiprocessing


def restore_start_method() -> str | None:
    """Make the platform's start method the default again where the current one is not a standard one;
    the start method set, or None."""
    standard = multiprocessing.get_all_start_methods()  # the platform's default first
    if multiprocessing.get_start_method(allow_none=True) in (None, *standard):
        return None
    multiprocessing.set_start_method(standard[0], force=True)
    return standard[0]
