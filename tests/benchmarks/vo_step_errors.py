"""Where a VO's heading goes wrong, step by step (docs/results.md, "Where 02's error comes from").

    python tests/benchmarks/vo_step_errors.py RUN [RUN ...] [--bin 50] [--frames A:B]

RUN is a folder written by `hippo-nav run` (its `trajectory_vo.kitti.txt` and `ground_truth.kitti.txt`). Each
step's error is the VO's step seen from the true one (`true_step⁻¹ · vo_step`, camera frame: x right, z
forward): its yaw (about the camera's y axis), its sideways (x) and its forward (z) part. Printed per RUN:
- per bin of frames: the true turn, the heading error gained, and the frames' speed;
- over `--frames` (default all): the mean and spread of the yaw error a step, the sideways error a step, and
  their correlation (near −1: a step's yaw error comes with the sideways error that explains the same image
  motion — heading and sideways motion are told apart badly);
- the yaw error by how fast the truth turns (sharp turns, gentle ones, straight road).
Frame numbers are the sequence's (`frames.csv`). Not a test (no assertions; pytest does not collect it).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
from hippo_nav.io import read_kitti_poses
from hippo_nav.metrics import rigid_inverse

_TURN_CLASSES_DEG = ((-180.0, -0.5), (-0.5, -0.1), (-0.1, 0.1), (0.1, 0.5), (0.5, 180.0))


def _yaw_deg(transforms: np.ndarray) -> np.ndarray:
    """Rotation about the camera's y axis (down), degrees, of (n, 4, 4) transforms."""
    return np.degrees(np.arctan2(transforms[:, 0, 2], transforms[:, 2, 2]))


def step_errors(ground_truth: np.ndarray, vo: np.ndarray) -> dict[str, np.ndarray]:
    """Per step i → i+1 of (n, 4, 4) poses: the true turn (deg), speed (m a frame) and the VO step's error
    (yaw deg, sideways m, forward m)."""
    true_step = rigid_inverse(ground_truth[:-1]) @ ground_truth[1:]
    vo_step = rigid_inverse(vo[:-1]) @ vo[1:]
    error = rigid_inverse(true_step) @ vo_step
    return {
        "turn_deg": _yaw_deg(true_step),
        "speed_m": np.linalg.norm(true_step[:, :3, 3], axis=1),
        "yaw_deg": _yaw_deg(error),
        "sideways_m": error[:, 0, 3],
        "forward_m": error[:, 2, 3],
    }


def _frame_numbers(run: Path, count: int) -> np.ndarray:
    frames_csv = run / "frames.csv"
    if not frames_csv.exists():
        return np.arange(count)
    with frames_csv.open() as f:
        return np.array([int(row["frame"]) for row in csv.DictReader(f)])[:count]


def report(run: Path, bin_frames: int, frames: tuple[int, int] | None) -> str:
    ground_truth = read_kitti_poses(run / "ground_truth.kitti.txt")
    vo = read_kitti_poses(run / "trajectory_vo.kitti.txt")
    errors = step_errors(ground_truth, vo)
    numbers = _frame_numbers(run, len(ground_truth))[:-1]  # a step is named by its first frame
    lines = [f"## {run}", "", "| frames | true turn (deg) | heading error gained (deg) | speed (m a frame) |"]
    lines.append("|---|---|---|---|")
    for start in range(0, len(numbers), bin_frames):
        part = slice(start, start + bin_frames)
        lines.append(
            f"| {numbers[part][0]}–{numbers[part][-1] + 1} | {errors['turn_deg'][part].sum():+.2f} | "
            f"{errors['yaw_deg'][part].sum():+.2f} | {errors['speed_m'][part].mean():.2f} |"
        )
    chosen = np.ones(len(numbers), bool)
    if frames is not None:
        chosen = (numbers >= frames[0]) & (numbers < frames[1])
    yaw, sideways = errors["yaw_deg"][chosen], errors["sideways_m"][chosen]
    correlation = float(np.corrcoef(yaw, sideways)[0, 1]) if len(yaw) > 2 else float("nan")
    where = "all steps" if frames is None else f"steps from frames {frames[0]}–{frames[1]}"
    forward_cm = 100 * errors["forward_m"][chosen].mean()
    summary = (
        f"{where} ({int(chosen.sum())}): yaw error a step {yaw.mean():+.4f}° (sd {yaw.std():.4f}°), sideways "
        f"{100 * sideways.mean():+.2f} cm (sd {100 * sideways.std():.2f} cm), forward {forward_cm:+.2f} cm; "
        f"correlation of yaw and sideways {correlation:+.2f}"
    )
    lines += [
        "",
        summary,
        "",
        "| true turn a step (deg) | steps | yaw error a step (mean, deg) | summed (deg) | speed (m a frame) |",
        "|---|---|---|---|---|",
    ]
    for low, high in _TURN_CLASSES_DEG:
        in_class = chosen & (errors["turn_deg"] > low) & (errors["turn_deg"] <= high)
        if in_class.any():
            lines.append(
                f"| ({low:g}, {high:g}] | {int(in_class.sum())} | {errors['yaw_deg'][in_class].mean():+.4f} | "
                f"{errors['yaw_deg'][in_class].sum():+.2f} | {errors['speed_m'][in_class].mean():.2f} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="folders written by hippo-nav run")
    parser.add_argument("--bin", type=int, default=50, help="frames a row of the first table (default 50)")
    parser.add_argument("--frames", help="A:B, the steps from frames A to B for the statistics (default all)")
    args = parser.parse_args(argv)
    frames = None
    if args.frames:
        first, last = (int(x) for x in args.frames.split(":"))
        frames = (first, last)
    for run in args.runs:
        print(report(run, max(1, args.bin), frames))
        print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
