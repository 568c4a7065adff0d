"""Command line: `hippo-nav run` (the main job) and `hippo-nav figures` (the paper's theory figures)."""

from __future__ import annotations

import argparse
import sys


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hippo-nav", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run the cognitive-mapping system (built-in demo when no dataset is given)")
    run.add_argument("--out", default="runs/demo", help="results folder")

    figures = sub.add_parser("figures", help="write the paper's theory figures as PNG files")
    figures.add_argument("--out", default="runs/figures", help="folder for the PNG files")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "run":
        from hippo_nav.demo import run_demo

        return run_demo(args)
    if args.command == "figures":
        from hippo_nav.theory.figures import write_all_figures

        write_all_figures(args.out)
        return 0
    return 2


if __name__ == "__main__":
    sys.exit(main())
