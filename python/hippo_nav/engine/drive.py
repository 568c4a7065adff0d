"""Drive the spatial memory along a trajectory's planar odometry (no camera): the network's own path
integration of a known motion, as in the paper's path-integration experiments.

Planar convention (docs/spec.md §9): the map's (forward, left) axes are KITTI's (z, −x); yaw turns
about −y (counter-clockwise seen from above is positive). The engine's frame has x along the initial
heading and y to its left, so its positions compare directly with the trajectory expressed in its first
pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.engine.network import SpatialMemory
from hippo_nav.geometry import planar_from_pose


@dataclass(frozen=True)
class PlanarOdometry:
    """Per-step motion between consecutive frames (length N − 1)."""

    yaw_rate_rad_s: np.ndarray
    speed_m_s: np.ndarray
    dt_s: np.ndarray


def planar_track(world_from_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) positions (forward, left) and (N,) yaw of KITTI camera poses, relative to the first pose."""
    poses = np.asarray(world_from_camera, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) < 2:
        raise HippoNavError(f"world_from_camera must be (N >= 2, 4, 4), got {poses.shape}")
    if not np.isfinite(poses).all():
        raise HippoNavError("world_from_camera contains NaN or infinite values")
    planar = planar_from_pose(np.linalg.inv(poses[0]) @ poses)
    return planar[:, :2], planar[:, 2]


def planar_odometry(world_from_camera: np.ndarray, timestamps_s: np.ndarray) -> PlanarOdometry:
    """Yaw rate and forward speed between consecutive poses (speed negative when reversing)."""
    positions, yaw = planar_track(world_from_camera)
    t = np.asarray(timestamps_s, dtype=np.float64)
    if t.shape != (len(positions),):
        raise HippoNavError(f"timestamps_s must have one value per pose ({len(positions)}), got {t.shape}")
    dt = np.diff(t)
    if not (np.isfinite(dt).all() and (dt > 0).all()):
        raise HippoNavError("timestamps_s must be finite and strictly increasing")
    step = np.diff(positions, axis=0)
    heading = np.stack([np.cos(yaw[:-1]), np.sin(yaw[:-1])], axis=1)
    forward = np.sign(np.einsum("ij,ij->i", step, heading) + 1e-12)
    dyaw = np.remainder(np.diff(yaw) + np.pi, 2 * np.pi) - np.pi
    return PlanarOdometry(dyaw / dt, forward * np.linalg.norm(step, axis=1) / dt, dt)


@dataclass(frozen=True)
class DriveResult:
    """Per frame (N, including the start): decoded heading, place-code and per-module positions (m)."""

    heading_rad: np.ndarray
    place_position_m: np.ndarray
    module_positions_m: np.ndarray  # (N, N_MODULES, 2)
    bump_counts: np.ndarray  # (N, N_MODULES)
    interrupted: bool = False


def drive(sm: SpatialMemory, odometry: PlanarOdometry, progress: bool = False) -> DriveResult:
    """Step `sm` once per odometry step, collecting the decoded state. Ctrl-C stops early and returns the
    frames integrated so far (`interrupted` is then True)."""
    lengths = {len(odometry.yaw_rate_rad_s), len(odometry.speed_m_s), len(odometry.dt_s)}
    if len(lengths) != 1:
        # zip would stop at the shortest and drop the rest of the drive without a word.
        raise HippoNavError(
            f"odometry arrays differ in length (yaw_rate_rad_s {len(odometry.yaw_rate_rad_s)}, speed_m_s "
            f"{len(odometry.speed_m_s)}, dt_s {len(odometry.dt_s)}); give one value of each a step"
        )
    readouts = [sm.readout()]
    steps = zip(odometry.yaw_rate_rad_s, odometry.speed_m_s, odometry.dt_s, strict=True)
    if progress:
        from tqdm import tqdm

        steps = tqdm(steps, total=len(odometry.dt_s), desc="path integration", unit="frame")
    interrupted = False
    try:
        for w, v, dt in steps:
            readouts.append(sm.step(w, v, dt))
    except KeyboardInterrupt:
        interrupted = True
    return DriveResult(
        heading_rad=np.array([r.heading_rad for r in readouts]),
        place_position_m=np.array([r.place_position_m for r in readouts]),
        module_positions_m=np.array([[m.position_m for m in r.modules] for r in readouts]),
        bump_counts=np.array([[len(m.bumps) for m in r.modules] for r in readouts]),
        interrupted=interrupted,
    )
