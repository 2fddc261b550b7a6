"""Child processes from inside a joblib (loky) worker, as in a `hydra/launcher=joblib` sweep job."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor

from joblib.externals.loky import get_reusable_executor

from lossvo.processes import restore_start_method


def _square(x: int) -> int:
    return x * x


def _spawn_child(restore: bool) -> tuple[str | None, str | None, str]:
    """In a loky worker: the start method found, what was restored, and the outcome of running a
    spawned child process."""
    found = multiprocessing.get_start_method(allow_none=True)
    restored = restore_start_method() if restore else None
    try:
        with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
            return found, restored, f"ok {pool.submit(_square, 7).result()}"
    except Exception as e:  # the failure this module exists for
        return found, restored, type(e).__name__


def in_fresh_loky_worker(restore: bool) -> tuple[str | None, str | None, str]:
    """Run :func:`_spawn_child` in a new joblib (loky) worker process, as Hydra's joblib launcher does."""
    return get_reusable_executor(max_workers=1, reuse=False).submit(_spawn_child, restore).result()


def test_spawned_children_start_inside_a_joblib_worker_once_restored() -> None:
    found, restored, outcome = in_fresh_loky_worker(restore=True)
    assert found == "loky" and restored == multiprocessing.get_all_start_methods()[0]
    assert outcome == "ok 49"


def test_without_restoring_a_spawned_child_fails_inside_a_joblib_worker() -> None:
    # The reference for the test above: the problem is real, not an artefact of the test.
    found, restored, outcome = in_fresh_loky_worker(restore=False)
    assert found == "loky" and restored is None and outcome == "BrokenProcessPool"


def test_nothing_changes_in_an_ordinary_process() -> None:
    before = multiprocessing.get_start_method(allow_none=True)
    assert restore_start_method() is None
    assert multiprocessing.get_start_method(allow_none=True) == before
