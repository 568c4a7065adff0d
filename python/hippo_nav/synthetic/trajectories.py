"""Camera trajectories for synthetic sequences, as (N, 4, 4) `world_from_camera` arrays (KITTI frames).

Planar convention (`hippo_nav.geometry`): the map's (forward, left) axes are the world's (z, −x); yaw ψ
turns about −y (counter-clockwise seen from above is a left turn), so a camera with yaw ψ looks along
world (x, z) = (−sin ψ, cos ψ). Height is up, i.e. world y = −height.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hippo_nav.geometry import planar_from_pose, pose_from_planar
from hippo_nav.io.errors import DatasetError
from hippo_nav.io.poses import read_kitti_poses
from hippo_nav.synthetic.appearance import PASS_RADIUS_M


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


@dataclass(frozen=True)
class RevisitStreet:
    """A straight street driven twice (`revisit_street`). Render it with
    `render_sequence(s.world_from_camera, out, street_path_m=s.street_path_m, …)` so the street follows the
    first pass whatever lane the second drives in."""

    world_from_camera: np.ndarray  # (2n, 4, 4): the first pass, then the second
    street_path_m: np.ndarray  # (n, 3): the street's centre line (the first pass's camera centres)
    first_pass: np.ndarray  # frame indices of the first pass, 0 … n − 1
    second_pass: np.ndarray  # frame indices of the second pass, n … 2n − 1
    revisit_of: (
        np.ndarray
    )  # per second-pass frame: the first-pass frame at the nearest place along the street


def revisit_street(
    n_frames: int = 60,
    *,
    step_m: float = 1.0,
    lateral_offset_m: float = 0.0,
    heading_offset_deg: float = 0.0,
    along_offset_m: float = 0.0,
    height_m: float = 0.0,
) -> RevisitStreet:
    """A straight street (along the first camera's forward axis) driven twice, `n_frames` frames `step_m`
    apart each time; the second pass starts again at the street's start (a cut, not a drive back).

    The second pass is `lateral_offset_m` to the left (planar convention: negative is right),
    `along_offset_m` further along and yawed by `heading_offset_deg` (left positive) relative to the street:
    a controlled revisit for measuring view recognition against offset and heading change. By `pass_indices`
    the first pass is pass 0 and the second pass 1 (the street is at least 3 pass radii long).
    """
    if n_frames < 2 or not (np.isfinite(step_m) and step_m > 0):
        raise DatasetError("revisit_street needs n_frames >= 2 and a positive step_m")
    length_m = (n_frames - 1) * step_m
    if length_m < 3 * PASS_RADIUS_M:
        raise DatasetError(
            f"the street is {length_m:.1f} m long; make it at least {3 * PASS_RADIUS_M:.0f} m "
            "(more frames or a longer step_m) so that the second pass is a separate visit"
        )
    if abs(lateral_offset_m) > 5.0 or abs(heading_offset_deg) > 45.0 or abs(along_offset_m) > length_m:
        raise DatasetError(
            "keep |lateral_offset_m| <= 5 m (the camera must stay inside the 7 m half street), "
            "|heading_offset_deg| <= 45 and |along_offset_m| within the street"
        )
    forward = np.arange(n_frames) * step_m
    first = planar_poses(forward, np.zeros(n_frames), np.zeros(n_frames), height_m)
    second = planar_poses(
        forward + along_offset_m,
        np.full(n_frames, float(lateral_offset_m)),
        np.full(n_frames, np.radians(heading_offset_deg)),
        height_m,
    )
    revisit_of = np.abs((forward + along_offset_m)[:, None] - forward[None, :]).argmin(1)
    return RevisitStreet(
        world_from_camera=np.concatenate([first, second]),
        street_path_m=first[:, :3, 3].copy(),
        first_pass=np.arange(n_frames),
        second_pass=np.arange(n_frames, 2 * n_frames),
        revisit_of=revisit_of,
    )


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
