"""`hippo-nav vocabulary`: the word view cells' vocabulary, trained on a folder of images or remade from the
renders."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np


HELP = "train the word view cells' vocabulary (on your images, or remake the shipped one)"
DESCRIPTION = (
    "Trains a vocabulary of binary words for the word view cells (docs/views.md) on the ORB "
    "features of the images in --images (every PNG/JPEG in the folder, gray or colour), or, without "
    "--images, on the procedural street renders the shipped vocabulary was trained on (the result is "
    "then the shipped file). Use it with the config's view_words.vocabulary = FILE. An existing --out file "
    "is kept unless --overwrite is given (checked before training, which takes a while)."
)


def add_arguments(vocabulary: argparse.ArgumentParser) -> None:
    vocabulary.add_argument("--out", required=True, metavar="FILE", help="vocabulary file to write")
    vocabulary.add_argument(
        "--overwrite",
        action="store_true",
        help="replace --out when it exists (default: off: an existing file is an error, nothing is trained)",
    )
    vocabulary.add_argument(
        "--images", metavar="DIR", default=None, help="folder of training images (default: the renders)"
    )
    from hippo_nav.cli.common import MAX_FRAME, MAX_SEED, bounded_int

    vocabulary.add_argument(
        "--every", type=bounded_int(1, MAX_FRAME), default=1, metavar="N", help="use every Nth image"
    )
    # The word tree's limits are the Rust trainer's (hippo_views::words::Vocabulary::train).
    vocabulary.add_argument(
        "--branching",
        type=bounded_int(2, 64),
        default=10,
        help="children per node of the word tree (2 to 64)",
    )
    vocabulary.add_argument(
        "--levels", type=bounded_int(1, 8), default=4, help="depth of the word tree (1 to 8)"
    )
    vocabulary.add_argument(
        "--seed",
        type=bounded_int(0, MAX_SEED),
        default=0,
        help=f"seed of the k-means clustering (0 to {MAX_SEED})",
    )


def command(args: argparse.Namespace) -> int:
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
    out = Path(args.out)
    # Before training (minutes on a big folder): a refusal must come first, and never after the work.
    if out.is_dir():
        raise HippoNavError(
            f"--out {out}: a folder; give the vocabulary file's name (e.g. {out / 'mine.voc'})"
        )
    if (out.exists() or out.is_symlink()) and not args.overwrite:
        raise HippoNavError(f"--out {out}: the file exists; give --overwrite to replace it, or another --out")
    vocabulary = train_vocabulary(images, branching=args.branching, levels=args.levels, seed=args.seed)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:  # the folder and the reason, not the system's "[Errno …]"
        raise HippoNavError(f"--out {out}: cannot create {out.parent} ({err.strerror or err})") from None
    vocabulary.save(out)  # atomic: a link planted at --out is replaced, never written through
    print(
        f"wrote {out}: {len(vocabulary)} words (branching {vocabulary.branching}, {vocabulary.levels} levels)"
    )
    return 0


def _read_gray(path: Path) -> np.ndarray:
    import cv2

    from hippo_nav.datasets.common import read_image_file

    # Decoded from its bytes: any file name works (OpenCV's own reader crashes on some), sizes are checked.
    return read_image_file(path, cv2.IMREAD_GRAYSCALE)
