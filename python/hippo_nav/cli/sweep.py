"""`hippo-nav sweep`: many runs over a cross-product of settings, on Ray (docs/sweep.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from hippo_nav.cli.common import (
    MAX_RETRIES,
    MAX_THREADS,
    add_input_flags,
    add_replay_flags,
    bounded_int,
    loader_options,
)

HELP = "run the pipeline over a cross-product of settings × seeds × sequences × odometries, on Ray"
DESCRIPTION = (
    "Runs `hippo-nav run` for every combination of the axes (from the command line and/or a "
    "TOML/YAML sweep file, docs/sweep.md) on Ray: on this machine by default, or on a cluster with "
    "--address. Each run writes its results folder and manifest.json into OUT/runs/<id>/. Rerunning the "
    "same command skips finished runs and reruns interrupted ones; a failing run is listed and never "
    "stops the others; Ctrl-C, SIGTERM and SIGHUP stop cleanly (the runs in flight write what they did). "
    "At most 10000 runs. Exit 0: every run done; 1: some failed; 2: bad input; 130/143/129: interrupted by "
    "SIGINT/SIGTERM/SIGHUP. Needs pip install 'hippo-nav[sweep]'."
)


def add_arguments(sweep: argparse.ArgumentParser) -> None:
    """`hippo-nav sweep`: the space (a file and/or axes), `run`'s input flags, and how the runs execute."""
    _add_space(
        sweep.add_argument_group("the space (the command line replaces a file's axis of the same name)")
    )
    # The sequence is an axis of the space; stride None: a sweep file's stride stands unless one is given.
    add_input_flags(sweep.add_argument_group("input (as in run)"), stride_default=None, sequence=False)
    setup = sweep.add_argument_group("configuration")
    setup.add_argument(
        "--config", metavar="JSON", help="base config file every run starts from (default: none)"
    )
    setup.add_argument("--no-figures", action="store_true", help="skip every run's figures")
    _add_execution(sweep.add_argument_group("execution"))
    sweep.add_argument(
        "--out", default=None, help="sweep folder (default: runs/<sweep file name>, or runs/sweep)"
    )


def _add_space(space: argparse._ArgumentGroup) -> None:

    space.add_argument(
        "file", nargs="?", metavar="SWEEP_FILE", help="sweep file (.toml, .yaml) (default: none)"
    )
    space.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=V1,V2",
        help="a config key and its values (JSON where they parse: true, 0.4, [0,10]), e.g. "
        "views.novelty_threshold=0.40,0.45 or lesions.dorsal=true,false (repeatable)",
    )
    space.add_argument("--seeds", metavar="0-4", help="seeds: 0-4, 0,3,7 (default: the config's seed)")
    space.add_argument(
        "--lesion",
        metavar="COND,…",
        help="lesion conditions: none, ventral, intermediate, dorsal, a+b (default: none)",
    )
    space.add_argument(
        "--sequence", metavar="SEQ,…", help="sequences of --dataset, e.g. 00,05 (default: its default)"
    )
    space.add_argument(
        "--odometry", metavar="vo,drift,FILE", help="odometries: vo (built-in), drift (the ground truth drifted "
        "1 %%), a trajectory file replayed as with run --odometry (default: vo)",
    )  # fmt: skip
    add_replay_flags(space, "the files", "a KITTI file's")


def _add_execution(execution: argparse._ArgumentGroup) -> None:
    execution.add_argument(
        "--address", metavar="auto|HOST:PORT", default=None,
        help="join a running Ray cluster (`ray start --head`; docs/sweep.md); gives up after 10 s when nothing "
        "answers at HOST:PORT (default: none, Ray on this machine)",
    )  # fmt: skip
    execution.add_argument(
        "--cpus-per-run", type=bounded_int(1, MAX_THREADS), default=1, metavar="N",
        help="CPUs each run is declared to Ray, and the size of its thread pools (a demo run keeps about one "
        "core busy: 0.95-1.06 cores measured)",
    )  # fmt: skip
    execution.add_argument(
        "--workers", type=bounded_int(1, MAX_THREADS), default=None, metavar="N",
        help="without --address: runs at a time on this machine (default: its cores / --cpus-per-run)",
    )  # fmt: skip
    execution.add_argument(
        "--retries", type=bounded_int(0, MAX_RETRIES), default=2, help="restarts of a run whose worker died"
    )
    execution.add_argument(
        "--retry-failed", action="store_true", help="run the runs that failed before again"
    )
    execution.add_argument(
        "--dry-run", action="store_true", help="list the runs and what would be done; run nothing"
    )
    execution.add_argument("--no-progress", action="store_true", help="no progress bar")


def command(args: argparse.Namespace) -> int:
    import sys

    from hippo_nav.sweep.scheduler import exit_status, signal_name, stop_signals

    # SIGINT, SIGTERM and SIGHUP stop every stage alike, validation and Ray's start included.
    try:
        with stop_signals():
            return _sweep(args)
    except KeyboardInterrupt as err:  # before any run started (a stop during the runs ends in `_sweep`)
        name = signal_name(err)
        print(
            f"hippo-nav: interrupted ({name}) before any run started; nothing was lost: rerun the same command",
            file=sys.stderr,
        )
        return exit_status(name)


def _sweep(args: argparse.Namespace) -> int:
    import sys

    from hippo_nav.sweep import SweepOptions, build_space, run_sweep
    from hippo_nav.sweep.scheduler import describe, dry_run

    if len(args.dataset_flags) > 1:
        from hippo_nav._core import HippoNavError

        raise HippoNavError(f"give one dataset path: {' and '.join(args.dataset_flags)} name the same option")
    flags = {"dataset": args.dataset, "dataset_kind": args.dataset_kind, "start": args.start, "stop": args.stop,
             "stride": args.stride, **loader_options(args)}  # fmt: skip
    space = build_space(
        args.file, sets=args.set, seeds=args.seeds, lesions=args.lesion, sequences=args.sequence,
        odometries=args.odometry, odometry_format=args.odometry_format, odometry_align=args.odometry_align,
        config=args.config, dataset=flags, no_figures=args.no_figures,
    )  # fmt: skip
    out = args.out or space.out or (f"runs/{Path(args.file).stem}" if args.file else "runs/sweep")

    if args.dry_run:  # stdout is the plan; what takes a while is said on stderr
        tell = lambda line: print(f"hippo-nav: {line}", file=sys.stderr)
        print("\n".join(dry_run(space, out, args.retry_failed, echo=tell)))
        return 0
    options = SweepOptions(
        address=args.address, cpus_per_run=args.cpus_per_run, workers=args.workers, retries=args.retries,
        retry_failed=args.retry_failed, progress=not args.no_progress,
    )  # fmt: skip
    summary = run_sweep(space, out, options)
    print(describe(summary))
    return summary.exit_status
