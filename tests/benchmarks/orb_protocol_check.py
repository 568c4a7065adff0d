"""The protocol check of docs/results.md: our ATE of the ORB-SLAM3 odometry files against the real KITTI ground
truth, beside the figures Hybrid-NeuroSLAM published for the same files (so the back-ends of the whole-sequence
sweep, `docs/sweeps/whole_sequences.toml`, are compared on the same footing).

    python tests/benchmarks/orb_protocol_check.py --kitti ../shared/data/kitti_odometry

Not a test (no assertions; pytest does not collect it): a reproducible measurement.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ORB_FILES = {"00": "kitti00_ORBSLAM.txt", "05": "kitti05_ORBSLAM.txt"}
PUBLISHED_ODOMETRY_ATE_M = {"00": 4.26, "05": 2.37}  # Hybrid-NeuroSLAM's table, ORB-SLAM3 odometry alone


def protocol_check(kitti: Path) -> dict[str, dict[str, float]]:
    from hippo_nav.io import read_kitti_poses
    from hippo_nav.metrics import ate_rmse

    out = {}
    for sequence, name in ORB_FILES.items():
        truth = read_kitti_poses(kitti / "poses" / f"{sequence}.txt")
        orb = read_kitti_poses(kitti / ".." / "peer_trajectories" / "hybrid_neuroslam_orbslam3" / name)
        orb = orb[: len(truth)]  # 00's file has 3 poses more than the sequence
        out[sequence] = {
            "ate_2d_m": ate_rmse(truth, orb, planar=True, align="se3"),
            "ate_3d_m": ate_rmse(truth, orb, planar=False, align="se3"),
            "published_m": PUBLISHED_ODOMETRY_ATE_M[sequence],
        }
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--kitti", type=Path, required=True, help="KITTI root with poses/ (peer_trajectories beside it)"
    )
    print(json.dumps(protocol_check(parser.parse_args(argv).kitti), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
