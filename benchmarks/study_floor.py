"""A study's compute floor on this CPU, and a measured wall time's ratio to it.

Run: ``.venv/bin/python benchmarks/study_floor.py [--wall SECONDS] [STUDY ARGUMENTS]``, the arguments of
``python -m lossvo.study`` (``--seeds``, ``--models``, ``--experiments``, overrides). The floor is the
floating-point operations of every training step and pair inference of the study's jobs
(``torch.utils.flop_counter.FlopCounterMode`` over one training step, forward, loss and backward, and over one
inference pass: matrix products and convolutions), done at the rate the study's timed calibration steps reach
(FLOPs of a step / its time), on all the cores its jobs use. Run it on an idle machine: the calibration is the
machine's rate at that moment. ``--wall``: the study's wall time (its last line), printed as a ratio.
"""

from __future__ import annotations

import argparse

import joblib
from omegaconf import DictConfig
from torch.utils.flop_counter import FlopCounterMode

from lossvo import study
from lossvo.evaluation.inference import predict_sequence


def step_flops(cfg: DictConfig) -> float:
    """FLOPs of one training step (forward, loss, backward) on a batch of the config's shape."""
    module = study.job_module(cfg)
    batch = study.random_batch(cfg, int(cfg.data.windows.batch_size), int(cfg.data.windows.seq_len))
    with FlopCounterMode(display=False) as counter:
        module.loss(module(batch), batch["targets"], None)["loss"].backward()
    return float(counter.get_total_flops())


def pair_flops(cfg: DictConfig) -> float:
    """FLOPs of a frame pair in an inference pass (:func:`lossvo.evaluation.inference.predict_sequence`)."""
    inputs = study.inference_inputs(cfg)
    with FlopCounterMode(display=False) as counter:
        predict_sequence(study.job_module(cfg), inputs, lambda loaded: loaded, int(cfg.data.windows.seq_len))
    return counter.get_total_flops() / (len(inputs["frames"]) - 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--wall", type=float, default=None, help="the study's wall time, seconds")
    args, rest = parser.parse_known_args()
    plan_args = study.parser().parse_args(rest)
    plan = study.plan_study(plan_args, False, 0.0, study.sweep_dir_of(plan_args))
    threads = max(joblib.cpu_count() // plan.at_once, 1)
    cores = min(joblib.cpu_count(), plan.at_once * threads)
    train = infer = seconds = 0.0
    for configuration in plan.configurations:
        cfg = study.compose_job(configuration, plan.losses[0], plan.overrides)
        size, rate, jobs = (
            study.job_size(cfg),
            study.calibrate(cfg, threads),
            len(plan.seeds) * len(plan.losses),
        )
        step, pair = step_flops(cfg), pair_flops(cfg)
        work = jobs * (size.steps * step + size.inferred_pairs * pair)
        train, infer = train + jobs * size.steps * step, infer + jobs * size.inferred_pairs * pair
        seconds += work / (step / rate.step_s) / cores
        print(f"{configuration}: {step / rate.step_s / 1e9:.1f} GFLOP/s a core ({threads} threads a job)")
    print(f"floor {seconds:,.0f} s: {(train + infer) / 1e12:.1f} TFLOP (training {train / 1e12:.1f}, "
          f"inference {infer / 1e12:.1f}) on {cores} cores")  # fmt: skip
    if args.wall is not None:
        print(f"wall {args.wall:,.0f} s: {args.wall / seconds:.2f}x the floor")


if __name__ == "__main__":
    main()
