"""Several Optuna workers on one study: errors, duplicate parameter sets and trial numbers, and time.

Run: ``.venv/bin/python benchmarks/optuna_workers.py --storage sqlite:////tmp/bench.db --workers 4``
(``--storage mysql+pymysql://USER:PASSWORD@localhost/DB`` for MariaDB: a new study per run; the database
must exist; ``--storage /tmp/bench.log``: a journal file). ``--workers`` processes start together and each
runs ``--trials`` ask/tell trials of ``--seconds`` each on a study of two log-uniform parameters, through
lossvo's storage, heartbeats, stale-trial check and sampler (:mod:`lossvo.training.shared_study`) as
``hparams_search=k_search`` does, or with ``--sampler tpe`` through Optuna's TPE seeded alike in every
worker. Prints the trials, how many finished in each state, the duplicate parameter sets and trial numbers,
the errors the workers met and the wall time.
"""

from __future__ import annotations

import argparse
import multiprocessing
import time
import traceback
import uuid
from collections import Counter

import optuna

from lossvo.training.shared_study import Heartbeats, TrialSeededTPESampler, fail_stale_trials, open_storage


def worker(url: str, study_name: str, sampler: str, trials: int, seconds: float, errors: list[str]) -> None:
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        storage = open_storage(url)
        heartbeats = Heartbeats(1.0)
        chosen = TrialSeededTPESampler(seed=0) if sampler == "lossvo" else optuna.samplers.TPESampler(seed=0)
        study = optuna.create_study(
            study_name=study_name, storage=storage, sampler=chosen, load_if_exists=True
        )
    except Exception:
        errors.append(traceback.format_exc().strip().splitlines()[-1])
        return
    for _ in range(trials):
        try:
            fail_stale_trials(study, grace_period=30.0)
            trial = study.ask()
            heartbeats.add(trial)
            k = trial.suggest_float("k", 5.0, 2000.0, log=True)
            lr = trial.suggest_float("lr", 1e-4, 3e-3, log=True)
            time.sleep(seconds)
            heartbeats.discard(trial)
            study.tell(trial, (k - 100.0) ** 2 * lr)
        except Exception:
            errors.append(traceback.format_exc().strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--storage", required=True)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=0.05, help="each trial's objective (sleep)")
    parser.add_argument("--sampler", choices=("lossvo", "tpe"), default="lossvo")
    args = parser.parse_args()
    study_name = f"bench-{uuid.uuid4().hex[:8]}"
    open_storage(args.storage)  # the tables (or the journal file), before the workers race to make them
    with multiprocessing.Manager() as manager:
        errors = manager.list()
        procs = [multiprocessing.Process(target=worker, args=(args.storage, study_name, args.sampler,
                                                              args.trials, args.seconds, errors))
                 for _ in range(args.workers)]  # fmt: skip
        start = time.perf_counter()
        for proc in procs:
            proc.start()
        for proc in procs:
            proc.join()
        wall = time.perf_counter() - start
        errors = list(errors)
    trials = optuna.load_study(study_name=study_name, storage=open_storage(args.storage)).trials
    params = Counter(tuple(sorted(t.params.items())) for t in trials)
    numbers = Counter(t.number for t in trials)
    states = Counter(t.state.name for t in trials)
    duplicates = sum(c - 1 for c in params.values())
    kind = args.storage.split(":")[0] if "://" in args.storage else "journal"
    print(f"{args.workers} workers x {args.trials} trials, sampler {args.sampler}, {kind}: "
          f"{len(trials)} trials {dict(states)}, duplicate parameter sets {duplicates}, "
          f"duplicate numbers {sum(c - 1 for c in numbers.values())}, errors {len(errors)} "
          f"{dict(Counter(errors))}, wall {wall:.1f} s")  # fmt: skip


if __name__ == "__main__":
    main()
