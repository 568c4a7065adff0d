"""Command line: `hippo-nav run` (the main job: the SLAM pipeline), `hippo-nav render` (a synthetic stereo
street along a KITTI ground truth) and `hippo-nav figures` (the paper's theory figures).

Exit codes: 0 done; 2 bad input (one line on stderr saying what to fix; nothing is processed); 130
interrupted by Ctrl-C, 143 by SIGTERM, 129 by SIGHUP (128 + the signal number; the results of the frames
processed so far are written)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any


class _HelpFormatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hippo-nav", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--version", action="version", version=f"hippo-nav {_version()}")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser(
        "run",
        help="run the SLAM pipeline on a stereo sequence (the built-in synthetic demo loop when no dataset is given)",
        description="Stereo VO (or another system's odometry, replayed with --odometry), spatial-memory "
        "network, view cells and experience map on every frame; writes trajectories (KITTI and TUM), the "
        "map, metrics.json, the resolved config and figures into --out.",
        formatter_class=_HelpFormatter,
    )
    run.add_argument(
        "--kitti",
        metavar="ROOT",
        help="KITTI odometry root (holds sequences/ and poses/) (default: none, the built-in synthetic demo loop)",
    )
    run.add_argument(
        "--dataset",
        metavar="PATH",
        help="any stereo dataset, recognised by its layout: a KITTI root, an EuRoC/ASL sequence (holds mav0/), "
        "a ROS 1 .bag file or ROS 2 bag folder, or a folder with left/, right/ and calibration.yaml "
        "(default: none)",
    )
    run.add_argument(
        "--dataset-kind",
        choices=["kitti", "euroc", "rosbag", "folder"],
        default=None,
        help="read --dataset as this kind instead of detecting it (default: detected from the layout)",
    )
    run.add_argument(
        "--left-topic",
        metavar="TOPIC",
        help="ROS bag: left image topic (sensor_msgs/Image) (default: guessed)",
    )
    run.add_argument("--right-topic", metavar="TOPIC", help="ROS bag: right image topic (default: guessed)")
    run.add_argument(
        "--topics",
        metavar="YAML",
        help="ROS bag: YAML with left_topic, right_topic and the calibration (CameraInfo topics, or fx, fy, "
        "cx, cy, baseline_m); flags win over it (default: none)",
    )
    run.add_argument(
        "--sequence",
        default=None,
        help="KITTI sequence number (with --kitti, or --dataset on a KITTI root; default 00), or a sequence "
        "folder inside --dataset (EuRoC, stereo folder)",
    )
    run.add_argument("--start", type=int, default=None, help="first frame (default: the sequence's first)")
    run.add_argument("--stop", type=int, default=None, help="frame to stop before (default: run to the end)")
    run.add_argument("--stride", type=int, default=1, help="use every n-th frame (default: 1)")
    run.add_argument(
        "--config",
        metavar="JSON",
        help="pipeline config file (any subset of sections; the rest: defaults) (default: none, all defaults)",
    )
    run.add_argument(
        "--lesion",
        action="append",
        default=[],
        choices=["ventral", "intermediate", "dorsal"],
        help="switch a grid module off (repeatable; adds to the config's lesions)",
    )
    run.add_argument(
        "--seed", type=int, default=None, help=f"override the config's seed (0 to {MAX_SEED}; default 0)"
    )
    run.add_argument(
        "--odometry",
        metavar="FILE",
        help="replay another system's trajectory (KITTI or TUM file) instead of the built-in stereo VO "
        "(default: none, the built-in stereo VO)",
    )
    run.add_argument(
        "--odometry-format",
        choices=["kitti", "tum"],
        default=None,
        help="format of --odometry (default: guessed, 12 numbers a line = kitti, 8 = tum)",
    )
    run.add_argument(
        "--odometry-align",
        choices=["exact", "start", "end"],
        default=None,
        help="how a KITTI --odometry file's lines map to frames: exact (default) one line per frame of the "
        "sequence; start: line 0 is frame 0, extra lines at the end ignored; end: the last line is the "
        "sequence's last frame",
    )
    run.add_argument("--no-figures", action="store_true", help="skip the figures")
    run.add_argument(
        "--out",
        default=None,
        help="results folder (default: runs/demo for the demo, runs/kitti_NN for a KITTI sequence); "
        "it must be new or empty unless --overwrite",
    )
    run.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the results of an earlier run in --out (only the files a run writes are removed)",
    )
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.add_argument(
        "--rerun",
        nargs="?",
        const="",
        default=None,
        metavar="FILE.rrd",
        help="log every frame to the Rerun viewer (camera and features, neural panels, decoded motion, the "
        "map growing, stage timings): without FILE, spawn a viewer or connect to a running one; with FILE, "
        "save a recording that `rerun FILE` opens later. Needs pip install 'hippo-nav[viewer]' (default: off)",
    )
    run.add_argument(
        "--video",
        action="store_true",
        help="write mapping.mp4 into --out: camera, neural panels and the map growing (default: off)",
    )
    run.add_argument(
        "--video-every",
        type=int,
        default=5,
        metavar="N",
        help="with --video, one video frame every N frames (and one after the final correction)",
    )

    render = sub.add_parser(
        "render",
        help="render the synthetic stereo street along a KITTI ground truth into a KITTI root",
        description="Renders a synthetic stereo sequence along ROOT/poses/NN.txt with the timestamps of "
        "ROOT/sequences/NN/times.txt into a KITTI root at --out (images, calib.txt, times.txt, poses/NN.txt). "
        "The camera keeps a fixed height above the road, so every pass sees a street the same way. "
        "Resumable: frames already written are kept. Run it afterwards with "
        "`hippo-nav run --kitti OUT --sequence NN`.",
        formatter_class=_HelpFormatter,
    )
    render.add_argument("--kitti", metavar="ROOT", required=True, help="KITTI root with poses/NN.txt")
    render.add_argument("--sequence", required=True, help="sequence number, e.g. 00")
    render.add_argument("--start", type=int, default=None, help="first frame to render (default 0)")
    render.add_argument("--stop", type=int, default=None, help="frame to stop before (default: all)")
    render.add_argument("--out", required=True, help="KITTI root to write (created if missing)")
    render.add_argument(
        "--size",
        default="320x96",
        metavar="WxH",
        help="image size in pixels (default 320x96, KITTI's aspect)",
    )
    render.add_argument("--seed", type=int, default=0, help="texture seed of the synthetic world (default 0)")
    render.add_argument("--workers", type=int, default=2, help="rendering threads (default 2)")
    render.add_argument("--no-progress", action="store_true", help="no progress bar")

    figures = sub.add_parser(
        "figures",
        help="write the paper's theory figures as PNG files",
        description="Writes the paper's theory figures (the 1-D theory of multi-resolution grid codes) as PNG files.",
        formatter_class=_HelpFormatter,
    )
    figures.add_argument("--out", default="runs/figures", help="folder for the PNG files")
    return parser


MAX_SEED = 2**31 - 1
"""Seeds reach OpenCV's RNG, which takes a 32-bit signed integer."""

_SIGNAL_EXIT = {"SIGINT": 130, "SIGHUP": 129, "SIGTERM": 143}


def _version() -> str:
    from hippo_nav import __version__

    return __version__


def _run(args: argparse.Namespace) -> int:
    from hippo_nav import HippoNavError
    from hippo_nav.pipeline import load_config, run
    from hippo_nav.pipeline.results import bump_rows, format_bump_table

    if args.kitti is None and args.dataset is None and args.sequence is not None:
        raise HippoNavError(
            f"--sequence {args.sequence} needs --kitti ROOT (the KITTI root that holds it) or --dataset PATH; "
            "without them the built-in demo runs"
        )
    if args.kitti is not None and not Path(args.kitti).is_dir():
        raise HippoNavError(f"--kitti {args.kitti}: no such folder (give the KITTI odometry root)")
    if args.seed is not None and not 0 <= args.seed <= MAX_SEED:
        raise HippoNavError(f"--seed {args.seed}: give an integer from 0 to {MAX_SEED}")
    kind, options = _dataset_input(args)
    sequence = (args.sequence or "00") if kind == "kitti" else args.sequence
    if args.out is None:
        if args.kitti is None and args.dataset is None:
            args.out = "runs/demo"
        elif kind == "kitti":
            args.out = f"runs/kitti_{sequence}"
        else:
            args.out = f"runs/{args.sequence or Path(args.dataset).resolve().stem}"
    odometry = _replay(args)
    config = load_config(args.config)
    if args.lesion:
        config = config.with_lesions(*args.lesion)
    if args.seed is not None:
        config = config.model_copy(update={"seed": args.seed})
    if args.no_figures:
        config = config.model_copy(update={"output": config.output.model_copy(update={"figures": False})})
    observers = _observers(args)  # before any frame: a missing viewer extra is reported at once
    try:
        result = run(
            args.out,
            kitti=args.kitti or args.dataset,
            sequence=sequence,
            start=args.start,
            stop=args.stop,
            stride=args.stride,
            config=config,
            progress=not args.no_progress,
            odometry=odometry,
            overwrite=args.overwrite,
            dataset_kind=kind if args.dataset is not None else None,
            dataset_options=options,
            observers=observers,
        )
    finally:
        for observer in observers:
            observer.close()
    print(json.dumps(_summary(result.metrics), indent=2))
    # The paper's bump table (μ, σ of every grid bump, fused, place) at the last snapshot frame only;
    # bump_table.csv in --out holds every snapshot frame.
    rows = bump_rows(result.record)
    if rows:
        last_frame = max(r["frame"] for r in rows)
        print(f"bump table at frame {last_frame} (radians on the torus):")
        print(format_bump_table([r for r in rows if r["frame"] == last_frame]))
    if result.interrupted:
        print(f"interrupted after {result.metrics['frames']} frames; results so far written to {args.out}")
        return _SIGNAL_EXIT.get(result.metrics.get("interrupted_by", "SIGINT"), 130)
    print(f"results written to {args.out}")
    if args.video:
        print(f"video written to {Path(args.out) / 'mapping.mp4'}")
    if args.rerun and not args.rerun.startswith("rerun"):
        print(f"rerun recording written to {args.rerun}; open it with: rerun {args.rerun}")
    return 0


def _dataset_input(args: argparse.Namespace) -> tuple[str | None, dict[str, Any]]:
    """The dataset kind of `--kitti`/`--dataset` (None for the demo) and the loader options of the flags."""
    from hippo_nav import HippoNavError
    from hippo_nav.datasets import detect_kind

    topics = {"left_topic": args.left_topic, "right_topic": args.right_topic, "topics": args.topics}
    options = {key: value for key, value in topics.items() if value is not None}
    flags = ", ".join("--" + key.replace("_", "-") for key in options)
    if args.dataset is None:
        for given, flag in ((args.dataset_kind, "--dataset-kind"), (options, flags)):
            if given:
                raise HippoNavError(f"{flag} needs --dataset PATH (the dataset to read)")
        return ("kitti" if args.kitti is not None else None), {}
    if args.kitti is not None:
        raise HippoNavError("give --kitti ROOT or --dataset PATH, not both")
    path = Path(args.dataset)
    if not path.exists():
        raise HippoNavError(f"--dataset {args.dataset}: no such file or folder")
    kind = args.dataset_kind or detect_kind(path)
    if options and kind not in ("rosbag", None):
        raise HippoNavError(f"{flags}: only for ROS bags; {args.dataset} is a {kind} dataset")
    if args.topics is not None and not Path(args.topics).is_file():
        raise HippoNavError(f"--topics {args.topics}: no such file (a YAML with left_topic, right_topic, …)")
    return kind, options


def _observers(args: argparse.Namespace) -> list[Any]:
    """The viewers asked for: `--rerun [FILE]` and `--video` (mapping.mp4 in --out)."""
    from hippo_nav import HippoNavError

    observers: list[Any] = []
    if args.video_every < 1:
        raise HippoNavError(f"--video-every {args.video_every}: give a positive number of frames")
    if args.rerun is not None:
        from hippo_nav.viewer.rerun import RerunObserver

        target = args.rerun or None
        if target is not None and not str(target).startswith("rerun") and Path(target).suffix != ".rrd":
            raise HippoNavError(
                f"--rerun {target}: give a recording file ending in .rrd (or no file for a live viewer)"
            )
        observers.append(RerunObserver(target))
    if args.video:
        from hippo_nav.viewer.video import VideoObserver

        observers.append(VideoObserver(Path(args.out) / "mapping.mp4", every=args.video_every))
    return observers


def _replay(args: argparse.Namespace) -> Callable[[Any], Any] | None:
    """The `--odometry` replay as the callable `run()` aligns with the opened dataset, or None.

    The file is read (and every line checked) here, before the dataset is opened or rendered."""
    from hippo_nav import HippoNavError

    if args.odometry is None:
        for flag in ("odometry_format", "odometry_align"):
            if getattr(args, flag) is not None:
                option = "--" + flag.replace("_", "-")
                raise HippoNavError(f"{option} needs --odometry FILE (the trajectory to replay)")
        return None
    from hippo_nav.vo.replay import replay_odometry

    align = args.odometry_align or "exact"
    build = replay_odometry(args.odometry, file_format=args.odometry_format, align=align)

    def aligned(dataset):
        replay = build(dataset)  # raises before any frame runs when the file does not fit the dataset
        print(replay.note)
        return replay

    return aligned


def _render(args: argparse.Namespace) -> int:
    from hippo_nav.synthetic import render_kitti

    try:
        width, height = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        print(f"hippo-nav: error: --size {args.size!r}: give WIDTHxHEIGHT, e.g. 320x96", file=sys.stderr)
        return 2
    root = render_kitti(
        args.kitti,
        args.sequence,
        args.out,
        args.start,
        args.stop,
        image_size_px=(width, height),
        seed=args.seed,
        workers=args.workers,
        progress=not args.no_progress,
    )
    print(f"rendered sequence {args.sequence} into {root}; run it with: "
          f"hippo-nav run --kitti {root} --sequence {args.sequence}")  # fmt: skip
    return 0


def _summary(metrics: dict) -> dict:
    """The headline numbers of a run (metrics.json holds everything)."""
    keys = ["sequence", "note", "frames", "view_cells", "vertices", "loop_closures", "interrupted"]
    summary = {k: metrics[k] for k in keys if metrics.get(k) not in (None, "")}
    for name, entry in (metrics.get("errors") or {}).items():
        if isinstance(entry, dict) and "ate_2d_m" in entry:
            summary[f"ate_2d_m_{name}"] = entry["ate_2d_m"]
    timing = metrics.get("timing", {})
    if timing.get("frames_per_s") is not None:
        summary["frames_per_s"] = timing["frames_per_s"]
    return summary


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import logging

    from hippo_nav import HippoNavError

    # Per-frame warnings (VO failures, clamped motion) go to stderr, one line each.
    logging.basicConfig(level=logging.WARNING, format="hippo-nav: %(message)s")

    try:
        if args.command == "run":
            return _run(args)
        if args.command == "render":
            return _render(args)
        if args.command == "figures":
            from hippo_nav.theory.figures import write_all_figures

            write_all_figures(args.out)
            return 0
    except (HippoNavError, OSError) as err:
        # Bad input: one line saying what to fix. Anything else is a bug and keeps its traceback.
        print(f"hippo-nav: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # before the pipeline started (e.g. while rendering the demo)
        print("hippo-nav: interrupted", file=sys.stderr)
        return 130
    return 2


if __name__ == "__main__":
    sys.exit(main())
