"""`hippo-nav render`: a synthetic stereo street along a KITTI ground truth, written as a KITTI root."""

from __future__ import annotations

import argparse
import sys

HELP = "render the synthetic stereo street along a KITTI ground truth into a KITTI root"
DESCRIPTION = (
    "Renders a synthetic stereo sequence along ROOT/poses/NN.txt with the timestamps of "
    "ROOT/sequences/NN/times.txt into a KITTI root at --out (images, calib.txt, times.txt, poses/NN.txt). "
    "The camera keeps a fixed height above the road; with --appearance same (the default) every pass sees "
    "a street the same way, with mild or strong a place looks different on each pass (light, shadows, "
    "shop fronts and posters, parked cars, noise, blur, vignetting, another lane; docs/render.md). "
    "Resumable: frames already written are kept. Run it afterwards with "
    "`hippo-nav run --dataset OUT --sequence NN`."
)


def add_arguments(render: argparse.ArgumentParser) -> None:
    from hippo_nav.synthetic.appearance import APPEARANCE_LEVELS

    render.add_argument("--kitti", metavar="ROOT", required=True, help="KITTI root with poses/NN.txt")
    render.add_argument("--sequence", required=True, help="sequence number, e.g. 00")
    from hippo_nav.cli.common import MAX_FRAME, MAX_SEED, MAX_THREADS, bounded_int, image_size
    from hippo_nav.synthetic.render import MAX_SIDE_PX

    render.add_argument(
        "--start", type=bounded_int(0, MAX_FRAME - 1), default=None, help="first frame to render (default 0)"
    )
    render.add_argument(
        "--stop", type=bounded_int(1, MAX_FRAME), default=None, help="frame to stop before (default: all)"
    )
    render.add_argument("--out", required=True, help="KITTI root to write (created if missing)")
    render.add_argument(
        "--size",
        type=image_size(16, MAX_SIDE_PX),
        default="320x96",
        metavar="WxH",
        help=f"image size in pixels, each side 16 to {MAX_SIDE_PX} (default 320x96, KITTI's aspect)",
    )
    render.add_argument(
        "--seed",
        type=bounded_int(0, MAX_SEED),
        default=0,
        help=f"texture seed of the synthetic world, 0 to {MAX_SEED} (default 0)",
    )
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
    render.add_argument(
        "--workers", type=bounded_int(1, MAX_THREADS), default=2, help="rendering threads (default 2)"
    )
    render.add_argument("--no-progress", action="store_true", help="no progress bar")


def command(args: argparse.Namespace) -> int:
    from hippo_nav.synthetic import render_kitti

    try:
        width, height = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        print(f"hippo-nav: error: --size {args.size!r}: give WIDTHxHEIGHT, e.g. 320x96", file=sys.stderr)
        return 2
    try:
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
    except OSError as err:  # e.g. --out under a file: the path and the reason, not the system's "[Errno …]"
        from hippo_nav._core import HippoNavError

        raise HippoNavError(f"{err.filename or args.out}: {err.strerror or err}") from None
    print(f"rendered sequence {args.sequence} into {root}; run it with: "
          f"hippo-nav run --dataset {root} --sequence {args.sequence}")  # fmt: skip
    return 0
