"""The stereo camera's pixel model and its derivatives, shared by the odometry's step refinement and its
disparity self-calibration (`hippo_nav.vo.disparity`).

Camera x right, y down, z forward; a point x of the current left camera is seen at u = fx·(x − s)/z + cx by a
camera s metres to its right (the right camera: s = baseline) and at v = fy·y/z + cy."""

from __future__ import annotations

import numpy as np

__all__ = ["pixel_rows"]


def pixel_rows(
    x: np.ndarray, axis: int, shift_m: float, camera: tuple[float, float, float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(predicted pixel coordinate `axis` (0: u, 1: v), its Jacobian (n, 6) on a left perturbation δ = (ω, τ)
    of the pose, and the coordinate's derivatives on x's `axis` and z components) for points `x` (n, 3) of the
    current left camera seen by a camera `shift_m` to its right; `camera` = (fx, fy, cx, cy).

    The point moves by dx = ω × x + τ, and u by du = fx/z·dx − fx·(x − s)/z²·dz (v likewise with fy, y), so
    d(pixel)/dω = x × (the gradient on x)."""
    fx, fy, cx, cy = camera
    focal, centre = (fx, cx) if axis == 0 else (fy, cy)
    a = x[:, axis] - (shift_m if axis == 0 else 0.0)
    z = x[:, 2]
    d_a, d_z = focal / z, -focal * a / z**2
    jac = np.zeros((len(x), 6))
    if axis == 0:
        jac[:, 0], jac[:, 1], jac[:, 2] = x[:, 1] * d_z, x[:, 2] * d_a - x[:, 0] * d_z, -x[:, 1] * d_a
    else:
        jac[:, 0], jac[:, 1], jac[:, 2] = x[:, 1] * d_z - x[:, 2] * d_a, -x[:, 0] * d_z, x[:, 0] * d_a
    jac[:, 3 + axis], jac[:, 5] = d_a, d_z
    return focal * a / z + centre, jac, d_a, d_z
