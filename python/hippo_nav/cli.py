"""Command line: `hippo-nav run` (the main job) and `hippo-nav figures` (the paper's theory figures)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hippo-nav", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser(
        "run",
        help="drive the spatial-memory network along a sequence (built-in synthetic demo when no dataset is given)",
    )
    run.add_argument("--kitti", metavar="ROOT", help="KITTI odometry root (holds sequences/ and poses/)")
    run.add_argument("--sequence", default="00", help="KITTI sequence number (default 00)")
    run.add_argument("--start", type=int, default=None, help="first frame")
    run.add_argument("--stop", type=int, default=None, help="frame to stop before")
    run.add_argument("--stride", type=int, default=1, help="use every n-th frame")
    run.add_argument(
        "--config", metavar="JSON", help="engine config file (unset fields: documented defaults)"
    )
    run.add_argument(
        "--lesion",
        action="append",
        default=[],
        choices=["ventral", "intermediate", "dorsal"],
        help="switch a grid module off (repeatable)",
    )
    run.add_argument("--out", default="runs/demo", help="results folder")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")

    figures = sub.add_parser("figures", help="write the paper's theory figures as PNG files")
    figures.add_argument("--out", default="runs/figures", help="folder for the PNG files")
    return parser


def _run(args: argparse.Namespace) -> int:
    from hippo_nav.engine import EngineConfig
    from hippo_nav.engine.job import run_engine_job

    if args.kitti is not None and not Path(args.kitti).is_dir():
        print(
            f"hippo-nav: error: --kitti {args.kitti}: no such folder (give the KITTI odometry root)",
            file=sys.stderr,
        )
        return 2
    config = EngineConfig()
    if args.config:
        config = EngineConfig.model_validate(json.loads(Path(args.config).read_text()))
    if args.lesion:
        config = config.with_lesions(**{name: True for name in args.lesion})
    metrics = run_engine_job(
        args.out,
        kitti_root=args.kitti,
        sequence=args.sequence,
        start=args.start,
        stop=args.stop,
        stride=args.stride,
        config=config,
        progress=not args.no_progress,
    )
    print(json.dumps(metrics, indent=2))
    print(f"results written to {args.out}")
    return 130 if metrics["interrupted"] else 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from hippo_nav import HippoNavError

    try:
        if args.command == "run":
            return _run(args)
        if args.command == "figures":
            from hippo_nav.theory.figures import write_all_figures

            write_all_figures(args.out)
            return 0
    except (HippoNavError, OSError, ValueError) as err:
        print(f"hippo-nav: error: {err}", file=sys.stderr)
        return 2
    return 2


if __name__ == "__main__":
    sys.exit(main())
