"""Is the ground truth or the VO wrong? The camera's rotation from the images alone, against both.

    python tests/benchmarks/ground_truth_rotation.py --data ../shared/data [--sequences 06 01]

For each real KITTI sequence of `--data` (frames 0–50), the rotation of the camera is chained from the
5-point essential matrix of consecutive images (SIFT, ratio test 0.7, RANSAC at 0.5 px, OpenCV): an estimate
that uses neither the stereo calibration nor our VO, once from the left images and once from the right. Where
the ground truth is filled in with a constant motion (`metrics.interpolated_steps`: KITTI 06 frames 0–11), the
question is whose rotation to believe there. Printed every 5 frames: the rotation error (rotation vector in
the camera frame, degrees: x pitch, y yaw, z roll) of each chain and of the default VO against the ground
truth. Writes `ground_truth_rotation.json` under `--out`. Not a test (no assertions): a measurement.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

import cv2
import numpy as np
from hippo_nav.datasets import KittiOdometry
from hippo_nav.metrics import interpolated_steps
from hippo_nav.vo import VoParams, run_odometry

SIFT = cv2.SIFT_create(4000)


def camera_from_previous_rotation(previous: np.ndarray, current: np.ndarray, camera_matrix: np.ndarray):
    """Rotation taking the previous camera's coordinates to the current one's (3×3), from the images alone."""
    kp_a, desc_a = SIFT.detectAndCompute(previous, None)
    kp_b, desc_b = SIFT.detectAndCompute(current, None)
    matches = cv2.BFMatcher(cv2.NORM_L2).knnMatch(desc_a, desc_b, k=2)
    good = [m for m, n in matches if m.distance < 0.7 * n.distance]
    a = np.float64([kp_a[m.queryIdx].pt for m in good])
    b = np.float64([kp_b[m.trainIdx].pt for m in good])
    essential, inliers = cv2.findEssentialMat(a, b, camera_matrix, cv2.RANSAC, 0.99999, 0.5)
    _, rotation, _, _ = cv2.recoverPose(essential, a, b, camera_matrix, mask=inliers)
    return rotation


def error_deg(truth: np.ndarray, rotation: np.ndarray) -> list[float]:
    """Rotation vector (degrees, camera frame) of truthᵀ · rotation."""
    rotation_vector, _ = cv2.Rodrigues(truth.T @ rotation)
    return np.degrees(rotation_vector[:, 0]).round(3).tolist()


def one(data: Path, sequence: str) -> dict:
    dataset = KittiOdometry(data / "kitti_odometry", sequence)
    frames = [dataset[i] for i in range(len(dataset))]
    camera_matrix = np.asarray(dataset.calibration.K, dtype=np.float64)
    gt = dataset.ground_truth()
    gt = np.linalg.inv(gt[0]) @ gt
    vo, _ = run_odometry(dataset, VoParams())
    chains = {}
    for side in ("left", "right"):
        world_from_camera = [np.eye(3)]
        for prev, cur in itertools.pairwise(frames):
            rotation = camera_from_previous_rotation(getattr(prev, side), getattr(cur, side), camera_matrix)
            world_from_camera.append(world_from_camera[-1] @ rotation.T)
        chains[side] = world_from_camera
    flagged = np.flatnonzero(interpolated_steps(gt))
    rows = []
    for i in range(0, len(frames), 5):
        rows.append(
            {
                "frame": i,
                "left_images": error_deg(gt[i][:3, :3], chains["left"][i]),
                "right_images": error_deg(gt[i][:3, :3], chains["right"][i]),
                "vo": error_deg(gt[i][:3, :3], vo[i][:3, :3]),
            }
        )
        print(sequence, json.dumps(rows[-1]), flush=True)
    return {"interpolated_steps": flagged.tolist(), "rows": rows}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--data", type=Path, required=True, help="the shared data folder (kitti_odometry/ inside)"
    )
    parser.add_argument("--sequences", nargs="+", default=["06", "01"])
    parser.add_argument("--out", type=Path, default=Path("runs/ground_truth_rotation"))
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    results = {seq: one(args.data, seq) for seq in args.sequences}
    (args.out / "ground_truth_rotation.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
