"""`hippo-nav record`: an open-field session of the spatial memory, recorded and measured as a lab would."""

from __future__ import annotations

import argparse
import sys

HELP = "record the networks in an open-field session (RatInABox foraging) and measure them as a lab would"
DESCRIPTION = (
    "Drives the spatial memory (no camera) along a rodent's foraging path in an open arena (RatInABox, or "
    "--trajectory CSV with columns t, x, y[, heading]), with the arena's landmarks as view cells, and records "
    "every unit of the head-direction ring, the three grid modules and the place torus. Writes into --out: "
    "recording.npz, session.json, measures.json (rate maps, 60° and 90° grid scores against a shuffle test, "
    "spacing, orientation, spatial information, fields, head-direction tuning), topology.json (persistent "
    "homology of each population), session.nwb (Neurodata Without Borders) and the figures as PNG and PDF "
    "(docs/neuro.md). Needs the neuro extra: pip install 'hippo-nav[neuro]'."
)


def add_arguments(record: argparse.ArgumentParser) -> None:
    from hippo_nav.cli.common import MAX_SEED, bounded_float, bounded_int
    from hippo_nav.openfield import LESIONS, OpenFieldConfig

    d = OpenFieldConfig()
    record.add_argument("--out", required=True, help="folder for the session's files (created if missing)")
    record.add_argument(
        "--config", metavar="FILE", help="a JSON file of OpenFieldConfig fields (docs/neuro.md)"
    )
    record.add_argument("--arena-shape", choices=["square", "circle"], help=f"(default {d.arena_shape})")
    record.add_argument(
        "--arena-size",
        type=bounded_float(0.1, 100.0),
        metavar="M",
        help=f"side or diameter (default {d.arena_size_m} m)",
    )
    record.add_argument(
        "--duration",
        type=bounded_float(0.001, 86_400.0),
        metavar="S",
        help=f"session length (default {d.duration_s:g} s)",
    )
    record.add_argument(
        "--period",
        type=bounded_float(0.1, 1e5),
        metavar="M",
        help=f"torus period P (default {d.torus_period_m} m)",
    )
    record.add_argument(
        "--speed-mean",
        type=bounded_float(0.001, 5.0),
        metavar="M_S",
        help=f"(default {d.speed_mean_m_s} m/s)",
    )
    record.add_argument("--seed", type=bounded_int(0, MAX_SEED), help=f"trajectory seed (default {d.seed})")
    record.add_argument("--lesion", choices=list(LESIONS), help="switch one grid module off (default none)")
    record.add_argument("--no-landmarks", action="store_true", help="path integration alone, no view cells")
    record.add_argument("--trajectory", metavar="CSV", help="a trajectory CSV instead of RatInABox's")
    record.add_argument(
        "--units",
        type=bounded_int(1, 1 << 20),
        default=32,
        help="units measured per population for the rate-map measures (default 32; every unit is recorded)",
    )
    record.add_argument(
        "--shuffles", type=bounded_int(1, 10_000), default=25, help="shuffles per unit (default 25)"
    )
    record.add_argument("--no-analysis", action="store_true", help="record only: no measures, topology, NWB")
    record.add_argument(
        "--lesion-study",
        type=bounded_int(1, 1000),
        metavar="SEEDS",
        help="instead of one session: every lesion condition × SEEDS seeds (from --seed), measured; writes "
        "lesions.json and lesions.png/.pdf (mean and 95 %% interval over seeds against the 1-D theory)",
    )
    record.add_argument(
        "--workers", type=bounded_int(1, 4096), default=1, help="processes for --lesion-study (default 1)"
    )
    record.add_argument("--overwrite", action="store_true", help="replace the session files already in --out")
    record.add_argument("--no-progress", action="store_true", help="no progress bar")


def _config(args: argparse.Namespace) -> object:
    import json

    from pydantic import ValidationError

    from hippo_nav._core import HippoNavError
    from hippo_nav.io.errors import os_error_words
    from hippo_nav.openfield import OpenFieldConfig

    given: dict[str, object] = {}
    if args.config:
        try:
            with open(args.config) as f:
                given = json.load(f)
        except OSError as err:
            raise HippoNavError(f"--config: {os_error_words(err)}") from None
        except ValueError as err:  # not JSON
            raise HippoNavError(f"--config {args.config}: not JSON ({err})") from None
        if not isinstance(given, dict):
            raise HippoNavError(f"--config {args.config}: must hold a JSON object of OpenFieldConfig fields")
    flags = {
        "arena_shape": args.arena_shape,
        "arena_size_m": args.arena_size,
        "duration_s": args.duration,
        "torus_period_m": args.period,
        "speed_mean_m_s": args.speed_mean,
        "seed": args.seed,
        "lesion": args.lesion,
    }
    given |= {k: v for k, v in flags.items() if v is not None}
    if args.no_landmarks:
        given["landmarks"] = {**dict(given.get("landmarks") or {}), "enabled": False}  # type: ignore[call-overload]
    try:
        return OpenFieldConfig.model_validate(given)
    except ValidationError as err:
        first = err.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise HippoNavError(f"session setting {where}: {first['msg']}") from None


def command(args: argparse.Namespace) -> int:
    from hippo_nav.openfield import record_session, trajectory_from_csv
    from hippo_nav.openfield.folder import SessionFolder

    config = _config(args)
    if args.lesion_study:
        return _lesion_study(args, config)
    folder = SessionFolder(args.out, overwrite=args.overwrite)  # checked before minutes of simulation
    trajectory = trajectory_from_csv(args.trajectory, config.step_dt_s) if args.trajectory else None  # type: ignore[attr-defined]
    bar = None
    if not args.no_progress and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=0, unit="sample", desc="session", file=sys.stderr)

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.total = total
            bar.n = done
            bar.refresh()

    try:
        recording = record_session(config, trajectory, progress)  # type: ignore[arg-type]
    finally:
        if bar is not None:
            bar.close()
    written = folder.write(
        recording,
        analysis=not args.no_analysis,
        units_per_population=args.units,
        shuffles=args.shuffles,
        seed=config.seed,  # type: ignore[attr-defined]
    )
    for path in written:
        print(f"wrote {path}")
    return 0


def _lesion_study(args: argparse.Namespace, config: object) -> int:
    import json

    from hippo_nav._core import HippoNavError
    from hippo_nav.io.atomic import output_folder, write_text
    from hippo_nav.openfield.lesions import run_lesion_study, write_lesion_figure

    out = output_folder(args.out, "the lesion study")
    if (out / "lesions.json").exists() and not args.overwrite:
        raise HippoNavError(
            f"--out {out} already holds a lesion study (lesions.json); give another folder or --overwrite"
        )
    first = config.seed  # type: ignore[attr-defined]
    seeds = list(range(first, first + args.lesion_study))

    def progress(done: int, total: int) -> None:
        if not args.no_progress:
            print(f"session {done} of {total}", file=sys.stderr)

    study = run_lesion_study(
        config,  # type: ignore[arg-type]
        seeds,
        units=args.units,
        shuffles=args.shuffles,
        workers=args.workers,
        progress=progress,
    )
    print(f"wrote {write_text(out / 'lesions.json', json.dumps(study.to_dict(), indent=2) + chr(10))}")
    for path in write_lesion_figure(study, out / "lesions"):
        print(f"wrote {path}")
    return 0
