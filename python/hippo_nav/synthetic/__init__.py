"""Synthetic stereo sequences: a procedurally textured street world rendered along any trajectory.

`render_sequence(world_from_camera, out_root)` writes a KITTI-layout sequence (images, calib.txt,
times.txt, poses) that `hippo_nav.datasets.KittiOdometry` reads back. Trajectories come from
`loop_trajectory` (a driven loop with a revisit) or `kitti_trajectory` (any KITTI ground-truth file, so
real loop geometry such as sequences 00, 05, 06, 07 can be rendered). `demo_sequence` is the built-in demo.
`drifting_odometry(ground_truth)` turns a trajectory into a drifting odometry (scale error, yaw bias, noise),
e.g. to write a file for `hippo-nav run --odometry`. `appearance="mild"` or `"strong"` (`APPEARANCE_LEVELS`)
makes a place look different on every pass (docs/render.md); `revisit_street` drives a street twice with a
controlled lateral and heading offset.
"""

from __future__ import annotations

import os
from pathlib import Path

from hippo_nav.synthetic.appearance import APPEARANCE_LEVELS, AppearanceModel, pass_indices
from hippo_nav.synthetic.drift import drifting_odometry, yaw_rotation
from hippo_nav.synthetic.render import (
    KITTI_FOCAL_RATIO,
    render_cached,
    render_kitti,
    render_sequence,
    stereo_projections,
    street_views,
)
from hippo_nav.synthetic.trajectories import (
    RevisitStreet,
    kitti_trajectory,
    level_trajectory,
    loop_trajectory,
    path_length_m,
    planar_poses,
    revisit_street,
    road_heights_m,
    road_trajectory,
    scale_trajectory,
)
from hippo_nav.synthetic.world import StreetWorld

DEMO_SEQUENCE = "00"
DEMO_FRAMES = 200


def default_cache_dir() -> Path:
    """Where rendered demo data is kept: $HIPPO_NAV_CACHE or ~/.cache/hippo_nav."""
    env = os.environ.get("HIPPO_NAV_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "hippo_nav"


def demo_sequence(out_root: str | Path | None = None, *, progress: bool = False) -> Path:
    """The built-in demo: 200 stereo frames (320×96, 10 Hz) driving 1.4 laps of a 190 m loop.

    The second lap revisits the first ~90 m, so loop closure can be seen. Rendered once into
    `out_root` (default: `default_cache_dir()/demo_kitti`) and reused while the parameters match.
    Returns the KITTI root; open it with `KittiOdometry(root, DEMO_SEQUENCE)`.
    """
    root = Path(out_root) if out_root is not None else default_cache_dir() / "demo_kitti"
    return render_cached(loop_trajectory(DEMO_FRAMES), root, DEMO_SEQUENCE, seed=0, progress=progress)


__all__ = [
    "APPEARANCE_LEVELS",
    "DEMO_FRAMES",
    "DEMO_SEQUENCE",
    "KITTI_FOCAL_RATIO",
    "AppearanceModel",
    "RevisitStreet",
    "StreetWorld",
    "default_cache_dir",
    "demo_sequence",
    "drifting_odometry",
    "kitti_trajectory",
    "level_trajectory",
    "loop_trajectory",
    "pass_indices",
    "path_length_m",
    "planar_poses",
    "render_cached",
    "render_kitti",
    "render_sequence",
    "revisit_street",
    "road_heights_m",
    "road_trajectory",
    "scale_trajectory",
    "stereo_projections",
    "street_views",
    "yaw_rotation",
]
