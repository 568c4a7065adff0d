"""The stereo camera's pixel model and its derivatives, shared by the odometry's step refinement and its
disparity self-calibration (`hippo_nav.vo.disparity`).

Camera x right, y down, z forward; a point x of the current left camera is seen at u = fx·(x − s)/z + cx by a
camera s metres to its right (the right camera: s = baseline) and at v = fy·y/z + cy."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["pixel_rows", "project", "refine_stereo_step", "reprojection_rmse", "triangulate"]


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


def refine_stereo_step(
    cur_from_prev: np.ndarray,
    points_m: np.ndarray,
    left_px: np.ndarray,
    right_px: np.ndarray,
    has_right: np.ndarray,
    camera: tuple[float, float, float, float, float],
    huber_px: float,
    offset_px: float,
) -> np.ndarray:
    """Gauss–Newton on left + right reprojection in the current frame.

    `camera` = (fx, fy, cx, cy, baseline_m); `offset_px` corrects the right columns (the disparity offset).
    Points without a consistent right match (`has_right` false) keep only their left residual.
    Robust (Huber) weights keep a few bad tracks from pulling the step."""
    left_obs = left_px.astype(np.float64)
    right_u = right_px[has_right, 0].astype(np.float64) - offset_px
    transform = cur_from_prev.copy()
    for _ in range(5):
        x = points_m @ transform[:3, :3].T + transform[:3, 3]
        if (x[:, 2] <= 0).any():
            return cur_from_prev
        # The right image adds only u (the disparity): its v repeats the left one, plus whatever
        # row offset the rectification left, which would tilt the pitch.
        rows = (
            _residual_rows(x, 0.0, 0, left_obs[:, 0], camera),
            _residual_rows(x, 0.0, 1, left_obs[:, 1], camera),
            _residual_rows(x[has_right], camera[4], 0, right_u, camera),
        )
        r = np.concatenate([row[0] for row in rows])
        jac = np.concatenate([row[1] for row in rows])
        weight = np.where(np.abs(r) <= huber_px, 1.0, huber_px / np.maximum(np.abs(r), 1e-12))
        jw = jac * weight[:, None]
        try:
            delta = -np.linalg.solve(jw.T @ jac, jw.T @ r)
        except np.linalg.LinAlgError:
            return cur_from_prev
        update = np.eye(4)
        update[:3, :3] = cv2.Rodrigues(delta[:3])[0]
        update[:3, 3] = delta[3:]
        transform = update @ transform
        if np.linalg.norm(delta) < 1e-9:
            break
    return transform


def _residual_rows(
    x: np.ndarray,
    offset_m: float,
    axis: int,
    observed: np.ndarray,
    camera: tuple[float, float, float, float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """(residuals (n,), Jacobian (n, 6) on a left perturbation (ω, τ) of the pose) of pixel coordinate `axis`
    (0: u, 1: v) of points `x` (current left camera frame) seen by a camera `offset_m` to its right."""
    predicted, jac, _, _ = pixel_rows(x, axis, offset_m, camera[:4])
    return predicted - observed, jac


def project(
    camera: tuple[float, float, float, float, float], points_m: np.ndarray, cur_from_prev: np.ndarray
) -> np.ndarray:
    """(n, 3): pixel u, v and depth of points of the previous camera seen from the current one; `camera` =
    (fx, fy, cx, cy, baseline_m)."""
    fx, fy, cx, cy, _ = camera
    x = points_m @ cur_from_prev[:3, :3].T + cur_from_prev[:3, 3]
    z = np.where(np.abs(x[:, 2]) < 1e-9, 1e-9, x[:, 2])
    return np.column_stack([fx * x[:, 0] / z + cx, fy * x[:, 1] / z + cy, x[:, 2]])


def reprojection_rmse(
    camera: tuple[float, float, float, float, float],
    cur_from_prev: np.ndarray,
    points_m: np.ndarray,
    pixels: np.ndarray,
) -> float:
    """RMS distance (px) between `pixels` and where `cur_from_prev` puts the previous camera's points."""
    projected = project(camera, points_m, cur_from_prev)[:, :2]
    return float(np.sqrt(np.mean(np.sum((projected - pixels) ** 2, axis=1))))


def triangulate(
    camera: tuple[float, float, float, float, float], pts: np.ndarray, disparity_px: np.ndarray
) -> np.ndarray:
    """(n, 3) points of the left camera at left pixels `pts` with disparities `disparity_px`: Z = fx·b/d."""
    fx, fy, cx, cy, baseline_m = camera
    z = fx * baseline_m / disparity_px.astype(np.float64)
    x = (pts[:, 0] - cx) * z / fx
    y = (pts[:, 1] - cy) * z / fy
    return np.column_stack([x, y, z])
