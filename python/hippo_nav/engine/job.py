"""The engine job: drive the spatial memory along a sequence's ground-truth planar motion and write what
the networks decoded (trajectories, metrics, the neural state figure). It shows the networks' path
integration on real trajectory shapes without a camera; the stereo SLAM pipeline adds VO, view cells and
the experience map on top.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.engine.config import EngineConfig
from hippo_nav.engine.drive import drive, planar_odometry, planar_track
from hippo_nav.engine.network import SpatialMemory


def _sequence(kitti_root: str | None, sequence: str, start: int | None, stop: int | None, stride: int):
    if kitti_root is None:
        from hippo_nav.synthetic import DEMO_FRAMES, loop_trajectory

        poses = loop_trajectory(DEMO_FRAMES)
        return "synthetic demo loop", poses, 0.1 * np.arange(len(poses))
    from hippo_nav.io import read_kitti_poses

    # Only the motion is needed here, not the images: the pose file and the frame times.
    root = Path(kitti_root)
    pose_file = root / "poses" / f"{sequence}.txt"
    times_file = root / "sequences" / sequence / "times.txt"
    if not pose_file.is_file():
        raise HippoNavError(
            f"{pose_file}: no ground-truth poses for sequence {sequence} (KITTI has them for 00–10)"
        )
    if not times_file.is_file():
        raise HippoNavError(f"{times_file}: frame times missing for sequence {sequence}")
    poses = read_kitti_poses(pose_file)
    times = np.loadtxt(times_file, ndmin=1)
    if len(times) != len(poses):
        raise HippoNavError(f"{times_file}: {len(times)} times for {len(poses)} poses in {pose_file}")
    if stride < 1:
        raise HippoNavError(f"stride must be at least 1, got {stride}")
    chosen = slice(start, stop, stride)
    poses, times = poses[chosen], times[chosen]
    if len(poses) < 2:
        raise HippoNavError(
            f"the frame range start={start} stop={stop} stride={stride} selects fewer than 2 frames"
        )
    return f"KITTI {sequence}", poses, times


def write_neural_state_figure(sm: SpatialMemory, path: Path, title: str) -> Path:
    """HD ring (θ × ν), each module's layer-II pattern, and the place bump, like the paper's figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 5, figsize=(17, 3.4))
    panels = [("HD ring (ν × θ)", sm.hd_activity())]
    panels += [(f"grid k={g.k} layer II", sm.grid_layer2(i)) for i, g in enumerate(sm.config.grid)]
    panels += [("CA3 place", sm.place_activity())]
    for ax, (name, img) in zip(axes, panels):
        ax.imshow(img, origin="lower", aspect="auto", cmap="viridis")
        ax.set_title(name)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def run_engine_job(
    out_dir: str | Path,
    kitti_root: str | None = None,
    sequence: str = "00",
    start: int | None = None,
    stop: int | None = None,
    stride: int = 1,
    config: EngineConfig | None = None,
    progress: bool = True,
) -> dict:
    """Run and write results into `out_dir`; returns the metrics. Ctrl-C keeps what was integrated."""
    from hippo_nav.io import write_kitti_poses, write_tum
    from hippo_nav.synthetic import planar_poses

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name, poses, times = _sequence(kitti_root, sequence, start, stop, stride)
    config = config if config is not None else EngineConfig()
    (out / "engine_config.json").write_text(config.model_dump_json(by_alias=True, indent=2))
    odo = planar_odometry(poses, times)
    sm = SpatialMemory(config)
    result = drive(sm, odo, progress=progress)
    n = len(result.heading_rad)
    truth, truth_yaw = planar_track(poses[:n])
    est = planar_poses(result.place_position_m[:, 0], result.place_position_m[:, 1], result.heading_rad)
    write_kitti_poses(out / "neural_estimate.kitti.txt", est)
    write_tum(out / "neural_estimate.tum.txt", times[:n], est)
    write_kitti_poses(
        out / "ground_truth_planar.kitti.txt", planar_poses(truth[:, 0], truth[:, 1], truth_yaw)
    )
    err = np.linalg.norm(result.place_position_m - truth, axis=1)
    heading_err = np.abs(np.remainder(result.heading_rad - truth_yaw + np.pi, 2 * np.pi) - np.pi)
    distance = float(np.sum(np.linalg.norm(np.diff(truth, axis=0), axis=1)))
    metrics = {
        "sequence": name,
        "odometry": "ground-truth planar motion",
        "frames": n,
        "distance_m": distance,
        "place_code_final_error_m": float(err[-1]),
        "place_code_final_error_pct_of_distance": float(100 * err[-1] / max(distance, 1e-9)),
        "place_code_rmse_m": float(np.sqrt(np.mean(err**2))),
        "heading_max_error_deg": float(np.degrees(heading_err.max())),
        "bump_counts_final": result.bump_counts[-1].tolist(),
        "interrupted": result.interrupted,
    }
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    write_neural_state_figure(sm, out / "neural_state.png", f"{name}: neural state after {n} frames")
    return metrics
