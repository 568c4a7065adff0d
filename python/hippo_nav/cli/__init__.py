"""Command line: `hippo-nav run` (the main job: the SLAM pipeline), `hippo-nav render` (a synthetic stereo
street along a KITTI ground truth), `hippo-nav figures` (the paper's theory figures, or with --appearance
the synthetic street at each appearance level), `hippo-nav vocabulary` (the word view cells' vocabulary,
trained on a folder of images or remade from the renders), `hippo-nav sweep` (many runs over a cross-product
of settings, on Ray), `hippo-nav report` (one table and figures over sweeps and runs), `hippo-nav record` (an
open-field session of the networks, recorded and measured as a lab would) and `hippo-nav config`
(the default config as JSON, a config file checked without running or shown resolved).

Exit codes: 0 done; 2 bad input (one line on stderr saying what to fix; nothing is processed) or a frame
that cannot be read mid-run (the results of the frames before it are written); 130 interrupted by Ctrl-C,
143 by SIGTERM, 129 by SIGHUP (128 + the signal number; the results of the frames processed so far are
written). With `run --json`, stdout holds one JSON object whatever the exit code (`exit_code`,
`exit_reason`; bad input: `{"exit_code": 2, "exit_reason": "error", "error": …}`), or nothing when the
command line itself cannot be parsed."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from types import ModuleType
from typing import NoReturn

from hippo_nav.cli import config, figures, record, render, report, run, sweep, vocabulary
from hippo_nav.cli.common import HelpFormatter

_COMMANDS: dict[str, ModuleType] = {
    "run": run,
    "render": render,
    "figures": figures,
    "vocabulary": vocabulary,
    "sweep": sweep,
    "report": report,
    "record": record,
    "config": config,
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
    as_json = getattr(args, "json", False)  # `run --json`: stdout is one JSON object, whatever happens
    try:
        return command(args)
    except HippoNavError as err:
        # Bad input: one line saying what to fix. Anything else is a bug and keeps its traceback.
        return _failed(str(err), as_json)
    except OSError as err:  # a file that cannot be read or written: in words, naming it (no "[Errno N]")
        from hippo_nav.io.errors import os_error_words

        return _failed(os_error_words(err), as_json)
    except KeyboardInterrupt:  # before the pipeline started (e.g. while rendering the demo)
        print("hippo-nav: interrupted", file=sys.stderr)
        if as_json:
            print(json.dumps({"exit_code": 130, "exit_reason": "interrupted", "signal": "SIGINT"}, indent=2))
        return 130


def _failed(message: str, as_json: bool) -> int:
    """The one error line on stderr (and with `--json` the same words as a JSON object on stdout); exit 2."""
    print(f"hippo-nav: error: {message}", file=sys.stderr)
    if as_json:
        print(json.dumps({"exit_code": 2, "exit_reason": "error", "error": message}, indent=2))
    return 2


__all__ = ["build_parser", "main"]
