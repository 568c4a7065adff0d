"""`hippo-nav figures`: the paper's theory figures, or the synthetic street at each appearance level."""

from __future__ import annotations

import argparse

HELP = "write the paper's theory figures (or the appearance levels of the synthetic street) as PNG files"
DESCRIPTION = (
    "Writes the paper's theory figures (the 1-D theory of multi-resolution grid codes) as PNG "
    "files; with --appearance, appearance_levels.png instead: one place of the synthetic street at each "
    "appearance level, on pass 0 and pass 1 (docs/render.md)."
)


def add_arguments(figures: argparse.ArgumentParser) -> None:
    figures.add_argument("--out", default="runs/figures", help="folder for the PNG files")
    figures.add_argument(
        "--appearance",
        action="store_true",
        help="write appearance_levels.png (the synthetic street at each appearance level) instead",
    )


def command(args: argparse.Namespace) -> int:
    from hippo_nav._core import HippoNavError
    from hippo_nav.io.atomic import output_folder

    out = output_folder(args.out, "the PNG files")  # checked before the figures are drawn (seconds)
    try:
        if args.appearance:
            from hippo_nav.synthetic.figures import appearance_figure

            print(f"wrote {appearance_figure(out / 'appearance_levels.png')}")
            return 0
        from hippo_nav.theory.figures import write_all_figures

        write_all_figures(out)
    except OSError as err:
        raise HippoNavError(f"{err.filename or out}: {err.strerror or err}") from None
    return 0
