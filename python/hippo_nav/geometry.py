"""Frames and planar geometry, in one place.

Camera frame (KITTI, docs/data.md): x right, y down, z forward. A pose `world_from_camera` is a 4×4
SE(3) matrix; "world" is the camera frame of the first frame.

Planar (map) frame: the ground plane seen from above, x = camera forward (world z), y = camera left
(world −x), yaw counter-clockwise (a left turn), i.e. a rotation about the camera's −y axis. A planar pose
is `(x_m, y_m, yaw_rad)`; SE(2) composition `a ⊕ b` applies `b` in the frame of `a`, and
`between(a, b) = a⁻¹ ⊕ b` is `b` seen from `a`. Yaw is wrapped to [−π, π) by `wrap_angle`.

A camera pose splits into its planar part (forward, left, yaw) and the rest (height, pitch, roll):
`planar_from_pose` takes the planar part; `lift_planar` puts a planar pose back into 3-D with the height,
pitch and roll of a reference pose, so an estimate made in the plane (the experience map, the place code)
is written as a 3-D trajectory that compares like with like against 3-D ground truth. For any pose T,
`lift_planar(planar_from_pose(T), T) == T`.
"""

from __future__ import annotations

import numpy as np

from hippo_nav._core import HippoNavError


def wrap_angle(angle_rad: np.ndarray | float) -> np.ndarray | float:
    """`mod(a + π, 2π) − π`: the representative of an angle in [−π, π). (An angle a rounding error below −π
    can round to +π: the two are the same direction.)"""
    return np.remainder(np.asarray(angle_rad) + np.pi, 2 * np.pi) - np.pi


def _last_axis(values: np.ndarray | list[float] | tuple[float, ...], size: int, what: str) -> np.ndarray:
    """`values` as float64 whose last axis holds `size` numbers (a longer one was silently cut before)."""
    array = np.asarray(values, dtype=np.float64)
    if array.ndim == 0 or array.shape[-1] != size:
        raise HippoNavError(f"{what} must be (…, {size}) arrays, got shape {array.shape}")
    return array


def se2_compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ⊕ b for (…, 3) arrays of (x, y, yaw); the yaw is wrapped."""
    a, b = _last_axis(a, 3, "planar poses (x, y, yaw)"), _last_axis(b, 3, "planar poses (x, y, yaw)")
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return np.stack([x, y, wrap_angle(a[..., 2] + b[..., 2])], axis=-1)


def se2_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a⁻¹ ⊕ b (b seen from a) for (…, 3) arrays of (x, y, yaw); the yaw is wrapped."""
    a, b = _last_axis(a, 3, "planar poses (x, y, yaw)"), _last_axis(b, 3, "planar poses (x, y, yaw)")
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[..., 2] - a[..., 2])], axis=-1)


def se2_chain(steps: np.ndarray) -> np.ndarray:
    """(n, 3) poses of chained steps; the first pose is the first step (usually the identity)."""
    steps = np.asarray(steps, dtype=np.float64).reshape(-1, 3)
    poses = np.empty_like(steps)
    if len(steps):
        poses[0] = steps[0]
    for k in range(1, len(steps)):
        poses[k] = se2_compose(poses[k - 1], steps[k])
    return poses


def planar_from_pose(world_from_camera: np.ndarray) -> np.ndarray:
    """(…, 3) planar poses (forward, left, yaw) of (…, 4, 4) camera poses."""
    t = np.asarray(world_from_camera, dtype=np.float64)
    # The camera's z axis seen in the world; yaw turns about −y (left positive).
    yaw = np.arctan2(-t[..., 0, 2], t[..., 2, 2])
    return np.stack([t[..., 2, 3], -t[..., 0, 3], yaw], axis=-1)


def planar_xy(world_from_camera: np.ndarray) -> np.ndarray:
    """(…, 2) map-frame positions (forward = z, left = −x) of (…, 4, 4) camera poses."""
    return planar_from_pose(world_from_camera)[..., :2]


def yaw_rotation(yaw_rad: np.ndarray | float) -> np.ndarray:
    """(…, 3, 3) rotation of a level camera with heading `yaw_rad` (about −y, left positive)."""
    yaw = np.asarray(yaw_rad, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    r = np.zeros(yaw.shape + (3, 3))
    # Columns are the camera axes in the world: x (right) = (c, 0, s), y (down), z (forward) = (−s, 0, c).
    r[..., 0, 0], r[..., 2, 0] = c, s
    r[..., 1, 1] = 1.0
    r[..., 0, 2], r[..., 2, 2] = -s, c
    return r


def pose_from_planar(xy_yaw: np.ndarray, height_m: np.ndarray | float = 0.0) -> np.ndarray:
    """(…, 4, 4) level camera poses at planar poses (forward, left, yaw), `height_m` above the origin."""
    p = _last_axis(xy_yaw, 3, "planar poses (forward, left, yaw)")
    poses = np.zeros(p.shape[:-1] + (4, 4))
    poses[..., :3, :3] = yaw_rotation(p[..., 2])
    poses[..., 0, 3] = -p[..., 1]
    poses[..., 1, 3] = -np.asarray(height_m, dtype=np.float64)
    poses[..., 2, 3] = p[..., 0]
    poses[..., 3, 3] = 1.0
    return poses


def lift_planar(xy_yaw: np.ndarray, reference_world_from_camera: np.ndarray) -> np.ndarray:
    """(…, 4, 4) poses with the planar part of `xy_yaw` and the height, pitch and roll of the reference.

    The reference rotation splits as `R = R_yaw(ψ_ref) · R_tilt`; the result is `R_yaw(ψ) · R_tilt` at
    position (−left, y_ref, forward)."""
    p = _last_axis(xy_yaw, 3, "planar poses (forward, left, yaw)")
    ref = np.asarray(reference_world_from_camera, dtype=np.float64)
    ref_yaw = planar_from_pose(ref)[..., 2]
    tilt = np.swapaxes(yaw_rotation(ref_yaw), -1, -2) @ ref[..., :3, :3]
    out = np.zeros(np.broadcast_shapes(p.shape[:-1], ref.shape[:-2]) + (4, 4))
    out[..., :3, :3] = yaw_rotation(p[..., 2]) @ tilt
    out[..., 0, 3] = -p[..., 1]
    out[..., 1, 3] = ref[..., 1, 3]
    out[..., 2, 3] = p[..., 0]
    out[..., 3, 3] = 1.0
    return out


def planar_step(camera_prev_from_camera_cur: np.ndarray) -> tuple[float, float, float]:
    """(forward_m, left_m, yaw_rad) of an SE(3) camera step: its translation and yaw, read in the frame
    of the previous camera."""
    forward, left, yaw = planar_from_pose(camera_prev_from_camera_cur)
    return float(forward), float(left), float(yaw)


def skew(v: np.ndarray) -> np.ndarray:
    """(…, 3, 3) cross-product matrices [v]× of (…, 3) vectors: `skew(a) @ b == np.cross(a, b)`."""
    v = _last_axis(v, 3, "vectors")
    s = np.zeros(v.shape[:-1] + (3, 3))
    s[..., 0, 1], s[..., 0, 2] = -v[..., 2], v[..., 1]
    s[..., 1, 0], s[..., 1, 2] = v[..., 2], -v[..., 0]
    s[..., 2, 0], s[..., 2, 1] = -v[..., 1], v[..., 0]
    return s
