"""Which descriptor and sequence length point a `sequence` closure at the place (renders at `strong`).

    python tests/benchmarks/sequence_recognition.py --dataset runs/renders_strong --sequence 06 05 \\
        [--lengths 1 5 10 15] [--region-m 100] [--spacing-m 2]

Along a rendered KITTI sequence (`hippo-nav render --appearance strong`), views are sampled every
`--spacing-m` of true travel, as the proposer samples them by odometry. A query is a sample with an earlier one
(at least 60 m back along the path) within 5 m and 45° of it: a revisit. Its candidates are the earlier samples
within `--region-m` of it and 45° of its heading (the search region of a drifted odometry, centred on the
truth) whose `length` views behind them exist. Each candidate's sequence distance is the mean over the last
`length` views of one minus the cosine of the two descriptors (less the mean descriptor of the sequence); the
rank of the best true candidate (within 5 m) among them says whether the proposer's shortlist would hold it:
top-1, top-3 and top-6 shares of the queries, and the mean number of candidates (chance is k over that).

Descriptors: `edge_layout` (the proposer's: contrast-stretched Canny edges of the upper image, 64 × 16) and
the paper's template (`TemplateViewCells.template_from_image`, patch-normalised 64 × 24 thumbnail).
Not a test (no assertions; pytest does not collect it): a reproducible experiment; prints a Markdown table.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
from hippo_nav.closure.sequence import edge_layout
from hippo_nav.view_cells.template import TemplateViewCells

MIN_GAP_M = 60.0
TRUE_M = 5.0
MAX_HEADING_RAD = np.radians(45.0)


def samples_by_travel(poses: np.ndarray, spacing_m: float) -> np.ndarray:
    """Frame indices every `spacing_m` of planar travel."""
    steps = np.linalg.norm(np.diff(poses[:, [0, 2], 3], axis=0), axis=1)
    travel = np.r_[0.0, np.cumsum(steps)]
    marks = np.floor(travel / spacing_m)
    return np.flatnonzero(np.r_[True, np.diff(marks) > 0])


def ranks(
    descriptors: np.ndarray, poses: np.ndarray, length: int, region_m: float
) -> tuple[np.ndarray, float]:
    """(rank of the best true candidate for each query, mean candidates per query)."""
    xz = poses[:, [0, 2], 3]
    forward = poses[:, [0, 2], 2]
    heading = np.arctan2(forward[:, 0], forward[:, 1])
    travel = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xz, axis=0), axis=1))]
    distance = np.linalg.norm(xz[:, None] - xz[None], axis=2)
    turn = np.abs((heading[:, None] - heading[None] + np.pi) % (2 * np.pi) - np.pi)
    region = (
        ((travel[:, None] - travel[None]) >= MIN_GAP_M) & (distance <= region_m) & (turn < MAX_HEADING_RAD)
    )
    region[:, : length - 1] = False
    true = region & (distance <= TRUE_M)
    x = descriptors - descriptors.mean(axis=0)
    x /= np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-9)
    single = 1.0 - x @ x.T
    found, sizes = [], []
    for q in np.flatnonzero(true.any(axis=1)):
        if q < length - 1:
            continue
        ends = np.flatnonzero(region[q])
        score = np.mean([single[q - k, ends - k] for k in range(length)], axis=0)
        best_true = score[true[q, ends]].min()
        found.append(int((score < best_true).sum()))
        sizes.append(len(ends))
    return np.array(found), float(np.mean(sizes)) if sizes else 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--sequence", nargs="+", required=True)
    parser.add_argument("--lengths", nargs="+", type=int, default=[1, 5, 10, 15])
    parser.add_argument("--region-m", type=float, default=100.0)
    parser.add_argument("--spacing-m", type=float, default=2.0)
    args = parser.parse_args()
    template = TemplateViewCells()
    print(f"region {args.region_m:g} m, a view every {args.spacing_m:g} m\n")
    print("| seq | descriptor | length | queries | candidates | top-1 | top-3 | top-6 |")
    print("|---|---|---|---|---|---|---|---|")
    for sequence in args.sequence:
        poses = np.loadtxt(args.dataset / "poses" / f"{sequence}.txt").reshape(-1, 3, 4)
        chosen = samples_by_travel(poses, args.spacing_m)
        images = [
            cv2.imread(
                str(args.dataset / "sequences" / sequence / "image_0" / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE
            )
            for i in chosen
        ]
        described = {
            "edge_layout": np.array([edge_layout(im) for im in images], np.float64),
            "template": np.array([template.template_from_image(im).ravel() for im in images], np.float64),
        }
        for name, descriptors in described.items():
            for length in args.lengths:
                found, size = ranks(descriptors, poses[chosen], length, args.region_m)
                shares = " | ".join(f"{np.mean(found < k):.2f}" for k in (1, 3, 6))
                print(f"| {sequence} | {name} | {length} | {len(found)} | {size:.0f} | {shares} |")


if __name__ == "__main__":
    main()
