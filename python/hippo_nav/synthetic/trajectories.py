"""Camera trajectories for synthetic sequences, as (N, 4, 4) `world_from_camera` arrays (KITTI frames).

Planar convention (`hippo_nav.geometry`): the map's (forward, left) axes are the world's (z, −x); yaw ψ
turns about −y (counter-clockwise seen from above is a left turn), so a camera with yaw ψ looks along
world (x, z) = (−sin ψ, cos ψ). Height is up, i.e. world y = −height.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hippo_nav.geometry import planar_from_pose, pose_from_planar
from hippo_nav.io.errors import DatasetError
from hippo_nav.io.poses import read_kitti_poses


def planar_poses(
    forward_m: np.ndarray, left_m: np.ndarray, yaw_rad: np.ndarray, height_m: float = 0.0
) -> np.ndarray:
    """KITTI-frame poses of a level camera at planar positions (forward, left) with heading yaw."""
    forward_m, left_m, yaw_rad = (
        np.asarray(x, dtype=np.float64).reshape(-1) for x in (forward_m, left_m, yaw_rad)
    )
    if not (len(forward_m) == len(left_m) == len(yaw_rad)):
        raise DatasetError("forward_m, left_m and yaw_rad must have the same length")
    return pose_from_planar(np.column_stack([forward_m, left_m, yaw_rad]), height_m)


def loop_trajectory(
    n_frames: int = 200,
    *,
    side_lengths_m: tuple[float, float] = (70.0, 35.0),
    corner_radius_m: float = 10.0,
    speed_m_per_frame: float = 1.4,
    speed_variation: float = 0.25,
) -> np.ndarray:
    """Drive a rounded rectangle counter-clockwise (left turns) and keep going, so the start is revisited.

    The camera starts in the middle of the first straight. Speed varies smoothly by ±`speed_variation`
    (a fraction) around `speed_m_per_frame` so the odometry sees accelerations, never a stop.
    """
    length_x, length_y = side_lengths_m
    if n_frames < 2 or min(length_x, length_y) <= 2 * corner_radius_m or corner_radius_m <= 0:
        raise DatasetError("need n_frames >= 2 and sides longer than twice the (positive) corner radius")
    if not 0 <= speed_variation < 1 or speed_m_per_frame <= 0:
        raise DatasetError("speed_m_per_frame must be positive and speed_variation in [0, 1)")
    # Dense arc-length table of the loop: straights and quarter circles, exact headings.
    straight_x, straight_y = length_x - 2 * corner_radius_m, length_y - 2 * corner_radius_m
    pieces = [
        ("line", straight_x / 2),
        ("arc", 0),
        ("line", straight_y),
        ("arc", 0),
        ("line", straight_x),
        ("arc", 0),
        ("line", straight_y),
        ("arc", 0),
        ("line", straight_x / 2),
    ]
    x, y, yaw = [0.0], [0.0], [0.0]
    arc_step = np.pi / 2 / 200
    for kind, length in pieces:
        if kind == "line":
            n = max(int(np.ceil(length / 0.05)), 1)
            for _ in range(n):
                x.append(x[-1] + length / n * np.cos(yaw[-1]))
                y.append(y[-1] + length / n * np.sin(yaw[-1]))
                yaw.append(yaw[-1])
        else:
            cx, cy = x[-1] - corner_radius_m * np.sin(yaw[-1]), y[-1] + corner_radius_m * np.cos(yaw[-1])
            start = yaw[-1]
            for k in range(1, 201):
                psi = start + k * arc_step
                x.append(cx + corner_radius_m * np.sin(psi))
                y.append(cy - corner_radius_m * np.cos(psi))
                yaw.append(psi)
    x_arr, y_arr, yaw_arr = np.array(x), np.array(y), np.array(yaw)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x_arr), np.diff(y_arr)))])
    perimeter = arc[-1]
    frame = np.arange(n_frames)
    speed = speed_m_per_frame * (1 + speed_variation * np.sin(2 * np.pi * frame / 97.0))
    travelled = np.concatenate([[0.0], np.cumsum(speed[1:])])
    laps, along = np.divmod(travelled, perimeter)
    forward = np.interp(along, arc, x_arr)
    left = np.interp(along, arc, y_arr)
    heading = np.interp(along, arc, yaw_arr) + 2 * np.pi * laps
    return planar_poses(forward, left, heading)


def kitti_trajectory(
    pose_file: str | Path,
    start: int = 0,
    stop: int | None = None,
    stride: int = 1,
    *,
    rebase: bool = True,
    level: bool = True,
) -> np.ndarray:
    """Frames [start:stop:stride] of a KITTI ground-truth file.

    `rebase` makes the first pose the identity (as in a KITTI pose file of the cropped sequence); `level`
    removes roll and pitch (KITTI's are below ~2°), keeping positions and yaw, which lets the renderer
    solve one ray per image column. The returned poses are the exact ground truth of what is rendered.
    """
    poses = read_kitti_poses(pose_file)
    if stride < 1 or not 0 <= start < len(poses):
        raise DatasetError(f"{pose_file}: start {start} / stride {stride} invalid for {len(poses)} poses")
    poses = poses[start:stop:stride]
    if rebase:
        poses = np.linalg.inv(poses[0]) @ poses
    return level_trajectory(poses) if level else poses


def level_trajectory(world_from_camera: np.ndarray) -> np.ndarray:
    """Same positions and headings, roll and pitch removed (camera y axis = world down)."""
    poses = np.asarray(world_from_camera, dtype=np.float64)
    level = pose_from_planar(planar_from_pose(poses))
    level[:, :3, 3] = poses[:, :3, 3]
    return level


def road_heights_m(positions_m: np.ndarray, smoothing_m: float = 6.0) -> np.ndarray:
    """Height (m, up) of the road under each camera position: a function of horizontal position only.

    KITTI's ground-truth heights of two passes over the same street disagree by 0.3–3 m (GPS/INS drift
    between passes), so a camera placed at each pass's own height sees the same street from a different
    height and revisits stop looking alike. Here the height at horizontal position q is the Gaussian-weighted
    mean (σ = `smoothing_m`) of every pose's height around q: passes over one street get one height, and
    slopes along a street (a linear profile averages to itself) are kept.
    """
    positions = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)
    if not (np.isfinite(smoothing_m) and smoothing_m > 0):
        raise DatasetError(f"smoothing_m must be positive, got {smoothing_m}")
    horizontal = positions[:, [0, 2]]
    height = -positions[:, 1]
    out = np.empty(len(positions))
    chunk = 512  # rows of the pairwise weight matrix held at once (memory stays ~ chunk × N)
    for lo in range(0, len(positions), chunk):
        d2 = ((horizontal[lo : lo + chunk, None, :] - horizontal[None, :, :]) ** 2).sum(-1)
        weight = np.exp(-0.5 * d2 / smoothing_m**2)
        out[lo : lo + chunk] = weight @ height / weight.sum(1)
    return out


def road_trajectory(world_from_camera: np.ndarray, smoothing_m: float = 6.0) -> np.ndarray:
    """The poses levelled (`level_trajectory`) with each camera at the road height of its position
    (`road_heights_m`): what a car with a fixed camera height sees when it drives the same streets again."""
    level = level_trajectory(world_from_camera)
    level[:, 1, 3] = -road_heights_m(level[:, :3, 3], smoothing_m)
    return level


def scale_trajectory(world_from_camera: np.ndarray, factor: float) -> np.ndarray:
    """Scale all translations about the first pose by `factor` (a speed change at the same frame rate)."""
    if not np.isfinite(factor) or factor <= 0:
        raise DatasetError(f"scale factor must be positive and finite, got {factor}")
    poses = np.array(world_from_camera, dtype=np.float64)
    poses[:, :3, 3] = poses[0, :3, 3] + factor * (poses[:, :3, 3] - poses[0, :3, 3])
    return poses


def path_length_m(world_from_camera: np.ndarray) -> float:
    """Total distance travelled by the camera centre."""
    return float(np.linalg.norm(np.diff(np.asarray(world_from_camera)[:, :3, 3], axis=0), axis=1).sum())
