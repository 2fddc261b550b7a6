"""Child processes of a training or evaluation job.

A job that Hydra's joblib launcher runs (``hydra/launcher=joblib``, parallel sweeps) lives in a joblib
"loky" worker, where multiprocessing's default start method is ``"loky"``. Neither DataLoader workers
(which use the default context) nor spawned children (which inherit the parent's start method by name
and do not know ``"loky"``, e.g. the synthetic renderer's process pool) can start there.
"""

from __future__ import annotations

import multiprocessing


def restore_start_method() -> str | None:
    """Make the platform's start method the default again if the current one is not a standard one.

    Returns:
        The start method set (``"fork"`` on Linux before Python 3.14), or None if nothing changed.
    """
    standard = multiprocessing.get_all_start_methods()  # the platform's default first
    if multiprocessing.get_start_method(allow_none=True) in (None, *standard):
        return None
    multiprocessing.set_start_method(standard[0], force=True)
    return standard[0]
