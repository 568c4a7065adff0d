"""The relative pose of a revisit: a stored keyframe's 3-D points found in the current stereo frame.

Matches: the keyframe's descriptors against the current frame's (brute force; SIFT's, the default, by L2,
ORB's with `closure.descriptor = "orb"` by Hamming distance), kept when the best is clearly better than the
second best (Lowe's ratio). Pose: PnP with RANSAC on (keyframe 3-D points, current pixels) gives the inliers
and a first `camera_cur_from_camera_key`; a two-view stereo bundle adjustment of the inliers
(`LoopMeasurer._refine`) gives the pose and its covariance. A closure is rejected
with fewer than `min_inliers` inliers, an inlier share below `min_inlier_ratio`, a keyframe farther than
`max_distance_m`, or a position less certain than `max_sigma_m` (on the synthetic renders true revisits give
70–340 inliers, unrelated places fewer than 10).

Why a bundle adjustment rather than PnP refined on the current pixels alone: PnP treats the keyframe's
stereo points as exact, but a point 30 m away with a 0.3 px disparity error is metres off in depth, and on
real KITTI 06 pairs 4–10 m apart the PnP pose was off by up to a metre with a covariance that claimed
centimetres. Here every point is an unknown seen by both stereo pairs, (u, v, disparity) in each with
σ = `pixel_sigma_px` on u, v and `disparity_sigma_px` on d, so depth errors are in the model and the pose's
covariance (the points marginalised) is honest: on real 06, accepted measurements 1–4 m apart are within
their χ² gate (docs/views.md, "Closure measurement").

The loop link is the planar part of that transform, `agent_from_target = planar_from_pose(cur_from_key)`
(the vertex's pose seen from the agent; see `hippo_nav.geometry`). Its covariance propagates the bundle
adjustment's 6×6 pose covariance through the planar projection, times `covariance_inflation` (for errors
the model leaves out: rolling matches, calibration) and floored at `sigma_floor_*`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.closure.config import ClosureConfig
from hippo_nav.closure.keyframes import DESCRIPTOR_BYTES, Keyframe
from hippo_nav.geometry import planar_from_pose, skew, wrap_angle

_GN_ITERATIONS = 10
_MIN_REFINED_POINTS = 6
_HUBER = 2.5  # whitened error (σ) beyond which an inlier's weight falls off


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
        self.baseline_m = float(calibration.baseline_m)
        self._sift = self.config.descriptor == "sift"
        self._matcher = cv2.BFMatcher(cv2.NORM_L2 if self._sift else cv2.NORM_HAMMING)

    def measure(
        self, target: Keyframe, current: Keyframe, min_inliers: int | None = None
    ) -> tuple[LoopMeasurement | None, str]:
        """(measurement, "ok") or (None, why not); `min_inliers`: the bar (None: the config's)."""
        cfg = self.config
        bar = cfg.min_inliers if min_inliers is None else int(min_inliers)
        if len(target) < bar or len(current) < bar:
            return None, "too_few_features"
        width = DESCRIPTOR_BYTES[cfg.descriptor]
        if target.descriptors.shape[1] != width or current.descriptors.shape[1] != width:
            raise HippoNavError(
                f"keyframe descriptors of {target.descriptors.shape[1]} and {current.descriptors.shape[1]} "
                f"bytes cannot be matched as closure.descriptor = {cfg.descriptor!r} ({width} bytes): a map "
                "must be continued with the descriptor it was made with"
            )
        if self._sift:
            pairs = self._matcher.knnMatch(
                target.descriptors.astype(np.float32), current.descriptors.astype(np.float32), k=2
            )
        else:
            pairs = self._matcher.knnMatch(target.descriptors, current.descriptors, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < cfg.ratio_test * p[1].distance]
        if len(good) < bar:
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
        if not found or n_inliers < bar or n_inliers < cfg.min_inlier_ratio * len(good):
            return None, "too_few_inliers"
        idx = inliers.ravel()
        cur_from_key = np.eye(4)
        cur_from_key[:3, :3] = cv2.Rodrigues(rvec)[0]
        cur_from_key[:3, 3] = tvec.ravel()
        key_index = np.array([good[i].queryIdx for i in idx])
        cur_index = np.array([good[i].trainIdx for i in idx])
        refined = self._refine(
            cur_from_key,
            self._stereo_observations(target, key_index),
            self._stereo_observations(current, cur_index),
            target.points_m[key_index].astype(np.float64),
        )
        if refined is None:
            return None, "degenerate"
        cur_from_key, cov6, rmse = refined
        if np.linalg.norm(cur_from_key[:3, 3]) > cfg.max_distance_m:
            return None, "too_far"
        information = self._planar_information(cur_from_key, cov6)
        if information is None:
            return None, "degenerate"
        # A link this uncertain adds little and is where wrong poses hide: on the 00 render at `strong` the
        # two accepted measurements off by 3 m or more had σ of 1.5-1.6 m (docs/results.md).
        sigma_m = np.sqrt(max(float(np.linalg.eigvalsh(np.linalg.inv(information)[:2, :2]).max()), 0.0))
        if not sigma_m <= cfg.max_sigma_m:
            return None, "uncertain"
        agent_from_target = tuple(float(v) for v in planar_from_pose(cur_from_key))
        return (
            LoopMeasurement(agent_from_target, information, cur_from_key, n_inliers, len(good), rmse),  # type: ignore[arg-type]
            "ok",
        )

    def _stereo_observations(self, keyframe: Keyframe, index: np.ndarray) -> np.ndarray:
        """(n, 3) stereo observations (u, v, disparity) of the chosen features of a keyframe."""
        z = keyframe.points_m[index, 2].astype(np.float64)
        return np.column_stack(
            [keyframe.pixels_px[index].astype(np.float64), self.K[0, 0] * self.baseline_m / z]
        )

    def _stereo_projection(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stereo observation (u, v, d) of camera-frame points (n, 3) and its Jacobian (n, 3, 3)."""
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        fb = fx * self.baseline_m
        h = np.column_stack([fx * x / z + cx, fy * y / z + cy, fb / z])
        jac = np.zeros((len(z), 3, 3))
        jac[:, 0, 0], jac[:, 0, 2] = fx / z, -fx * x / z**2
        jac[:, 1, 1], jac[:, 1, 2] = fy / z, -fy * y / z**2
        jac[:, 2, 2] = -fb / z**2
        return h, jac

    def _normal_equations(self, pose, points, seen_key, seen_cur, weight):
        """Residuals, χ² per point and the blocks of the normal equations of `_refine` at (pose, points);
        `weight` (n, 3) the diagonal information of each point's observations. None when a point is behind
        a camera."""
        points_cur = points @ pose[:3, :3].T + pose[:3, 3]
        if (points[:, 2] <= 0).any() or (points_cur[:, 2] <= 0).any():
            return None
        h_key, j_key = self._stereo_projection(points)
        h_cur, j_cur = self._stereo_projection(points_cur)
        r_key, r_cur = h_key - seen_key, h_cur - seen_cur
        dx = np.zeros((len(points), 3, 6))
        dx[:, :, :3] = -skew(points_cur)
        dx[:, :, 3:] = np.eye(3)
        j_pose = j_cur @ dx  # current observation w.r.t. the pose perturbation δ
        j_point = j_cur @ pose[:3, :3]  # current observation w.r.t. the key-frame point
        h_pp = np.einsum("nki,nk,nkj->nij", j_pose, weight, j_pose)
        h_pt = np.einsum("nki,nk,nkj->nij", j_pose, weight, j_point)
        h_tt = np.einsum("nki,nk,nkj->nij", j_key, weight, j_key) + np.einsum(
            "nki,nk,nkj->nij", j_point, weight, j_point
        )
        g_p = np.einsum("nki,nk,nk->ni", j_pose, weight, r_cur)
        g_t = np.einsum("nki,nk,nk->ni", j_key, weight, r_key) + np.einsum(
            "nki,nk,nk->ni", j_point, weight, r_cur
        )
        return r_cur, h_pp, h_pt, h_tt, g_p, g_t

    def _refine(
        self, cur_from_key: np.ndarray, seen_key: np.ndarray, seen_cur: np.ndarray, points_key: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, float] | None:
        """Two-view stereo bundle adjustment of the inliers.

        Unknowns: the pose `cur_from_key` (a left perturbation δ = (ω, τ)) and every matched point X in the
        key frame. Observations: each point's (u, v, disparity) in the keyframe and in the current frame,
        independent, σ = `pixel_sigma_px` on u and v and `disparity_sigma_px` on d. Gauss–Newton with the
        points eliminated through their 3×3 blocks (Schur complement), a Huber loss on each point's
        whitened error. The pose's covariance is the inverse of the reduced system (the points
        marginalised), widened when the points fit worse than their modelled noise. Returns (pose, 6×6
        covariance, RMSE px of the current reprojection) or None when the geometry is degenerate."""
        cfg = self.config
        if len(points_key) < _MIN_REFINED_POINTS:
            return None
        sigma = np.array([cfg.pixel_sigma_px, cfg.pixel_sigma_px, cfg.disparity_sigma_px])
        information = np.broadcast_to(1.0 / sigma**2, points_key.shape)
        pose, points = cur_from_key.copy(), points_key.copy()
        for _ in range(_GN_ITERATIONS):
            system = self._normal_equations(pose, points, seen_key, seen_cur, information)
            if system is None:
                return None
            # Huber: a point whose whitened error exceeds `_HUBER` counts linearly (weights rescaled).
            chi2_point = self._chi2_per_point(pose, points, seen_key, seen_cur, information)
            robust = np.where(chi2_point <= _HUBER**2, 1.0, _HUBER / np.sqrt(np.maximum(chi2_point, 1e-12)))
            system = self._normal_equations(pose, points, seen_key, seen_cur, information * robust[:, None])
            if system is None:
                return None
            _, h_pp, h_pt, h_tt, g_p, g_t = system
            try:
                h_tt_inv = np.linalg.inv(h_tt)
                reduced = (h_pp - h_pt @ h_tt_inv @ h_pt.transpose(0, 2, 1)).sum(0)
                rhs = (g_p - np.einsum("nij,njk,nk->ni", h_pt, h_tt_inv, g_t)).sum(0)
                delta = -np.linalg.solve(reduced, rhs)
            except np.linalg.LinAlgError:
                return None
            step = -np.einsum("nij,nj->ni", h_tt_inv, g_t + np.einsum("nji,j->ni", h_pt, delta))
            pose = _perturbed(pose, delta)
            points = points + step
            # A far point (disparity of a pixel or two) can be stepped behind a camera: it carries no usable
            # depth, so it leaves the problem rather than failing the measurement.
            in_front = (points[:, 2] > 0) & ((points @ pose[:3, :3].T + pose[:3, 3])[:, 2] > 0)
            if not in_front.all():
                if in_front.sum() < _MIN_REFINED_POINTS:
                    return None
                points, seen_key, seen_cur = points[in_front], seen_key[in_front], seen_cur[in_front]
                information = information[in_front]
            if np.linalg.norm(delta) < 1e-10:
                break
        system = self._normal_equations(pose, points, seen_key, seen_cur, information)
        if system is None or not np.isfinite(pose).all():
            return None
        r_cur, h_pp, h_pt, h_tt, _, _ = system
        chi2 = float(self._chi2_per_point(pose, points, seen_key, seen_cur, information).sum())
        dof = max(3 * len(points) - 6, 1)  # 6 observations and 3 unknowns per point, 6 for the pose
        try:
            reduced = (h_pp - h_pt @ np.linalg.inv(h_tt) @ h_pt.transpose(0, 2, 1)).sum(0)
            cov6 = max(chi2 / dof, 1.0) * np.linalg.inv(reduced)
        except np.linalg.LinAlgError:
            return None
        if not np.isfinite(cov6).all():
            return None
        rmse = float(np.sqrt(np.mean(np.sum(r_cur[:, :2] ** 2, axis=1))))
        return pose, cov6, rmse

    def _chi2_per_point(self, pose, points, seen_key, seen_cur, information) -> np.ndarray:
        points_cur = points @ pose[:3, :3].T + pose[:3, 3]
        r_key = self._stereo_projection(points)[0] - seen_key
        r_cur = self._stereo_projection(points_cur)[0] - seen_cur
        return (r_key**2 * information).sum(1) + (r_cur**2 * information).sum(1)

    def _planar_information(self, cur_from_key: np.ndarray, cov6: np.ndarray):
        """Information (3, 3) of the planar measurement, or None when the pose is unobservable."""
        cfg = self.config
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
