"""What `hippo-nav sweep` costs over the same runs one after another (docs/sweep.md, "Overhead").

The same N runs of the demo loop (seeds 0 … N−1, figures off) three ways, interleaved round by round so that
all three see the same machine load:
- `sequential`: `hippo_nav.pipeline.run` for each run, one after another, in this process (the baseline: what
  a loop over `hippo-nav run` does, without its interpreter starts);
- `sweep, 1 at a time`: `run_sweep` with one run in flight (`--workers 1 --cpus-per-run 2`): Ray's start
  and stop, its worker processes, the manifests, and nothing gained from parallelism — the overhead itself;
- `sweep, 2 at a time`: `run_sweep` as a user on this machine would (`--workers 2 --cpus-per-run 1`).
Each sweep's wall time includes starting and stopping its local Ray, which is also timed on its own each round
(`ray start + stop`: `ray.init`, one task on each of two new workers importing the pipeline, `ray.shutdown`):
the fixed part of the overhead, which a longer sweep spreads over more runs. Ratios < 1: the sweep is faster.

    python tests/benchmarks/sweep_overhead.py [--runs 4] [--frames 200] [--rounds 2] [--out runs/sweep_overhead]

Not a test (no assertions; pytest does not collect it): a reproducible measurement.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import time
from pathlib import Path


def sequential(out: Path, runs: int, frames: int) -> float:
    from hippo_nav.pipeline import config_from_dict, run

    clock = time.perf_counter()
    for seed in range(runs):
        config = config_from_dict({"seed": seed, "output": {"figures": False}})
        run(out / f"s{seed}", stop=frames, config=config, progress=False, overwrite=True)
    return time.perf_counter() - clock


def sweep(out: Path, runs: int, frames: int, workers: int, cpus_per_run: int) -> float:
    from hippo_nav.sweep import SweepOptions, build_space, run_sweep

    space = build_space(seeds=f"0-{runs - 1}", dataset={"stop": frames}, no_figures=True)
    clock = time.perf_counter()
    summary = run_sweep(
        space,
        out,
        SweepOptions(workers=workers, cpus_per_run=cpus_per_run, progress=False),
        echo=lambda _: None,
    )
    wall = time.perf_counter() - clock
    if summary.done != runs:
        raise SystemExit(f"the sweep ended with {summary.done} of {runs} runs done: {summary.failed}")
    return wall


def ray_start_stop() -> float:
    import logging

    import ray

    clock = time.perf_counter()
    ray.init(
        address="local",
        num_cpus=2,
        include_dashboard=False,
        log_to_driver=False,
        logging_level=logging.WARNING,
    )
    task = ray.remote(num_cpus=1)(_import_pipeline)
    ray.get([task.remote() for _ in range(2)])
    ray.shutdown()
    return time.perf_counter() - clock


def _import_pipeline() -> None:
    import importlib

    for module in (
        "hippo_nav.pipeline",
        "hippo_nav.sweep.worker",
    ):  # what a worker loads before its first run
        importlib.import_module(module)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=4)
    parser.add_argument("--frames", type=int, default=200, help="frames of the demo loop per run (200: all)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("runs/sweep_overhead"))
    args = parser.parse_args(argv)
    from hippo_nav.synthetic import demo_sequence

    demo_sequence()  # rendered (or found) once, before anything is timed
    ways = {
        "ray start + stop": lambda out: ray_start_stop(),
        "sequential": lambda out: sequential(out, args.runs, args.frames),
        "sweep, 1 at a time": lambda out: sweep(out, args.runs, args.frames, workers=1, cpus_per_run=2),
        "sweep, 2 at a time": lambda out: sweep(out, args.runs, args.frames, workers=2, cpus_per_run=1),
    }
    walls: dict[str, list[float]] = {name: [] for name in ways}
    for round_index in range(args.rounds):
        for k, (name, measure) in enumerate(ways.items()):
            out = args.out / f"round{round_index}_{k}"
            shutil.rmtree(out, ignore_errors=True)
            walls[name].append(measure(out))
            print(f"round {round_index}: {name}: {walls[name][-1]:.1f} s", flush=True)
    base = statistics.median(walls["sequential"])
    print(f"\n{args.runs} runs of {args.frames} demo frames, {args.rounds} rounds (median wall time):\n")
    print("| way | wall (s), each round | median (s) | against sequential |")
    print("|---|---|---|---|")
    for name, values in walls.items():
        median = statistics.median(values)
        if name == "ray start + stop":
            print(f"| {name} (no runs) | {', '.join(f'{v:.1f}' for v in values)} | {median:.1f} | – |")
            continue
        print(f"| {name} | {', '.join(f'{v:.1f}' for v in values)} | {median:.1f} | {median / base:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
