"""`hippo-nav run`: the SLAM pipeline on a stereo sequence (the built-in synthetic demo loop without one)."""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hippo_nav._core import HippoNavError
from hippo_nav.cli.common import (
    MAX_FRAME,
    MAX_SEED,
    SIGNAL_EXIT,
    add_input_flags,
    add_replay_flags,
    bounded_int,
    dataset_input,
)

if TYPE_CHECKING:
    from hippo_nav.pipeline import RunResult
    from hippo_nav.viewer.rerun import RerunObserver
    from hippo_nav.viewer.video import VideoObserver


HELP = (
    "run the SLAM pipeline on a stereo sequence (the built-in synthetic demo loop when no dataset is given)"
)
DESCRIPTION = (
    "Stereo VO (or another system's odometry, replayed with --odometry), spatial-memory "
    "network, view cells and experience map on every frame; writes trajectories (KITTI and TUM), the "
    "map, metrics.json, the resolved config and figures into --out."
)


def add_arguments(run: argparse.ArgumentParser) -> None:
    """`hippo-nav run`: its choices come from the loader registry, the module names and the replay formats."""
    data = run.add_argument_group("input")
    options = run.add_argument_group("loader options", "keywords of the loaders that take them")
    add_input_flags(data, stride_default=1, loader_group=options)
    _add_configuration(run.add_argument_group("configuration"))
    _add_odometry(run.add_argument_group("odometry"))
    run.add_argument_group("maps that outlive a run").add_argument(
        "--map",
        dest="memory_from",
        default=None,
        metavar="PREVIOUS_RESULTS",
        help="start inside the map of an earlier run (its results folder, which holds memory/): lost until a "
        "familiar view is confirmed by the closure measurement, then placed in that map and extending it; "
        "metrics.json's loaded_map says when and where (docs/memory.md) (default: a new map)",
    )
    _add_output(run.add_argument_group("output"))
    _add_viewers(run.add_argument_group("viewers"))


def _add_configuration(setup: argparse._ArgumentGroup) -> None:
    from hippo_nav.engine import MODULE_NAMES
    from hippo_nav.system.presets import PRESETS

    setup.add_argument(
        "--config",
        metavar="JSON",
        help="pipeline config file (any subset of sections; the rest: defaults) (default: none, all defaults)",
    )
    setup.add_argument(
        "--preset",
        choices=list(PRESETS),
        default=None,
        help="start from named settings, the --config file's on top: paper = the system as the paper describes "
        "it (template view cells, RatSLAM closure and relaxation, recalled states as stored; "
        "`hippo-nav config --preset paper` shows it) (default: the config's own, else default)",
    )
    setup.add_argument(
        "--lesion",
        action="append",
        default=[],
        choices=list(MODULE_NAMES),
        help="switch a grid module off (repeatable; adds to the config's lesions)",
    )
    setup.add_argument(
        "--seed",
        type=bounded_int(0, MAX_SEED),
        default=None,
        help=f"override the config's seed (0 to {MAX_SEED}; default 0)",
    )


def _add_odometry(odometry: argparse._ArgumentGroup) -> None:

    odometry.add_argument(
        "--odometry",
        metavar="FILE",
        help="replay another system's trajectory (KITTI or TUM file) instead of the built-in stereo VO "
        "(default: none, the built-in stereo VO)",
    )
    add_replay_flags(odometry, "--odometry", "a KITTI --odometry file's")


def _add_output(output: argparse._ArgumentGroup) -> None:
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
    output.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object on stdout at the end and nothing else there: the results folder, the "
        "headline metrics, the errors per trajectory, exit_reason and exit_code (bad input too: "
        '{"exit_code": 2, "exit_reason": "error", "error": …}); every other line goes to stderr',
    )


def _add_viewers(viewers: argparse._ArgumentGroup) -> None:
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
        type=bounded_int(1, MAX_FRAME),
        default=5,
        metavar="N",
        help="with --video, one video frame every N frames (and one after the final correction)",
    )


def command(args: argparse.Namespace) -> int:
    from hippo_nav.pipeline import load_config, run
    from hippo_nav.pipeline.observers import ObserverError

    if args.dataset is None and args.sequence is not None:
        raise HippoNavError(
            f"--sequence {args.sequence} needs --kitti/--dataset PATH (the dataset that holds it); without a "
            "dataset the built-in demo runs"
        )
    if args.seed is not None and not 0 <= args.seed <= MAX_SEED:
        raise HippoNavError(f"--seed {args.seed}: give an integer from 0 to {MAX_SEED}")
    kind, options = dataset_input(args)
    if args.out is None:
        args.out = _default_out(args, kind)
    odometry = _replay(args)
    config = load_config(args.config, args.preset)
    if args.lesion:
        config = config.with_lesions(*args.lesion)
    if args.seed is not None:
        config = config.model_copy(update={"seed": args.seed})
    if args.no_figures:
        config = config.model_copy(update={"output": config.output.model_copy(update={"figures": False})})
    # --json: stdout holds the one JSON object only; anything else printed during the run (the --odometry
    # replay's note, a viewer's or an observer's line) goes to stderr with the progress bar and the log.
    with contextlib.redirect_stdout(sys.stderr) if args.json else contextlib.nullcontext():
        observers = _observers(args)  # before any frame: a missing viewer extra is reported at once
        failure: HippoNavError | None = None
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
        except HippoNavError as err:
            # Stopped by an unreadable frame mid-run, a results folder that stopped taking files, or a viewer
            # that could not finish after the results were written: the results exist (`err.result`).
            # Without --json (or without results) `main` prints the one line.
            # That error is the one to report: a viewer or video that cannot finish too (the same full disk)
            # only adds a warning, or its error would hide where the results were saved.
            _close_after_failure(observers)
            if not args.json or getattr(err, "result", None) is None:
                raise
            print(f"hippo-nav: error: {err}", file=sys.stderr)
            failure, result = err, err.result  # type: ignore[attr-defined]
        except BaseException:
            _close_after_failure(observers)
            raise
        else:
            try:
                for observer in observers:
                    observer.close()
            except HippoNavError as err:
                _close_after_failure(observers)
                failure = ObserverError(f"{err} (the run's results are written to {result.out_dir})")
                if not args.json:
                    raise failure from err
                # A script reading --json still gets the run's results and summary: only a viewer failed.
                print(f"hippo-nav: error: {failure}", file=sys.stderr)
    if args.json:
        return _print_json(args, result, failure)
    return _print_result(args, result)


def _close_after_failure(observers: list[Any]) -> None:
    """Close every observer, each failure a warning: an error is already on its way to the user."""
    for observer in observers:
        try:
            observer.close()
        except Exception as err:  # noqa: BLE001 - the run's own error is the one reported
            logging.getLogger("hippo_nav").warning("warning: %s", err)


def _exit(result: RunResult) -> tuple[str, int, str | None]:
    """(exit_reason, exit code, signal) of a run that returned: "done", 0 — or "interrupted", 128 + the
    signal that stopped the frames, or came after the last one (the correction, the figures, a viewer)."""
    signal = result.metrics.get("interrupted_by") or ("SIGINT" if result.interrupted else None)
    if signal is None:
        return "done", 0, None
    return "interrupted", SIGNAL_EXIT.get(signal, 130), signal


def _print_json(args: argparse.Namespace, result: RunResult, failure: HippoNavError | None = None) -> int:
    """`--json`: one JSON object on stdout (docs/pipeline.md, "Machine-readable output"); the exit code.

    `failure`: the error that stopped a run whose results exist (an unreadable frame mid-run:
    "stopped_by_error"; a results folder that stopped taking files: "not_written", `results` is then the
    folder they were written to instead, or null)."""
    from hippo_nav.pipeline.observers import ObserverError
    from hippo_nav.pipeline.results import ResultsNotWrittenError, json_safe

    results: Path | str | None = result.out_dir if result.out_dir is not None else args.out
    if failure is None:
        reason, code, signal = _exit(result)
    elif isinstance(failure, ResultsNotWrittenError):
        reason, code, signal, results = "not_written", 2, None, failure.rescued_to
    elif isinstance(failure, ObserverError):
        reason, code, signal = "viewer_not_written", 2, None
    else:
        reason, code, signal = "stopped_by_error", 2, None
    report: dict[str, Any] = {"exit_code": code, "exit_reason": reason}
    if signal is not None:
        report["signal"] = signal
    if failure is not None:
        report["error"] = str(failure)  # the words of the one line on stderr
    report["results"] = None if results is None else str(results)
    if args.video and reason not in ("not_written", "viewer_not_written"):
        report["video"] = str(Path(args.out) / "mapping.mp4")
    if (
        args.rerun
        and not args.rerun.startswith("rerun")
        and reason not in ("not_written", "viewer_not_written")
    ):
        report["rerun_recording"] = args.rerun
    report["summary"] = _summary(result.metrics)
    errors = result.metrics.get("errors") or {}
    report["errors"] = {name: e for name, e in errors.items() if isinstance(e, dict) and "ate_2d_m" in e}
    print(json.dumps(json_safe(report), indent=2, allow_nan=False))
    return code


def _print_result(args: argparse.Namespace, result: RunResult) -> int:
    """Print what the run did and where it wrote it; the exit code (128 + the signal that stopped it)."""
    from hippo_nav.pipeline.results import bump_rows, format_bump_table

    print(json.dumps(_summary(result.metrics), indent=2))
    # The paper's bump table (μ, σ of every grid bump, fused, place) at the last snapshot frame only;
    # bump_table.csv in --out holds every snapshot frame.
    rows = bump_rows(result.record)
    if rows:
        last_frame = max(r["frame"] for r in rows)
        print(f"bump table at frame {last_frame} (radians on the torus):")
        print(format_bump_table([r for r in rows if r["frame"] == last_frame]))
    reason, code, _ = _exit(result)
    if result.interrupted:
        written = result.out_dir if result.out_dir is not None else args.out
        kept = "" if Path(written) == Path(args.out) else f" (the earlier results in {args.out} are kept)"
        print(
            f"interrupted after {result.metrics['frames']} frames; results so far written to {written}{kept}"
        )
        return code
    if reason == "interrupted":  # every frame, but a signal during the correction or the figures
        print(f"interrupted after the last frame; results written to {args.out} (see metrics.json)")
        return code
    print(f"results written to {args.out}")
    if args.video:
        print(f"video written to {Path(args.out) / 'mapping.mp4'}")
    if args.rerun and not args.rerun.startswith("rerun"):
        print(f"rerun recording written to {args.rerun}; open it with: rerun {args.rerun}")
    return 0


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


def _observers(args: argparse.Namespace) -> list[RerunObserver | VideoObserver]:
    """The viewers asked for: `--rerun [FILE]` and `--video` (mapping.mp4 in --out)."""

    observers: list[RerunObserver | VideoObserver] = []
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
    sessions = metrics.get("sessions") or {}
    if "ate_2d_m" in sessions:  # every session's frames on this run's map (docs/memory.md)
        summary["ate_2d_m_all_sessions"] = sessions["ate_2d_m"]
    timing = metrics.get("timing", {})
    if timing.get("frames_per_s") is not None:
        summary["frames_per_s"] = timing["frames_per_s"]
    return summary
