"""The relative pose of a revisit: PnP of a stored keyframe's 3-D points in the current image.

Matches: ORB descriptors of the keyframe against the current frame's (brute force, Hamming), kept when
the best is clearly better than the second best (Lowe's ratio). Pose: PnP with RANSAC on (keyframe 3-D
points, current pixels) gives `camera_cur_from_camera_key`, refined by Levenberg–Marquardt on the inliers.
A closure is rejected with fewer than `min_inliers` inliers, an inlier share below `min_inlier_ratio`,
or a keyframe farther than `max_distance_m` (on the synthetic renders true revisits give 70–340 inliers,
unrelated places fewer than 10).

The loop link is the planar part of that transform, `agent_from_target = planar_from_pose(cur_from_key)`
(the vertex's pose seen from the agent; see `hippo_nav.geometry`). Its covariance propagates the PnP
covariance `σ² (JᵀJ)⁻¹` (J: reprojection Jacobian of the inliers w.r.t. a left perturbation (ω, τ) of the
pose, σ the inlier RMSE, at least 0.3 px) through the planar projection, inflated by
`covariance_inflation` (PnP ignores depth and feature errors) and floored at `sigma_floor_*`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from hippo_nav.closure.keyframes import ClosureConfig, Keyframe
from hippo_nav.geometry import planar_from_pose, wrap_angle

_MIN_PIXEL_SIGMA_PX = 0.3


@dataclass(frozen=True)
class LoopMeasurement:
    """A verified closure: the target keyframe seen from the current frame."""

    agent_from_target: tuple[float, float, float]  # planar (forward m, left m, yaw rad)
    information: np.ndarray  # (3, 3) inverse covariance of agent_from_target
    camera_cur_from_camera_key: np.ndarray  # (4, 4)
    inliers: int
    matches: int
    rmse_px: float

    @property
    def sigma(self) -> tuple[float, float, float]:
        """Standard deviations (m, m, rad) of the planar measurement."""
        cov = np.linalg.inv(self.information)
        return tuple(float(np.sqrt(v)) for v in np.diag(cov))  # type: ignore[return-value]


def _skew(v: np.ndarray) -> np.ndarray:
    s = np.zeros(v.shape[:-1] + (3, 3))
    s[..., 0, 1], s[..., 0, 2] = -v[..., 2], v[..., 1]
    s[..., 1, 0], s[..., 1, 2] = v[..., 2], -v[..., 0]
    s[..., 2, 0], s[..., 2, 1] = -v[..., 1], v[..., 0]
    return s


def _perturbed(transform: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """exp(δ) · T for δ = (ω, τ) (small rotation vector, translation)."""
    update = np.eye(4)
    update[:3, :3] = cv2.Rodrigues(delta[:3].reshape(3, 1))[0]
    update[:3, 3] = delta[3:]
    return update @ transform


class LoopMeasurer:
    """`LoopMeasurer(calibration, config).measure(target_keyframe, current_keyframe)`."""

    def __init__(self, calibration, config: ClosureConfig | None = None) -> None:
        self.config = config or ClosureConfig()
        self.K = np.asarray(calibration.K, dtype=np.float64)
        self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING)

    def measure(self, target: Keyframe, current: Keyframe) -> tuple[LoopMeasurement | None, str]:
        """(measurement, "ok") or (None, why not)."""
        cfg = self.config
        if len(target) < cfg.min_inliers or len(current) < cfg.min_inliers:
            return None, "too_few_features"
        pairs = self._matcher.knnMatch(target.descriptors, current.descriptors, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < cfg.ratio_test * p[1].distance]
        if len(good) < cfg.min_inliers:
            return None, "too_few_matches"
        object_points = target.points_m[[m.queryIdx for m in good]].astype(np.float64)
        image_points = current.pixels_px[[m.trainIdx for m in good]].astype(np.float64)
        found, rvec, tvec, inliers = cv2.solvePnPRansac(
            object_points,
            image_points,
            self.K,
            None,
            iterationsCount=cfg.ransac_iterations,
            reprojectionError=cfg.ransac_reprojection_px,
            confidence=0.999,
            flags=cv2.SOLVEPNP_EPNP,
        )
        n_inliers = 0 if inliers is None else len(inliers)
        if not found or n_inliers < cfg.min_inliers or n_inliers < cfg.min_inlier_ratio * len(good):
            return None, "too_few_inliers"
        idx = inliers.ravel()
        rvec, tvec = cv2.solvePnPRefineLM(object_points[idx], image_points[idx], self.K, None, rvec, tvec)
        cur_from_key = np.eye(4)
        cur_from_key[:3, :3] = cv2.Rodrigues(rvec)[0]
        cur_from_key[:3, 3] = tvec.ravel()
        if not np.isfinite(cur_from_key).all():
            return None, "degenerate"
        if np.linalg.norm(cur_from_key[:3, 3]) > cfg.max_distance_m:
            return None, "too_far"
        points_cur = object_points[idx] @ cur_from_key[:3, :3].T + cur_from_key[:3, 3]
        if (points_cur[:, 2] <= 0).any():
            return None, "degenerate"
        residuals = self._project(points_cur) - image_points[idx]
        rmse = float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))
        information = self._planar_information(cur_from_key, points_cur, rmse)
        if information is None:
            return None, "degenerate"
        agent_from_target = tuple(float(v) for v in planar_from_pose(cur_from_key))
        return (
            LoopMeasurement(agent_from_target, information, cur_from_key, n_inliers, len(good), rmse),  # type: ignore[arg-type]
            "ok",
        )

    def _project(self, points_cur: np.ndarray) -> np.ndarray:
        k = self.K
        z = points_cur[:, 2]
        return np.column_stack(
            [k[0, 0] * points_cur[:, 0] / z + k[0, 2], k[1, 1] * points_cur[:, 1] / z + k[1, 2]]
        )

    def _planar_information(self, cur_from_key: np.ndarray, points_cur: np.ndarray, rmse_px: float):
        """Information (3, 3) of the planar measurement, or None when the pose is unobservable."""
        cfg = self.config
        fx, fy = self.K[0, 0], self.K[1, 1]
        x, y, z = points_cur[:, 0], points_cur[:, 1], points_cur[:, 2]
        du = np.zeros((len(z), 2, 3))
        du[:, 0, 0], du[:, 0, 2] = fx / z, -fx * x / z**2
        du[:, 1, 1], du[:, 1, 2] = fy / z, -fy * y / z**2
        dx = np.zeros((len(z), 3, 6))
        dx[:, :, :3] = -_skew(points_cur)
        dx[:, :, 3:] = np.eye(3)
        jac = (du @ dx).reshape(-1, 6)
        sigma_px = max(rmse_px, _MIN_PIXEL_SIGMA_PX)
        try:
            cov6 = sigma_px**2 * np.linalg.inv(jac.T @ jac)
        except np.linalg.LinAlgError:
            return None
        # Planar projection's Jacobian by central differences (it is smooth near any valid pose).
        h = 1e-6
        a = np.zeros((3, 6))
        for k in range(6):
            delta = np.zeros(6)
            delta[k] = h
            plus = planar_from_pose(_perturbed(cur_from_key, delta))
            minus = planar_from_pose(_perturbed(cur_from_key, -delta))
            diff = plus - minus
            diff[2] = wrap_angle(diff[2])
            a[:, k] = diff / (2 * h)
        cov = cfg.covariance_inflation * (a @ cov6 @ a.T)
        cov += np.diag([cfg.sigma_floor_xy_m**2, cfg.sigma_floor_xy_m**2, cfg.sigma_floor_yaw_rad**2])
        if not np.isfinite(cov).all():
            return None
        information = np.linalg.inv(cov)
        return 0.5 * (information + information.T)
