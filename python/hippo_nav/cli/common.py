"""What the commands share: the help formatter, the input flags of `run` and `sweep` (one definition), the
loader options they take (declared by the loaders, `StereoLoader.FLAGS`), and the exit codes of signals."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hippo_nav.datasets import LoaderFlag

MAX_SEED = 2**31 - 1
"""Seeds reach OpenCV's RNG, which takes a 32-bit signed integer."""

MAX_FRAME = 10**9
"""Frame numbers, strides and counts of frames at most: a billion (KITTI's longest sequence has 4 661 frames).
More is a typo of extra digits, and the frame arithmetic stays far inside int64."""
MAX_THREADS = 4096
"""Threads, processes or CPUs of one option at most (more than any machine has)."""
MAX_RETRIES = 100
"""Restarts of a sweep's run whose worker died, at most (a run that dies 100 times will not finish)."""

SIGNAL_EXIT = {"SIGINT": 130, "SIGHUP": 129, "SIGTERM": 143}
"""The exit code of a run stopped by a signal: 128 + the signal number."""


def _shown(text: str, limit: int = 40) -> str:
    """`text` as it is quoted in a message: cut to `limit` characters (a pasted megabyte stays one line)."""
    return repr(text) if len(text) <= limit else repr(text[:limit]) + f"… ({len(text)} characters)"


def bounded_int(lo: int, hi: int) -> Callable[[str], int]:
    """An argparse `type=` for an integer option from `lo` to `hi`: anything else (text, a fraction, a value
    out of range, 10**30 digits) is argparse's one-line error naming the option and the range, exit 2, before
    the value reaches NumPy or Rust (where it would overflow or allocate without end)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:  # also a number of more than 4 300 digits (Python's limit for int("…"))
            raise argparse.ArgumentTypeError(
                f"{_shown(text)} is not an integer; give one from {lo} to {hi}"
            ) from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(
                f"{_shown(text)} is out of range; give an integer from {lo} to {hi}"
            )
        return value

    parse.__name__ = f"integer from {lo} to {hi}"
    return parse


def bounded_float(lo: float, hi: float) -> Callable[[str], float]:
    """An argparse `type=` for a finite number from `lo` to `hi` (NaN, infinities and text are refused with
    argparse's one line, exit 2)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{_shown(text)} is not a number; give one from {lo} to {hi}"
            ) from None
        if not lo <= value <= hi:  # NaN fails every comparison
            raise argparse.ArgumentTypeError(
                f"{_shown(text)} is out of range; give a number from {lo} to {hi}"
            )
        return value

    parse.__name__ = f"number from {lo} to {hi}"
    return parse


def image_size(lo: int, hi: int) -> Callable[[str], str]:
    """An argparse `type=` for `WIDTHxHEIGHT` pixels, each side from `lo` to `hi`; returns the text as given
    (the command splits it), so a bad size is argparse's one line, exit 2, before anything is rendered."""

    def parse(text: str) -> str:
        sides = text.lower().split("x")
        try:
            width, height = (int(side) for side in sides)
        except ValueError:  # not two integers (or one of more than 4 300 digits)
            raise argparse.ArgumentTypeError(
                f"{_shown(text)}: give WIDTHxHEIGHT in pixels, e.g. 320x96"
            ) from None
        if not (lo <= width <= hi and lo <= height <= hi):
            raise argparse.ArgumentTypeError(f"{_shown(text)}: each side must be {lo} to {hi} px")
        return text

    parse.__name__ = "WIDTHxHEIGHT"
    return parse


class HelpFormatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """Every option's help ends with its default: "(default: …)" from argparse, unless the help already says
    what the default is (options whose default is None say it in words)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        help_text = action.help or ""
        if "default" in help_text.lower() or action.default is argparse.SUPPRESS:
            return help_text
        if action.required:
            return help_text + " (required)"
        if action.default is None:
            return help_text + " (default: none)"
        if action.default is False and action.nargs == 0:
            return help_text + " (default: off)"
        if action.default == []:
            return help_text + " (default: none)"
        return super()._get_help_string(action) or help_text


class _DatasetPath(argparse.Action):
    """`--dataset PATH` (also spelt `--kitti`): remembers which spelling was used, and every use, so that
    a message can name the flag typed and two paths are refused rather than one silently winning."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: object,
        option: str | None = None,
    ) -> None:
        namespace.dataset = values
        namespace.dataset_flags = [*getattr(namespace, "dataset_flags", []), str(option)]


def loader_flags() -> dict[str, LoaderFlag]:
    """The loader options offered as flags, by keyword: every registered loader's `FLAGS`, in registry
    order (the first loader to declare a keyword gives its metavar and help)."""
    from hippo_nav.datasets import LOADERS

    flags: dict[str, LoaderFlag] = {}
    for loader in LOADERS.values():
        for flag in loader.FLAGS:
            flags.setdefault(flag.keyword, flag)
    return flags


def loaders_taking(option: str) -> list[str]:
    """The kinds of the registered loaders whose `OPTIONS` include `option`."""
    from hippo_nav.datasets import LOADERS

    return [kind for kind, loader in LOADERS.items() if option in loader.OPTIONS]


def add_input_flags(
    target: argparse.ArgumentParser | argparse._ArgumentGroup,
    *,
    stride_default: int | None,
    sequence: bool = True,
    loader_group: argparse._ArgumentGroup | None = None,
) -> None:
    """The input flags of `run` and `sweep`: `--dataset/--kitti`, `--dataset-kind`, `--sequence` (unless
    `sequence` is False: sweep's is an axis), `--start`, `--stop`, `--stride` (default `stride_default`;
    None lets a sweep file's value stand) and the loader options (`loader_flags()`) into `loader_group`, or
    into `target` when there is none."""
    from hippo_nav.datasets import LOADERS

    target.set_defaults(dataset=None, dataset_flags=[])
    layouts = "; ".join(f"{loader.TITLE} ({kind})" for kind, loader in LOADERS.items())
    target.add_argument(
        "--dataset",
        "--kitti",
        metavar="PATH",
        action=_DatasetPath,
        help=f"the stereo dataset, recognised by its layout: {layouts}; --kitti is another name for it "
        "(default: none, the built-in synthetic demo loop)",
    )
    target.add_argument(
        "--dataset-kind",
        choices=list(LOADERS),
        default=None,
        help="read --dataset as this kind instead of detecting it (default: detected from the layout)",
    )
    if sequence:
        numbered = "; ".join(f"{loader.DEFAULT_SEQUENCE} for {kind}" for kind, loader in LOADERS.items()
                             if loader.DEFAULT_SEQUENCE is not None)  # fmt: skip
        target.add_argument(
            "--sequence",
            default=None,
            help="the sequence inside --dataset: a sequence number (KITTI) or a sequence folder (EuRoC, stereo "
            f"folder) (default: {numbered}; else the path itself)",
        )
    target.add_argument(
        "--start",
        type=bounded_int(0, MAX_FRAME - 1),
        default=None,
        help="first frame (default: the sequence's first)",
    )
    target.add_argument(
        "--stop",
        type=bounded_int(1, MAX_FRAME),
        default=None,
        help="frame to stop before (default: run to the end)",
    )
    target.add_argument(
        "--stride",
        type=bounded_int(1, MAX_FRAME),
        default=stride_default,
        help="use every n-th frame (default: 1)",
    )
    options = target if loader_group is None else loader_group
    for key, flag in loader_flags().items():
        options.add_argument(
            flag.flag, dest=key, metavar=flag.metavar, help=f"{'/'.join(loaders_taking(key))}: {flag.help}"
        )


def loader_options(args: argparse.Namespace) -> dict[str, object]:
    """The loader options given on the command line, by keyword (the flags left out are not there)."""
    return {key: getattr(args, key) for key in loader_flags() if getattr(args, key, None) is not None}


def dataset_input(args: argparse.Namespace) -> tuple[str | None, dict[str, object]]:
    """The dataset kind of `--dataset` (None for the demo) and the loader options of the flags, checked
    against the loaders' contract (`StereoLoader.OPTIONS`)."""
    from hippo_nav._core import HippoNavError
    from hippo_nav.datasets import LOADERS, detect_kind

    options = loader_options(args)
    named = loader_flags()
    flags = ", ".join(named[key].flag for key in options)
    if args.dataset is None:
        for value, flag in ((args.dataset_kind, "--dataset-kind"), (options, flags)):
            if value:
                raise HippoNavError(f"{flag} needs --dataset PATH (the dataset to read)")
        return None, {}
    if len(args.dataset_flags) > 1:
        raise HippoNavError(
            f"give one dataset path: {' and '.join(args.dataset_flags)} name the same option (--kitti is "
            "another name for --dataset)"
        )
    path = Path(args.dataset)
    if not path.exists():
        raise HippoNavError(f"{args.dataset_flags[0]} {args.dataset}: no such file or folder")
    kind = args.dataset_kind or detect_kind(path)
    if kind is not None:
        refused = [key for key in options if key not in LOADERS[kind].OPTIONS]
        if refused:
            takers = [k for k in LOADERS if any(k in loaders_taking(key) for key in refused)]
            titles = " or ".join(LOADERS[k].TITLE for k in takers)
            raise HippoNavError(f"{flags}: only for {titles}; {args.dataset} is a {kind} dataset")
    topics = options.get("topics")
    if topics is not None and not Path(str(topics)).is_file():
        raise HippoNavError(f"--topics {topics}: no such file (a YAML with left_topic, right_topic, …)")
    return kind, options


def add_replay_flags(group: argparse._ArgumentGroup, files: str, a_file: str) -> None:
    """`--odometry-format` and `--odometry-align`, the options of a replayed trajectory file, for `run` (of
    its `--odometry`) and `sweep` (of its odometry axis's files): `files` and `a_file` name them in the help."""
    from hippo_nav.vo.replay import ALIGNMENTS, FORMATS

    group.add_argument(
        "--odometry-format",
        choices=list(FORMATS),
        default=None,
        help=f"format of {files} (default: guessed, 12 numbers a line = kitti, 8 = tum)",
    )
    group.add_argument(
        "--odometry-align",
        choices=list(ALIGNMENTS),
        default=None,
        help=f"how {a_file} lines map to frames: exact (default) one line per frame of the sequence; start: "
        "line 0 is frame 0, extra lines at the end ignored; end: the last line is the sequence's last frame",
    )
