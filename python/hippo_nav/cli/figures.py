"""`hippo-nav figures`: the paper's theory figures, the synthetic street at each appearance level, or the
networks of one run measured and drawn from its results folder (`--run DIR`)."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = (
    "write the paper's theory figures, the synthetic street's appearance levels, or (--run DIR) a run's "
    "neural figures"
)
DESCRIPTION = (
    "Writes the paper's theory figures (the 1-D theory of multi-resolution grid codes) as PNG "
    "files; with --appearance, appearance_levels.png instead: one place of the synthetic street at each "
    "appearance level, on pass 0 and pass 1 (docs/render.md). With --run DIR, the networks of that `hippo-nav "
    "run` results folder, from its recording (recording.npz, module_phase.npz) without running again: rate "
    "maps of example units per grid module and of the place torus on the true positions and folded onto "
    "each module's spacing P/k, each module's decoded phase against the true position modulo P/k with "
    "its circular error, and the lab's measures (grid scores against a shuffle test, spacing, information, "
    "fields; head-direction tuning) on the positions folded onto two spacings; with --topology the "
    "persistent homology of each population too (PNG and PDF, and neural_measures.json; docs/neuro.md)."
)


def add_arguments(figures: argparse.ArgumentParser) -> None:
    figures.add_argument(
        "--out",
        default=None,
        help="folder for the figures (default: runs/figures, or DIR/figures with --run)",
    )
    which = figures.add_mutually_exclusive_group()
    which.add_argument(
        "--appearance",
        action="store_true",
        help="write appearance_levels.png (the synthetic street at each appearance level) instead",
    )
    which.add_argument(
        "--run",
        metavar="DIR",
        default=None,
        help="a `hippo-nav run` results folder: draw its networks' rate maps and decoded phases instead",
    )
    figures.add_argument(
        "--topology",
        action="store_true",
        help="with --run: also the persistent homology of each grid module and the ring (seconds to a "
        "minute; needs 600 moving frames)",
    )


def command(args: argparse.Namespace) -> int:
    from hippo_nav._core import HippoNavError
    from hippo_nav.io.atomic import output_folder

    if args.run is not None:
        return _run_figures(Path(args.run), args.out, args.topology)
    if args.topology:
        raise HippoNavError("--topology measures a run's recording: give --run DIR with it")
    if args.out is not None and not str(args.out).strip():
        raise HippoNavError("--out is empty: give the folder the figures go into (default: runs/figures)")
    out = output_folder(args.out or "runs/figures", "the PNG files")  # checked before the figures (seconds)
    try:
        if args.appearance:
            from hippo_nav.synthetic.figures import appearance_figure

            print(f"wrote {appearance_figure(out / 'appearance_levels.png')}")
            return 0
        from hippo_nav.theory.figures import write_all_figures

        written = write_all_figures(out)
    except OSError as err:
        raise HippoNavError(f"{err.filename or out}: {err.strerror or err}") from None
    print(f"wrote {', '.join(p.name for p in written)} into {out}")  # as the other two modes say
    return 0


def _run_figures(run: Path, out_arg: str | None, topology: bool) -> int:
    from hippo_nav._core import HippoNavError
    from hippo_nav.io.atomic import output_folder
    from hippo_nav.report.neural import load_run_recording, write_neural_figures

    load_run_recording(run)  # a folder without a recording is refused before any folder is made
    out = output_folder(out_arg if out_arg is not None else run / "figures", "the figures")
    try:
        written = write_neural_figures(run, out, topology=topology)
    except OSError as err:
        raise HippoNavError(f"{err.filename or out}: {err.strerror or err}") from None
    print(f"wrote {', '.join(p.name for p in written)} into {out}")
    return 0
