"""Whole KITTI sequences: the back-end against its odometry, side by side with the published back-ends.

Renders the synthetic stereo street along the full ground truth of each sequence (`hippo-nav render`,
resumable), then runs the whole system on it with several odometries and closure modes, and writes a
Markdown table (the source of docs/results.md) plus every run's results folder.

    python tests/benchmarks/whole_sequences.py --kitti ../shared/data/kitti_odometry \\
        --renders runs/renders --out runs/whole [--sequences 00 05] [--variants vo drift orb] \\
        [--config '{"parts": {"view_cells": "template"}}'] [--appearance strong]

Variants (each a run of `hippo_nav.pipeline.Pipeline` on the render):
- `vo`: the built-in stereo VO; geometric loop closure (the default config).
- `drift`: the ground truth made to drift like a real odometry (1 % scale, 0.02°/frame yaw bias,
  `hippo_nav.synthetic.drifting_odometry`), replayed; geometric closure.
- `orb`: stereo ORB-SLAM3 odometry as fed to brain-inspired back-ends by Hybrid-NeuroSLAM (00 and 05
  only; `peer_trajectories/hybrid_neuroslam_orbslam3` of the shared data), replayed.
- `<odometry>-ratslam`: the same odometry with the paper's RatSLAM-style closure and relaxation.
Not a test (no assertions; pytest does not collect it): a reproducible experiment.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ORB_FILES = {"00": ("kitti00_ORBSLAM.txt", "start"), "05": ("kitti05_ORBSLAM.txt", "exact")}
PUBLISHED = {  # Hybrid-NeuroSLAM's table (ATE, m): VO alone, + RatSLAM, + NeuroBayesSLAM
    "00": (4.26, 3.80, 2.41),
    "02": (8.35, 6.76, 8.32),
    "05": (2.37, 6.57, 3.81),
    "08": (7.35, 6.86, 6.85),
}
RATSLAM = {
    "map": {"closure": "RatSlam", "online_correction": "Relaxation"},
    "correction": {"method": "relaxation"},
}


def odometry_for(variant: str, sequence: str, render_root: Path, kitti: Path, work: Path):
    """(odometry argument of `run`, description) of a variant."""
    from hippo_nav.io import read_kitti_poses, write_kitti_poses
    from hippo_nav.synthetic import drifting_odometry
    from hippo_nav.vo.replay import replay_odometry

    base = variant.split("-")[0]
    if base == "vo":
        return None, "built-in stereo VO"
    if base == "drift":
        truth = read_kitti_poses(render_root / "poses" / f"{sequence}.txt")
        path = write_kitti_poses(work / f"drift_{sequence}.txt", drifting_odometry(truth))
        return replay_odometry(path), "ground truth drifted 1 %, 0.02°/frame"
    if base == "orb":
        name, align = ORB_FILES[sequence]
        path = kitti / ".." / "peer_trajectories" / "hybrid_neuroslam_orbslam3" / name
        return replay_odometry(path, align=align), "ORB-SLAM3 stereo (Hybrid-NeuroSLAM)"
    raise SystemExit(f"unknown variant {variant!r}")


def published_protocol_check(kitti: Path) -> dict[str, dict[str, float]]:
    """Our ATE of the ORB-SLAM3 files against the real KITTI ground truth (the published VO figures)."""
    from hippo_nav.io import read_kitti_poses
    from hippo_nav.metrics import ate_rmse

    out = {}
    for sequence, (name, _) in ORB_FILES.items():
        gt = read_kitti_poses(kitti / "poses" / f"{sequence}.txt")
        orb = read_kitti_poses(kitti / ".." / "peer_trajectories" / "hybrid_neuroslam_orbslam3" / name)[
            : len(gt)
        ]
        out[sequence] = {
            "ate_2d_m": ate_rmse(gt, orb, planar=True, align="se3"),
            "ate_3d_m": ate_rmse(gt, orb, planar=False, align="se3"),
            "published_m": PUBLISHED[sequence][0],
        }
    return out


def run_one(sequence: str, variant: str, args: argparse.Namespace) -> dict:
    from hippo_nav.pipeline import config_from_dict, run

    out = args.out / f"{sequence}_{variant}"
    metrics_path = out / "metrics.json"
    if metrics_path.is_file() and not args.again:
        metrics = json.loads(metrics_path.read_text())
        if not metrics.get("interrupted"):  # a run stopped early (Ctrl-C, SIGTERM) is run again
            return metrics
    odometry, _ = odometry_for(variant, sequence, args.renders, args.kitti, args.out)
    config = {**args.config, "output": {"figures": variant == "vo"}}
    if variant.endswith("-ratslam"):
        config.update(RATSLAM)
    started = time.perf_counter()
    result = run(
        out, dataset=args.renders, sequence=sequence, config=config_from_dict(config), progress=True,
        odometry=odometry,
    )  # fmt: skip
    result.metrics["wall_s"] = time.perf_counter() - started
    return result.metrics


def table(rows: list[tuple[str, str, dict]]) -> str:
    head = (
        "| seq | odometry, closure | frames | ATE 2-D odometry / online / corrected / neural (m) | "
        "ATE 3-D odometry / corrected (m) | closures (true) | precision | recall | frames/s |\n"
        "|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for sequence, variant, m in rows:
        e = m["errors"]
        q = m.get("closure_quality", {})
        precision = "–" if q.get("precision") is None else f"{q['precision']:.2f}"
        recall = "–" if q.get("recall") is None else f"{q['recall']:.2f}"
        two_d = " / ".join(f"{e[n]['ate_2d_m']:.2f}" for n in ("vo", "online", "corrected", "neural"))
        three_d = f"{e['vo']['ate_3d_m']:.2f} / {e['corrected']['ate_3d_m']:.2f}"
        lines.append(
            f"| {sequence} | {variant} | {m['frames']} | {two_d} | {three_d} | "
            f"{q.get('closures', 0)} ({q.get('true_closures', 0)}) | {precision} | {recall} | "
            f"{m['timing']['frames_per_s']:.1f} |"
        )
    return head + "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--kitti", type=Path, required=True, help="KITTI root with poses/ and sequences/*/times.txt"
    )
    parser.add_argument("--renders", type=Path, required=True, help="KITTI root the renders go to")
    parser.add_argument("--out", type=Path, required=True, help="folder for the runs and the table")
    parser.add_argument("--sequences", nargs="+", default=["00", "02", "05", "06", "08"])
    parser.add_argument("--variants", nargs="+", default=["vo", "drift", "orb", "vo-ratslam", "orb-ratslam"])
    parser.add_argument("--again", action="store_true", help="rerun even where metrics.json exists")
    parser.add_argument("--size", default="320x96", metavar="WxH", help="render size (default 320x96)")
    parser.add_argument(
        "--appearance",
        choices=["same", "mild", "strong"],
        default="same",
        help="how much a place changes between passes (docs/render.md); use one --renders root per level",
    )
    parser.add_argument(
        "--config",
        type=json.loads,
        default={},
        metavar="JSON",
        help='config sections every run starts from, e.g. \'{"parts": {"view_cells": "template"}}\'',
    )
    args = parser.parse_args(argv)
    from hippo_nav.synthetic import render_kitti

    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for sequence in args.sequences:
        render_kitti(
            args.kitti, sequence, args.renders, progress=True, appearance=args.appearance,
            image_size_px=tuple(int(v) for v in args.size.split("x")),
        )  # fmt: skip
        for variant in args.variants:
            if variant.startswith("orb") and sequence not in ORB_FILES:
                continue
            metrics = run_one(sequence, variant, args)
            rows.append((sequence, variant, metrics))
            print(table(rows[-1:]), flush=True)
    check = published_protocol_check(args.kitti)
    report = {"protocol_check": check, "runs": {f"{s}_{v}": m for s, v, m in rows}}
    (args.out / "whole_sequences.json").write_text(json.dumps(report, indent=2, default=float) + "\n")
    (args.out / "whole_sequences.md").write_text(table(rows))
    print(table(rows))
    print(json.dumps(check, indent=2))
    return 0


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    sys.exit(main())
