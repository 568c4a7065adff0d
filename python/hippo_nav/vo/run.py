"""Run the stereo VO over a whole dataset: the VO-only trajectory and its per-frame steps."""

from __future__ import annotations

import numpy as np

from hippo_nav.datasets.base import StereoDataset
from hippo_nav.vo.odometry import StereoOdometry, VoParams, VoStep


def run_odometry(
    dataset: StereoDataset, params: VoParams | None = None, progress: bool = False
) -> tuple[np.ndarray, list[VoStep]]:
    """(world_from_camera (n, 4, 4) starting at the identity, steps) of the VO over `dataset`."""
    vo = StereoOdometry(dataset.calibration, params)
    frames = range(len(dataset))
    if progress:
        from tqdm import tqdm

        frames = tqdm(frames, desc=f"VO {getattr(dataset, 'name', '')}", unit="frame")
    poses, steps = [], []
    world_from_camera = np.eye(4)
    for i in frames:
        step = vo.process(dataset[i])
        world_from_camera = world_from_camera @ step.camera_prev_from_camera_cur
        poses.append(world_from_camera)
        steps.append(step)
    return np.stack(poses), steps
