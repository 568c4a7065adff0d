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


class _DatasetPath(argparse.Action):
    """`--dataset PATH` (also spelt `--kitti`): remembers which spelling was used, and every use, so that
    a message can name the flag typed and two paths are refused rather than one silently winning."""

    def __call__(
        self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option: Any = None
    ) -> None:
        namespace.dataset = values
        namespace.dataset_flags = [*getattr(namespace, "dataset_flags", []), str(option)]


LOADER_FLAGS = {
    "--left-topic": "left_topic",
    "--right-topic": "right_topic",
    "--topics": "topics",
    "--cameras": "cameras",
}
"""Command-line flags of loader options (keywords of `StereoLoader.OPTIONS`)."""


def _loaders_taking(option: str) -> list[str]:
    from hippo_nav.datasets import LOADERS

    return [kind for kind, loader in LOADERS.items() if option in loader.OPTIONS]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hippo-nav", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--version", action="version", version=f"hippo-nav {_version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_run(sub)
    _add_render(sub)
    _add_figures(sub)
    _add_vocabulary(sub)
    _add_sweep(sub)
    _add_report(sub)
    return parser


def _add_run(sub: argparse._SubParsersAction) -> None:
    """`hippo-nav run`: its choices come from the loader registry, the module names and the replay formats."""
    from hippo_nav.datasets import LOADERS
    from hippo_nav.engine import MODULE_NAMES
    from hippo_nav.vo.replay import ALIGNMENTS, FORMATS

    run = sub.add_parser(
        "run",
        help="run the SLAM pipeline on a stereo sequence (the built-in synthetic demo loop when no dataset is given)",
        description="Stereo VO (or another system's odometry, replayed with --odometry), spatial-memory "
        "network, view cells and experience map on every frame; writes trajectories (KITTI and TUM), the "
        "map, metrics.json, the resolved config and figures into --out.",
        formatter_class=_HelpFormatter,
    )
    run.set_defaults(dataset=None, dataset_flags=[])
    data = run.add_argument_group("input")
    layouts = "; ".join(f"{loader.TITLE} ({kind})" for kind, loader in LOADERS.items())
    data.add_argument(
        "--dataset",
        "--kitti",
        metavar="PATH",
        action=_DatasetPath,
        help=f"the stereo dataset, recognised by its layout: {layouts}; --kitti is another name for it "
        "(default: none, the built-in synthetic demo loop)",
    )
    data.add_argument(
        "--dataset-kind",
        choices=list(LOADERS),
        default=None,
        help="read --dataset as this kind instead of detecting it (default: detected from the layout)",
    )
    numbered = "; ".join(f"{loader.DEFAULT_SEQUENCE} for {kind}" for kind, loader in LOADERS.items()
                         if loader.DEFAULT_SEQUENCE is not None)  # fmt: skip
    data.add_argument(
        "--sequence",
        default=None,
        help="the sequence inside --dataset: a sequence number (KITTI) or a sequence folder (EuRoC, stereo "
        f"folder) (default: {numbered}; else the path itself)",
    )
    data.add_argument("--start", type=int, default=None, help="first frame (default: the sequence's first)")
    data.add_argument("--stop", type=int, default=None, help="frame to stop before (default: run to the end)")
    data.add_argument("--stride", type=int, default=1, help="use every n-th frame (default: 1)")

    options = run.add_argument_group("loader options", "keywords of the loaders that take them")
    option_help = {
        "--left-topic": ("TOPIC", "left image topic (sensor_msgs/Image) (default: guessed)"),
        "--right-topic": ("TOPIC", "right image topic (default: guessed)"),
        "--topics": (
            "YAML",
            (
                "YAML with left_topic, right_topic and the calibration (CameraInfo topics, or fx, fy, cx, "
                "cy, baseline_m); flags win over it (default: none)"
            ),
        ),
        "--cameras": (
            "{gray,color}",
            (
                "the stereo pair: gray (image_0, image_1) or color (image_2, image_3, read as gray) "
                "(default: gray where its folders exist, else color)"
            ),
        ),
    }
    for flag, key in LOADER_FLAGS.items():
        metavar, text = option_help[flag]
        options.add_argument(flag, metavar=metavar, help=f"{'/'.join(_loaders_taking(key))}: {text}")

    setup = run.add_argument_group("configuration")
    setup.add_argument(
        "--config",
        metavar="JSON",
        help="pipeline config file (any subset of sections; the rest: defaults) (default: none, all defaults)",
    )
    setup.add_argument(
        "--lesion",
        action="append",
        default=[],
        choices=list(MODULE_NAMES),
        help="switch a grid module off (repeatable; adds to the config's lesions)",
    )
    setup.add_argument(
        "--seed", type=int, default=None, help=f"override the config's seed (0 to {MAX_SEED}; default 0)"
    )

    odometry = run.add_argument_group("odometry")
    odometry.add_argument(
        "--odometry",
        metavar="FILE",
        help="replay another system's trajectory (KITTI or TUM file) instead of the built-in stereo VO "
        "(default: none, the built-in stereo VO)",
    )
    odometry.add_argument(
        "--odometry-format",
        choices=list(FORMATS),
        default=None,
        help="format of --odometry (default: guessed, 12 numbers a line = kitti, 8 = tum)",
    )
    odometry.add_argument(
        "--odometry-align",
        choices=list(ALIGNMENTS),
        default=None,
        help="how a KITTI --odometry file's lines map to frames: exact (default) one line per frame of the "
        "sequence; start: line 0 is frame 0, extra lines at the end ignored; end: the last line is the "
        "sequence's last frame",
    )

    memory = run.add_argument_group("maps that outlive a run")
    memory.add_argument(
        "--map",
        dest="memory_from",
        default=None,
        metavar="PREVIOUS_RESULTS",
        help="start inside the map of an earlier run (its results folder, which holds memory/): lost until a "
        "familiar view is confirmed by the closure measurement, then placed in that map and extending it; "
        "metrics.json's loaded_map says when and where (docs/memory.md) (default: a new map)",
    )

    output = run.add_argument_group("output")
    output.add_argument(
        "--out",
        default=None,
        help="results folder (default: runs/demo for the demo, runs/kitti_NN for a KITTI sequence, else "
        "runs/<sequence or dataset name>); it must be new or empty unless --overwrite",
    )
    output.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the results of an earlier run in --out (only the files a run writes are removed)",
    )
    output.add_argument("--no-figures", action="store_true", help="skip the figures")
    output.add_argument("--no-progress", action="store_true", help="no progress bar")

    viewers = run.add_argument_group("viewers")
    viewers.add_argument(
        "--rerun",
        nargs="?",
        const="",
        default=None,
        metavar="FILE.rrd",
        help="log every frame to the Rerun viewer (camera and features, neural panels, decoded motion, the "
        "map growing, stage timings): without FILE, spawn a viewer or connect to a running one; with FILE, "
        "save a recording that `rerun FILE` opens later. Needs pip install 'hippo-nav[viewer]' (default: off)",
    )
    viewers.add_argument(
        "--video",
        action="store_true",
        help="write mapping.mp4 into --out: camera, neural panels and the map growing (default: off)",
    )
    viewers.add_argument(
        "--video-every",
        type=int,
        default=5,
        metavar="N",
        help="with --video, one video frame every N frames (and one after the final correction)",
    )


def _add_render(sub: argparse._SubParsersAction) -> None:
    from hippo_nav.synthetic.appearance import APPEARANCE_LEVELS

    render = sub.add_parser(
        "render",
        help="render the synthetic stereo street along a KITTI ground truth into a KITTI root",
        description="Renders a synthetic stereo sequence along ROOT/poses/NN.txt with the timestamps of "
        "ROOT/sequences/NN/times.txt into a KITTI root at --out (images, calib.txt, times.txt, poses/NN.txt). "
        "The camera keeps a fixed height above the road; with --appearance same (the default) every pass sees "
        "a street the same way, with mild or strong a place looks different on each pass (light, shadows, "
        "shop fronts and posters, parked cars, noise, blur, vignetting, another lane; docs/render.md). "
        "Resumable: frames already written are kept. Run it afterwards with "
        "`hippo-nav run --dataset OUT --sequence NN`.",
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
    render.add_argument(
        "--appearance",
        choices=list(APPEARANCE_LEVELS),
        default="same",
        help="how much a place's look changes between passes (default same: identical on every pass)",
    )
    render.add_argument(
        "--poles",
        action="store_true",
        help="posts on the pavements (trees, lamp posts: structure along the street besides its walls)",
    )
    render.add_argument("--workers", type=int, default=2, help="rendering threads (default 2)")
    render.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_figures(sub: argparse._SubParsersAction) -> None:
    figures = sub.add_parser(
        "figures",
        help="write the paper's theory figures (or the appearance levels of the synthetic street) as PNG files",
        description="Writes the paper's theory figures (the 1-D theory of multi-resolution grid codes) as PNG "
        "files; with --appearance, appearance_levels.png instead: one place of the synthetic street at each "
        "appearance level, on pass 0 and pass 1 (docs/render.md).",
        formatter_class=_HelpFormatter,
    )
    figures.add_argument("--out", default="runs/figures", help="folder for the PNG files")
    figures.add_argument(
        "--appearance",
        action="store_true",
        help="write appearance_levels.png (the synthetic street at each appearance level) instead",
    )


def _add_vocabulary(sub: argparse._SubParsersAction) -> None:
    vocabulary = sub.add_parser(
        "vocabulary",
        help="train the word view cells' vocabulary (on your images, or remake the shipped one)",
        description="Trains a vocabulary of binary words for the word view cells (docs/views.md) on the ORB "
        "features of the images in --images (every PNG/JPEG in the folder, gray or colour), or, without "
        "--images, on the procedural street renders the shipped vocabulary was trained on (the result is "
        "then the shipped file). Use it with the config's view_words.vocabulary = FILE.",
        formatter_class=_HelpFormatter,
    )
    vocabulary.add_argument("--out", required=True, metavar="FILE", help="vocabulary file to write")
    vocabulary.add_argument(
        "--images", metavar="DIR", default=None, help="folder of training images (default: the renders)"
    )
    vocabulary.add_argument("--every", type=int, default=1, metavar="N", help="use every Nth image")
    vocabulary.add_argument("--branching", type=int, default=10, help="children per node of the word tree")
    vocabulary.add_argument("--levels", type=int, default=4, help="depth of the word tree")
    vocabulary.add_argument("--seed", type=int, default=0, help="seed of the k-means clustering")


def _add_sweep(sub: argparse._SubParsersAction) -> None:
    """`hippo-nav sweep`: the space (a file and/or axes), `run`'s dataset flags, and how the runs execute."""
    from hippo_nav.datasets import LOADERS
    from hippo_nav.vo.replay import ALIGNMENTS, FORMATS

    sweep = sub.add_parser(
        "sweep",
        help="run the pipeline over a cross-product of settings × seeds × sequences × odometries, on Ray",
        description="Runs `hippo-nav run` for every combination of the axes (from the command line and/or a "
        "TOML/YAML sweep file, docs/sweep.md) on Ray: on this machine by default, or on a cluster with "
        "--address. Each run writes its results folder and manifest.json into OUT/runs/<id>/. Rerunning the "
        "same command skips finished runs and reruns interrupted ones; a failing run is listed and never "
        "stops the others; Ctrl-C stops cleanly. Exit 0: every run done; 1: some failed; 130: interrupted. "
        "Needs pip install 'hippo-nav[sweep]'.",
        formatter_class=_HelpFormatter,
    )
    sweep.set_defaults(dataset=None, dataset_flags=[])
    space = sweep.add_argument_group("the space (the command line replaces a file's axis of the same name)")
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
    space.add_argument(
        "--odometry-format",
        choices=list(FORMATS),
        default=None,
        help="format of the files (default: guessed)",
    )
    space.add_argument(
        "--odometry-align",
        choices=list(ALIGNMENTS),
        default=None,
        help="alignment of KITTI files (default: exact)",
    )
    data = sweep.add_argument_group("input (as in run)")
    data.add_argument("--dataset", "--kitti", metavar="PATH", action=_DatasetPath,
                      help="the stereo dataset (default: none, the built-in demo loop)")  # fmt: skip
    data.add_argument(
        "--dataset-kind", choices=list(LOADERS), default=None, help="the dataset's kind (default: detected)"
    )
    data.add_argument("--start", type=int, default=None, help="first frame (default: the sequence's first)")
    data.add_argument("--stop", type=int, default=None, help="frame to stop before (default: the end)")
    data.add_argument("--stride", type=int, default=None, help="use every n-th frame (default: 1)")
    for flag, key in LOADER_FLAGS.items():
        data.add_argument(
            flag, metavar=key.upper(), help=f"{'/'.join(_loaders_taking(key))}: as in run (default: none)"
        )
    setup = sweep.add_argument_group("configuration")
    setup.add_argument(
        "--config", metavar="JSON", help="base config file every run starts from (default: none)"
    )
    setup.add_argument("--no-figures", action="store_true", help="skip every run's figures")
    execution = sweep.add_argument_group("execution")
    execution.add_argument(
        "--address", metavar="auto|HOST:PORT", default=None,
        help="join a running Ray cluster (`ray start --head`; docs/sweep.md) (default: none, Ray on this machine)",
    )  # fmt: skip
    execution.add_argument(
        "--cpus-per-run", type=int, default=1, metavar="N",
        help="CPUs each run is declared to Ray, and the size of its thread pools (a demo run keeps about one "
        "core busy: 0.95-1.06 cores measured)",
    )  # fmt: skip
    execution.add_argument(
        "--workers", type=int, default=None, metavar="N",
        help="without --address: runs at a time on this machine (default: its cores / --cpus-per-run)",
    )  # fmt: skip
    execution.add_argument("--retries", type=int, default=2, help="restarts of a run whose worker died")
    execution.add_argument(
        "--retry-failed", action="store_true", help="run the runs that failed before again"
    )
    execution.add_argument(
        "--dry-run", action="store_true", help="list the runs and what would be done; run nothing"
    )
    execution.add_argument("--no-progress", action="store_true", help="no progress bar")
    sweep.add_argument(
        "--out", default=None, help="sweep folder (default: runs/<sweep file name>, or runs/sweep)"
    )


def _add_report(sub: argparse._SubParsersAction) -> None:
    report = sub.add_parser(
        "report",
        help="one table (CSV, Markdown), statistics over seeds and figures from sweep and run folders",
        description="Reads sweep folders (OUT/runs/*/manifest.json) and plain `hippo-nav run` folders (any "
        "folder holding metrics.json, searched below each DIR) and writes into --out: table.csv and table.md "
        "(one row per run: what it varies, its metrics and timings), groups.csv and the grouped statistics "
        "over seeds in table.md (mean, std, n, 95 %% confidence interval), figures (ATE per configuration with "
        "the seeds as points, the trajectories of one sequence overlaid, a metric against one swept key) and, "
        "when the runs differ in lesions, lesions.md (place-bump width and path-integration error per lesion "
        "against the 1-D theory's order).",
        formatter_class=_HelpFormatter,
    )
    report.add_argument("dirs", nargs="+", metavar="DIR", help="sweep or run folders")
    report.add_argument(
        "--out", default=None, help="report folder (default: DIR/report for one DIR, else runs/report)"
    )
    report.add_argument(
        "--metric", default="ate_2d_corrected_m", help="the metric of the figures (a column of table.csv)"
    )
    report.add_argument(
        "--key",
        default=None,
        help="the swept key of the response figure (default: the first with several values)",
    )
    report.add_argument(
        "--sequence", default=None, help="the sequence whose trajectories are overlaid (default: the first)"
    )
    report.add_argument("--no-figures", action="store_true", help="tables only")


MAX_SEED = 2**31 - 1
"""Seeds reach OpenCV's RNG, which takes a 32-bit signed integer."""

_SIGNAL_EXIT = {"SIGINT": 130, "SIGHUP": 129, "SIGTERM": 143}


def _version() -> str:
    from hippo_nav._core import __version__

    return __version__


def _run(args: argparse.Namespace) -> int:
    from hippo_nav._core import HippoNavError
    from hippo_nav.pipeline import load_config, run
    from hippo_nav.pipeline.results import bump_rows, format_bump_table

    if args.dataset is None and args.sequence is not None:
        raise HippoNavError(
            f"--sequence {args.sequence} needs --kitti/--dataset PATH (the dataset that holds it); without a "
            "dataset the built-in demo runs"
        )
    if args.seed is not None and not 0 <= args.seed <= MAX_SEED:
        raise HippoNavError(f"--seed {args.seed}: give an integer from 0 to {MAX_SEED}")
    kind, options = _dataset_input(args)
    if args.out is None:
        args.out = _default_out(args, kind)
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
            dataset=args.dataset,
            sequence=args.sequence,
            start=args.start,
            stop=args.stop,
            stride=args.stride,
            config=config,
            progress=not args.no_progress,
            odometry=odometry,
            overwrite=args.overwrite,
            dataset_kind=args.dataset_kind,
            dataset_options=options,
            observers=observers,
            memory_from=args.memory_from,
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
    if result.metrics.get("interrupted_by"):  # every frame, but a signal during the correction or the figures
        print(f"interrupted after the last frame; results written to {args.out} (see metrics.json)")
        return _SIGNAL_EXIT.get(result.metrics["interrupted_by"], 130)
    print(f"results written to {args.out}")
    if args.video:
        print(f"video written to {Path(args.out) / 'mapping.mp4'}")
    if args.rerun and not args.rerun.startswith("rerun"):
        print(f"rerun recording written to {args.rerun}; open it with: rerun {args.rerun}")
    return 0


def _dataset_input(args: argparse.Namespace) -> tuple[str | None, dict[str, Any]]:
    """The dataset kind of `--dataset` (None for the demo) and the loader options of the flags, checked
    against the loaders' contract (`StereoLoader.OPTIONS`)."""
    from hippo_nav._core import HippoNavError
    from hippo_nav.datasets import LOADERS, detect_kind

    given = {flag: getattr(args, key) for flag, key in LOADER_FLAGS.items()}
    options = {LOADER_FLAGS[flag]: value for flag, value in given.items() if value is not None}
    flags = ", ".join(flag for flag, value in given.items() if value is not None)
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
            takers = [k for k in LOADERS if any(k in _loaders_taking(key) for key in refused)]
            titles = " or ".join(LOADERS[k].TITLE for k in takers)
            raise HippoNavError(f"{flags}: only for {titles}; {args.dataset} is a {kind} dataset")
    if args.topics is not None and not Path(args.topics).is_file():
        raise HippoNavError(f"--topics {args.topics}: no such file (a YAML with left_topic, right_topic, …)")
    return kind, options


def _default_out(args: argparse.Namespace, kind: str | None) -> str:
    """runs/demo for the demo; runs/<kind>_<sequence> for a loader of numbered sequences (KITTI); else
    runs/<sequence or the dataset path's name>."""
    from hippo_nav.datasets import LOADERS

    if kind is None:
        return "runs/demo" if args.dataset is None else f"runs/{Path(args.dataset).resolve().stem}"
    numbered = LOADERS[kind].DEFAULT_SEQUENCE
    if numbered is not None:
        return f"runs/{kind}_{args.sequence or numbered}"
    return f"runs/{args.sequence or Path(args.dataset).resolve().stem}"


def _observers(args: argparse.Namespace) -> list[Any]:
    """The viewers asked for: `--rerun [FILE]` and `--video` (mapping.mp4 in --out)."""
    from hippo_nav._core import HippoNavError

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
    from hippo_nav._core import HippoNavError

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
        appearance=args.appearance,
        poles=args.poles,
        workers=args.workers,
        progress=not args.no_progress,
    )
    print(f"rendered sequence {args.sequence} into {root}; run it with: "
          f"hippo-nav run --dataset {root} --sequence {args.sequence}")  # fmt: skip
    return 0


def _vocabulary(args: argparse.Namespace) -> int:
    from hippo_nav._core import HippoNavError
    from hippo_nav.synthetic import street_views
    from hippo_nav.view_cells import train_vocabulary

    if args.every < 1:
        raise HippoNavError(f"--every {args.every}: give 1 or more")
    if args.images is None:
        images: Any = street_views()
    else:
        folder = Path(args.images)
        if not folder.is_dir():
            raise HippoNavError(f"--images {folder}: not a folder")
        suffixes = {".png", ".jpg", ".jpeg"}
        paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in suffixes)[:: args.every]
        if not paths:
            raise HippoNavError(f"--images {folder}: no PNG or JPEG images there")
        images = (_read_gray(p) for p in paths)
    vocabulary = train_vocabulary(images, branching=args.branching, levels=args.levels, seed=args.seed)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    vocabulary.save(out)
    print(
        f"wrote {out}: {len(vocabulary)} words (branching {vocabulary.branching}, {vocabulary.levels} levels)"
    )
    return 0


def _read_gray(path: Path) -> Any:
    import cv2

    from hippo_nav.datasets.common import read_image_file

    # Decoded from its bytes: any file name works (OpenCV's own reader crashes on some), sizes are checked.
    return read_image_file(path, cv2.IMREAD_GRAYSCALE)


def _sweep(args: argparse.Namespace) -> int:
    from hippo_nav.sweep import SweepOptions, build_space, run_sweep
    from hippo_nav.sweep.scheduler import describe, dry_run

    if len(args.dataset_flags) > 1:
        from hippo_nav._core import HippoNavError

        raise HippoNavError(f"give one dataset path: {' and '.join(args.dataset_flags)} name the same option")
    flags = {"dataset": args.dataset, "dataset_kind": args.dataset_kind, "start": args.start, "stop": args.stop,
             "stride": args.stride, **{key: getattr(args, key) for key in LOADER_FLAGS.values()}}  # fmt: skip
    space = build_space(
        args.file, sets=args.set, seeds=args.seeds, lesions=args.lesion, sequences=args.sequence,
        odometries=args.odometry, odometry_format=args.odometry_format, odometry_align=args.odometry_align,
        config=args.config, dataset=flags, no_figures=args.no_figures,
    )  # fmt: skip
    out = args.out or space.out or (f"runs/{Path(args.file).stem}" if args.file else "runs/sweep")
    if args.dry_run:
        print("\n".join(dry_run(space, out, args.retry_failed)))
        return 0
    options = SweepOptions(
        address=args.address, cpus_per_run=args.cpus_per_run, workers=args.workers, retries=args.retries,
        retry_failed=args.retry_failed, progress=not args.no_progress,
    )  # fmt: skip
    summary = run_sweep(space, out, options)
    print(describe(summary))
    if summary.interrupted:
        return 130
    return 1 if summary.failed else 0


def _report(args: argparse.Namespace) -> int:
    from hippo_nav.report import write_report

    out = args.out or (str(Path(args.dirs[0]) / "report") if len(args.dirs) == 1 else "runs/report")
    written = write_report(
        args.dirs, out, metric=args.metric, key=args.key, sequence=args.sequence, figures=not args.no_figures
    )
    print(f"{written.runs} runs; wrote {', '.join(p.name for p in written.files)} into {out}")
    return 0


def _summary(metrics: dict) -> dict:
    """The headline numbers of a run (metrics.json holds everything)."""
    keys = ["sequence", "note", "frames", "view_cells", "vertices", "loop_closures", "interrupted"]
    summary = {k: metrics[k] for k in keys if metrics.get(k) not in (None, "")}
    loaded = metrics.get("loaded_map")
    if loaded:
        summary["relocalised"] = loaded.get("relocalised")
        if loaded.get("relocalisation"):
            summary["relocalised_at_frame"] = loaded["relocalisation"]["frame"]
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

    from hippo_nav._core import HippoNavError

    # Per-frame warnings (VO failures, clamped motion) go to stderr, one line each.
    logging.basicConfig(level=logging.WARNING, format="hippo-nav: %(message)s")

    try:
        if args.command == "run":
            return _run(args)
        if args.command == "render":
            return _render(args)
        if args.command == "vocabulary":
            return _vocabulary(args)
        if args.command == "sweep":
            return _sweep(args)
        if args.command == "report":
            return _report(args)
        if args.command == "figures":
            if args.appearance:
                from hippo_nav.synthetic.figures import appearance_figure

                print(f"wrote {appearance_figure(Path(args.out) / 'appearance_levels.png')}")
                return 0
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
