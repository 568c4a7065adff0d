"""Command line: `hippo-nav run` (the main job: the SLAM pipeline), `hippo-nav render` (a synthetic stereo
street along a KITTI ground truth), `hippo-nav figures` (the paper's theory figures, or with --appearance
the synthetic street at each appearance level), `hippo-nav vocabulary` (the word view cells' vocabulary,
trained on a folder of images or remade from the renders), `hippo-nav sweep` (many runs over a cross-product
of settings, on Ray) and `hippo-nav report` (one table and figures over sweeps and runs).

Exit codes: 0 done; 2 bad input (one line on stderr saying what to fix; nothing is processed) or a frame
that cannot be read mid-run (the results of the frames before it are written); 130 interrupted by Ctrl-C,
143 by SIGTERM, 129 by SIGHUP (128 + the signal number; the results of the frames processed so far are
written)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from types import ModuleType
from typing import NoReturn

from hippo_nav.cli import figures, render, report, run, sweep, vocabulary
from hippo_nav.cli.common import HelpFormatter

_COMMANDS: dict[str, ModuleType] = {
    "run": run,
    "render": render,
    "figures": figures,
    "vocabulary": vocabulary,
    "sweep": sweep,
    "report": report,
}
"""The commands in the order of the help, each a module with `HELP`, `DESCRIPTION`, `add_arguments(parser)` and
`command(args) -> int`."""


class _Parser(argparse.ArgumentParser):
    """argparse, but a bad option is one line like every other bad input (not the whole usage first)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="hippo-nav", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--version", action="version", version=f"hippo-nav {_version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    for name, module in _COMMANDS.items():
        command = sub.add_parser(
            name, help=module.HELP, description=module.DESCRIPTION, formatter_class=HelpFormatter
        )
        module.add_arguments(command)
    return parser


def _version() -> str:
    from hippo_nav._core import __version__

    return __version__


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as stop:  # --help, --version (0) or a bad option (2: argparse printed the one line)
        return stop.code if isinstance(stop.code, int) else 2
    import logging

    from hippo_nav._core import HippoNavError

    # Per-frame warnings (VO failures, clamped motion) go to stderr, one line each.
    logging.basicConfig(level=logging.WARNING, format="hippo-nav: %(message)s")

    command: Callable[[argparse.Namespace], int] = _COMMANDS[args.command].command
    try:
        return command(args)
    except HippoNavError as err:
        # Bad input: one line saying what to fix. Anything else is a bug and keeps its traceback.
        print(f"hippo-nav: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:  # a file that cannot be read or written: in words, naming it (no "[Errno N]")
        from hippo_nav.io.errors import os_error_words

        print(f"hippo-nav: error: {os_error_words(err)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # before the pipeline started (e.g. while rendering the demo)
        print("hippo-nav: interrupted", file=sys.stderr)
        return 130


__all__ = ["build_parser", "main"]
