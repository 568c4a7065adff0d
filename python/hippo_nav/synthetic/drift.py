"""A drifting odometry made from a ground-truth trajectory: what a real VO's errors do to it, controllably.

For experiments (how much drift does the back-end correct?) and tests (a replayed odometry file with a
known error). Conventions: poses are (N, 4, 4) `world_from_camera` in the KITTI camera frame (x right,
y down, z forward); yaw is a rotation about the camera's −y axis (up), positive = a left turn, as in
`hippo_nav.vo.planar_step` and `hippo_nav.synthetic.planar_poses`.

Every frame-to-frame step of the ground truth, `step_k = inv(gt[k−1]) @ gt[k] = [R_k | t_k]`, becomes

    drifted step_k = [R_k · Yaw(bias + ε_k) | (1 + scale_error) · t_k + n_k]

where `Yaw(ψ)` turns by ψ about −y, ε_k ~ N(0, yaw_noise) and n_k ~ N(0, translation_noise² I₃)
(metres, per axis, in the previous camera's frame). The yaw error is applied in the current camera's
frame, i.e. it turns the camera *after* this step's translation, the way a VO's rotation error bends
every later step. The drifted trajectory is chained from the first ground-truth pose:
`drifted[0] = gt[0]`, `drifted[k] = drifted[k−1] @ drifted step_k`. Hence, without noise:
- the path is exactly (1 + scale_error) times as long (rotations keep step lengths);
- on a level trajectory (all rotations about y) the heading after k steps is off by k · bias.
"""

from __future__ import annotations

import numpy as np

from hippo_nav.geometry import yaw_rotation
from hippo_nav.io.errors import DatasetError


def drifting_odometry(
    world_from_camera: np.ndarray,
    *,
    scale_error: float = 0.01,
    yaw_bias_deg_per_frame: float = 0.02,
    translation_noise_m: float = 0.0,
    yaw_noise_deg: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    """(N, 4, 4) drifted `world_from_camera` from a ground truth (N, 4, 4); see the module doc.

    `scale_error`: relative error of every step's length (0.01 = 1 % too long); `yaw_bias_deg_per_frame`:
    heading error added per step (positive = turns left); `translation_noise_m`, `yaw_noise_deg`: σ of the
    zero-mean Gaussian noise per step. The noise is drawn from `numpy.random.default_rng(seed)` whatever
    the σ, so a given seed gives the same noise pattern at any noise level.
    """
    gt = np.asarray(world_from_camera, dtype=np.float64)
    if gt.ndim != 3 or gt.shape[1:] != (4, 4) or len(gt) == 0:
        raise DatasetError(f"world_from_camera must have shape (N, 4, 4) with N >= 1, got {gt.shape}")
    if not np.isfinite(gt).all():
        raise DatasetError("world_from_camera contains NaN or infinity")
    numbers = {
        "scale_error": scale_error,
        "yaw_bias_deg_per_frame": yaw_bias_deg_per_frame,
        "translation_noise_m": translation_noise_m,
        "yaw_noise_deg": yaw_noise_deg,
    }
    for name, value in numbers.items():
        if not np.isfinite(value):
            raise DatasetError(f"{name} must be finite, got {value}")
    if scale_error <= -1.0:
        raise DatasetError(f"scale_error must be > -1 (a step cannot shrink to nothing), got {scale_error}")
    if translation_noise_m < 0 or yaw_noise_deg < 0:
        raise DatasetError("translation_noise_m and yaw_noise_deg are standard deviations: give values >= 0")

    n_steps = len(gt) - 1
    rng = np.random.default_rng(seed)
    translation_noise = rng.standard_normal((n_steps, 3)) * translation_noise_m
    yaw_error_rad = np.deg2rad(yaw_bias_deg_per_frame + rng.standard_normal(n_steps) * yaw_noise_deg)

    drifted = np.empty_like(gt)
    drifted[0] = gt[0]
    for k in range(1, len(gt)):
        step = np.linalg.solve(gt[k - 1], gt[k])  # inv(gt[k−1]) @ gt[k]
        noisy = np.eye(4)
        noisy[:3, :3] = step[:3, :3] @ yaw_rotation(yaw_error_rad[k - 1])
        noisy[:3, 3] = (1.0 + scale_error) * step[:3, 3] + translation_noise[k - 1]
        drifted[k] = drifted[k - 1] @ noisy
    return drifted
