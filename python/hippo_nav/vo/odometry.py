"""Feature-based stereo visual odometry with OpenCV (the paper used direct sparse stereo odometry).

Per stereo frame k (rectified pair, camera x right, y down, z forward; docs/spec.md §9):

1. Features: Shi–Tomasi corners in the left image, spread by a minimum distance.
2. Stereo: each corner is tracked into the right image with pyramidal KLT, started at a typical
   disparity, and back again (left–right consistency); a rectified pair allows only a small row error
   and positive disparity. Depth `Z = fx · b / d` gives the corner's 3-D point in camera k.
3. Temporal: the 3-D points of frame k−1 are projected into frame k with the motion prior (the last
   step, constant velocity) and KLT-tracked from there, with a forward–backward check. The prediction
   is what keeps 40 px image motion near facades trackable.
4. Pose: PnP with RANSAC on (points of k−1, pixels in k) gives `camera_cur_from_camera_prev`; the
   inliers are refined with Levenberg–Marquardt, then by a joint Gauss–Newton fit of the reprojection
   error in *both* images of frame k (the right-image residual constrains depth along the baseline,
   which halves the translation error on forward motion).
5. Checks: too few tracked points or inliers (low texture, blur, a covered lens) or a step beyond the
   plausible speed or turn makes the frame *flagged*: the motion prior stands in for the step and the
   status says why, so the odometry never crashes or jumps on a bad frame.

The step returned is `camera_prev_from_camera_cur` (4×4): the current camera's pose in the previous
camera's frame, so `world_from_cur = world_from_prev @ step`. `planar_step` reduces it to the map's
(forward, left, yaw) and `VoStep.planar_velocities` to the engine's yaw rate and speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from hippo_nav._core import HippoNavError
from hippo_nav.geometry import planar_step

STATUSES = ("first", "ok", "low_texture", "rejected")
"""`VoStep.status`: first frame (identity); a measured step; too few features, tracks or inliers (prior
used); a measured step beyond the plausibility limits (prior used)."""


class VoParams(BaseModel):
    """Stereo VO parameters; pixel values refer to the input image resolution."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    max_features: int = Field(1500, ge=8, description="corners detected per left image at most")
    feature_quality: float = Field(0.005, gt=0.0, lt=1.0, description="Shi–Tomasi quality level")
    min_feature_distance_px: float = Field(7.0, gt=0.0, description="minimum distance between corners")
    klt_window_px: int | None = Field(
        None,
        ge=5,
        description="KLT window side (odd); None: width/25 within 11–15 px (13 at 320 px, 15 on KITTI)",
    )
    klt_levels: int = Field(4, ge=0, le=8, description="KLT pyramid levels above the image")
    forward_backward_px: float = Field(1.0, gt=0.0, description="max forward–backward KLT error")
    stereo_row_tolerance_px: float = Field(1.5, gt=0.0, description="max row difference of a stereo match")
    min_disparity_px: float = Field(1.0, gt=0.0, description="nearer than fx·b/this: farther points dropped")
    stereo_guess_depth_m: float = Field(20.0, gt=0.0, description="depth whose disparity starts stereo KLT")
    ransac_reprojection_px: float = Field(1.0, gt=0.0, description="PnP RANSAC inlier threshold")
    ransac_iterations: int = Field(200, ge=10)
    ransac_confidence: float = Field(0.999, gt=0.0, lt=1.0)
    min_inliers: int = Field(25, ge=6, description="fewer PnP inliers flag the frame (prior used)")
    min_inlier_ratio: float = Field(
        0.6, ge=0.0, le=1.0, description="below this inlier share, tracking is retried without the prior"
    )
    min_accept_ratio: float = Field(
        0.4, ge=0.0, le=1.0, description="below this inlier share the step is not trusted (prior used)"
    )
    stereo_refinement: bool = Field(True, description="refine the step on left and right reprojections")
    max_speed_m_s: float = Field(60.0, gt=0.0, description="a faster step is rejected (prior used)")
    max_yaw_rate_rad_s: float = Field(3.0, gt=0.0, description="a faster turn is rejected (prior used)")
    seed: int = Field(0, description="seeds OpenCV's RNG (RANSAC) on reset, so runs are repeatable")
    default_dt_s: float = Field(0.1, gt=0.0, description="frame interval used when timestamps do not advance")
    max_prior_gap_s: float = Field(
        1.0,
        gt=0.0,
        description="after a longer gap between frames the motion prior is 'no motion': a gap is not "
        "extrapolated into motion (100 s at the last speed would be a kilometre)",
    )


@dataclass(frozen=True)
class VoStep:
    """The outcome of one frame."""

    camera_prev_from_camera_cur: np.ndarray  # (4, 4) SE(3)
    status: str  # one of STATUSES
    dt_s: float  # time since the previous frame (0 on the first)
    n_features: int  # stereo-matched corners of this frame (the points tracked into the next)
    n_tracked: int  # points of the previous frame tracked into this one
    n_inliers: int  # PnP inliers
    reprojection_rmse_px: float  # of the inliers, after refinement (NaN when not measured)

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def planar_velocities(self) -> tuple[float, float]:
        """(yaw_rate_rad_s, speed_m_s) of the step; speed is negative when reversing, 0 on the first frame."""
        return planar_velocities(self.camera_prev_from_camera_cur, self.dt_s)


def planar_velocities(camera_prev_from_camera_cur: np.ndarray, dt_s: float) -> tuple[float, float]:
    """(yaw_rate_rad_s, speed_m_s) the engine integrates for a step taking `dt_s` (0, 0 when dt_s ≤ 0).

    Speed is the planar chord length, negative when the camera moved backwards."""
    if dt_s <= 0:
        return 0.0, 0.0
    forward_m, left_m, yaw_rad = planar_step(camera_prev_from_camera_cur)
    speed_m = float(np.copysign(np.hypot(forward_m, left_m), forward_m))
    return yaw_rad / dt_s, speed_m / dt_s


@dataclass
class _StereoPoints:
    gray: np.ndarray  # left image
    right: np.ndarray  # right image
    pixels: np.ndarray  # (n, 2) float32, left image
    points_m: np.ndarray  # (n, 3) float64, camera frame


class StereoOdometry:
    """`StereoOdometry(calibration, params).process(frame) -> VoStep`, one frame after another."""

    def __init__(self, calibration, params: VoParams | None = None) -> None:
        self.params = params or VoParams()
        self.calibration = calibration
        self.K = calibration.K
        self.fx, self.fy = calibration.fx, calibration.fy
        self.cx, self.cy = calibration.cx, calibration.cy
        self.baseline_m = calibration.baseline_m
        if not (self.fx > 0 and self.fy > 0 and self.baseline_m > 0 and np.isfinite(self.K).all()):
            raise HippoNavError(
                f"calibration unusable for stereo VO: fx={self.fx}, fy={self.fy}, baseline={self.baseline_m} m "
                "(need positive focal lengths and P1[0,3] = -fx·baseline < 0)"
            )
        w = self.params.klt_window_px or int(np.clip(calibration.image_size_px[0] // 25, 11, 15))
        w |= 1
        self._klt = {
            "winSize": (w, w),
            "maxLevel": self.params.klt_levels,
            "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01),
        }
        self.reset()

    def reset(self) -> None:
        """Forget the previous frame and the motion prior (the next frame starts a new trajectory)."""
        cv2.setRNGSeed(self.params.seed)
        self._previous: _StereoPoints | None = None
        self._previous_time_s: float | None = None
        self._prior_step = np.eye(4)  # camera_prev_from_camera_cur of the last good frame
        self._prior_dt_s = self.params.default_dt_s

    # ------------------------------------------------------------------------------------------------
    def process(self, frame) -> VoStep:
        """The step from the previous frame to `frame` (identity with status "first" on the first)."""
        left, right = self._check_images(frame)
        current = self._stereo_points(left, right)
        stamp = float(frame.timestamp_s)
        if self._previous is None:
            self._previous, self._previous_time_s = current, stamp
            return VoStep(np.eye(4), "first", 0.0, len(current.pixels), 0, 0, float("nan"))
        dt_s = stamp - float(self._previous_time_s)
        if not (np.isfinite(dt_s) and dt_s > 0):
            dt_s = self.params.default_dt_s
        # The prior scaled to this frame interval (constant velocity through a dropped frame).
        if dt_s > self.params.max_prior_gap_s:
            prior = np.eye(4)
        else:
            prior = _scale_step(self._prior_step, dt_s / self._prior_dt_s)
        step, status, n_tracked, n_inliers, rmse = self._measure(self._previous, current, prior)
        if status == "ok" and not self._plausible(step, dt_s):
            status = "rejected"
        if status != "ok":
            step = prior
        else:
            self._prior_step, self._prior_dt_s = step, dt_s
        self._previous, self._previous_time_s = current, stamp
        return VoStep(step, status, dt_s, len(current.pixels), n_tracked, n_inliers, rmse)

    # ------------------------------------------------------------------------------------------------
    def _check_images(self, frame) -> tuple[np.ndarray, np.ndarray]:
        where = f"frame {getattr(frame, 'index', '?')}"
        images = []
        for name in ("left", "right"):
            image = np.asarray(getattr(frame, name))
            if image.ndim != 2 or image.dtype != np.uint8:
                raise HippoNavError(
                    f"{where}: the {name} image must be 8-bit gray (H, W), got {image.dtype} {image.shape}"
                )
            images.append(np.ascontiguousarray(image))
        left, right = images
        if left.shape != right.shape:
            raise HippoNavError(f"{where}: left {left.shape} and right {right.shape} image sizes differ")
        width, height = self.calibration.image_size_px
        if left.shape != (height, width):
            raise HippoNavError(
                f"{where}: image is {left.shape[1]}×{left.shape[0]} px but the calibration is for "
                f"{width}×{height}; use the calib.txt of this sequence"
            )
        return left, right

    def _stereo_points(self, left: np.ndarray, right: np.ndarray) -> _StereoPoints:
        p = self.params
        corners = cv2.goodFeaturesToTrack(
            left, p.max_features, p.feature_quality, p.min_feature_distance_px, blockSize=5
        )
        empty = _StereoPoints(left, right, np.zeros((0, 2), np.float32), np.zeros((0, 3)))
        if corners is None:
            return empty
        pts = corners.reshape(-1, 2).astype(np.float32)
        guess = pts.copy()
        guess[:, 0] -= self.fx * self.baseline_m / p.stereo_guess_depth_m
        in_right, ok, _ = cv2.calcOpticalFlowPyrLK(
            left, right, pts, guess, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self._klt
        )
        back, ok_back, _ = cv2.calcOpticalFlowPyrLK(
            right, left, in_right, pts.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self._klt
        )
        disparity = pts[:, 0] - in_right[:, 0]
        keep = (
            (ok.ravel() == 1)
            & (ok_back.ravel() == 1)
            & (np.linalg.norm(back - pts, axis=1) < p.forward_backward_px)
            & (np.abs(in_right[:, 1] - pts[:, 1]) < p.stereo_row_tolerance_px)
            & (disparity > p.min_disparity_px)
        )
        if not keep.any():
            return empty
        pts, disparity = pts[keep], disparity[keep].astype(np.float64)
        z = self.fx * self.baseline_m / disparity
        x = (pts[:, 0] - self.cx) * z / self.fx
        y = (pts[:, 1] - self.cy) * z / self.fy
        return _StereoPoints(left, right, pts, np.column_stack([x, y, z]))

    def _measure(self, prev: _StereoPoints, cur: _StereoPoints, prior: np.ndarray):
        """(step, status, n_tracked, n_inliers, rmse) from tracking `prev`'s points into `cur`.

        A sudden change of motion (a car turning into a corner) makes the prior's prediction wrong by
        tens of pixels, and KLT started there can settle on a consistent but wrong set of matches in
        repetitive texture; so several motion hypotheses are tried in turn (see below)."""
        p = self.params
        if len(prev.pixels) < p.min_inliers:
            return (prior, "low_texture", 0, 0, float("nan"))
        # Hypotheses for where the points went, tried in turn until most tracks agree with the PnP
        # solution (else the one with most inliers wins): the motion prior; a turn by the image's
        # global horizontal shift (phase correlation; a car entering a corner turns faster than the
        # prior says) at the prior's speed; straight ahead at that speed; no motion.
        speed_m = float(np.linalg.norm(prior[:3, 3]))
        hypotheses = (
            lambda: prior,
            lambda: _planar_motion(speed_m, self._image_yaw_rad(prev.gray, cur.gray)),
            lambda: _planar_motion(speed_m, 0.0),
            lambda: np.eye(4),
        )
        best = None
        for hypothesis in hypotheses:
            cur_from_prev = np.linalg.inv(hypothesis())
            predicted = self._project(prev.points_m, cur_from_prev)
            guess = np.where(predicted[:, 2:] > 0, predicted[:, :2], prev.pixels).astype(np.float32)
            outcome = self._solve(prev, cur, guess, cur_from_prev)
            if best is None or outcome[2] > best[2]:
                best = outcome
            if outcome[2] >= p.min_inliers and outcome[2] >= p.min_inlier_ratio * outcome[1]:
                break
        solution, n_tracked, n_inliers = best
        if solution is None or n_inliers < p.min_inliers or n_inliers < p.min_accept_ratio * n_tracked:
            return (prior, "low_texture", n_tracked, n_inliers, float("nan"))
        cur_from_prev, rmse = solution
        return (np.linalg.inv(cur_from_prev), "ok", n_tracked, n_inliers, rmse)

    def _solve(self, prev: _StereoPoints, cur: _StereoPoints, guess: np.ndarray, cur_from_prev: np.ndarray):
        """((cur_from_prev, rmse) or None, n_tracked, n_inliers) for one initial flow hypothesis."""
        p = self.params
        tracked, ok, _ = cv2.calcOpticalFlowPyrLK(
            prev.gray, cur.gray, prev.pixels, guess, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self._klt
        )
        back, ok_back, _ = cv2.calcOpticalFlowPyrLK(
            cur.gray, prev.gray, tracked, prev.pixels.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self._klt
        )
        h, w = cur.gray.shape
        good = (
            (ok.ravel() == 1)
            & (ok_back.ravel() == 1)
            & (np.linalg.norm(back - prev.pixels, axis=1) < p.forward_backward_px)
            & (tracked[:, 0] >= 0)
            & (tracked[:, 0] <= w - 1)
            & (tracked[:, 1] >= 0)
            & (tracked[:, 1] <= h - 1)
        )
        n_tracked = int(good.sum())
        if n_tracked < p.min_inliers:
            return (None, n_tracked, 0)
        object_points = prev.points_m[good]
        image_points = tracked[good].astype(np.float64)
        rvec0, _ = cv2.Rodrigues(cur_from_prev[:3, :3])
        found, rvec, tvec, inliers = cv2.solvePnPRansac(
            object_points,
            image_points,
            self.K,
            None,
            rvec=rvec0.copy(),
            tvec=cur_from_prev[:3, 3].reshape(3, 1).copy(),
            useExtrinsicGuess=True,
            iterationsCount=p.ransac_iterations,
            reprojectionError=p.ransac_reprojection_px,
            confidence=p.ransac_confidence,
            flags=cv2.SOLVEPNP_ITERATIVE,
        )
        n_inliers = 0 if inliers is None else len(inliers)
        if not found or n_inliers < 6:
            return (None, n_tracked, n_inliers)
        idx = inliers.ravel()
        rvec, tvec = cv2.solvePnPRefineLM(object_points[idx], image_points[idx], self.K, None, rvec, tvec)
        transform = np.eye(4)
        transform[:3, :3] = cv2.Rodrigues(rvec)[0]
        transform[:3, 3] = tvec.ravel()
        if p.stereo_refinement:
            transform = self._refine_stereo(transform, object_points[idx], tracked[good][idx], cur)
        rmse = self._rmse(transform, object_points[idx], image_points[idx])
        return ((transform, rmse), n_tracked, n_inliers)

    def _image_yaw_rad(self, prev_gray: np.ndarray, cur_gray: np.ndarray) -> float:
        """Yaw (left positive) that explains the global horizontal image shift between two frames."""
        window = cv2.createHanningWindow(prev_gray.shape[::-1], cv2.CV_32F)
        (shift_px, _), _ = cv2.phaseCorrelate(
            prev_gray.astype(np.float32), cur_gray.astype(np.float32), window
        )
        # A left turn moves the scene right (positive shift).
        return float(np.arctan2(shift_px, self.fx))

    def _refine_stereo(
        self, cur_from_prev: np.ndarray, points_m: np.ndarray, left_px: np.ndarray, cur: _StereoPoints
    ) -> np.ndarray:
        """Gauss–Newton on left + right reprojection in the current frame.

        The right-image position of each tracked point is found by KLT from its left position (started at
        the disparity the current estimate predicts); points without a consistent right match keep only
        their left residual. Robust (Huber) weights keep a few bad tracks from pulling the step."""
        p = self.params
        predicted = self._project(points_m, cur_from_prev)
        disparity_guess = self.fx * self.baseline_m / np.maximum(predicted[:, 2], 1e-3)
        start = left_px.astype(np.float32)
        guess = start.copy()
        guess[:, 0] -= disparity_guess.astype(np.float32)
        in_right, ok, _ = cv2.calcOpticalFlowPyrLK(
            cur.gray, cur.right, start, guess, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self._klt
        )
        has_right = (
            (ok.ravel() == 1)
            & (np.abs(in_right[:, 1] - start[:, 1]) < p.stereo_row_tolerance_px)
            & (start[:, 0] - in_right[:, 0] > p.min_disparity_px)
        )
        transform = cur_from_prev.copy()
        huber_px = p.ransac_reprojection_px
        for _ in range(5):
            x = points_m @ transform[:3, :3].T + transform[:3, 3]
            z = x[:, 2]
            if (z <= 0).any():
                return cur_from_prev
            residuals, jacobians = [], []
            for offset_m, observed, mask in (
                (0.0, left_px.astype(np.float64), np.ones(len(x), bool)),
                (self.baseline_m, in_right.astype(np.float64), has_right),
            ):
                xs = x[mask] - np.array([offset_m, 0.0, 0.0])
                zs = xs[:, 2]
                u = self.fx * xs[:, 0] / zs + self.cx
                v = self.fy * xs[:, 1] / zs + self.cy
                r = np.column_stack([u, v]) - observed[mask]
                # d(u, v)/d(point in camera), then the point's derivative for a left perturbation
                # δ = (ω, τ): d x = −[x]× ω + τ (x the point in the current *left* frame).
                du = np.zeros((len(xs), 2, 3))
                du[:, 0, 0] = self.fx / zs
                du[:, 0, 2] = -self.fx * xs[:, 0] / zs**2
                du[:, 1, 1] = self.fy / zs
                du[:, 1, 2] = -self.fy * xs[:, 1] / zs**2
                xm = x[mask]
                dx = np.zeros((len(xs), 3, 6))
                dx[:, :, :3] = -_skew(xm)
                dx[:, :, 3:] = np.eye(3)
                j = du @ dx
                if offset_m > 0:
                    # Right image: only u (the disparity) is new; its v repeats the left one, plus
                    # whatever row offset the rectification left, which would tilt the pitch.
                    r, j = r[:, :1], j[:, :1]
                residuals.append(r.reshape(-1))
                jacobians.append(j.reshape(-1, 6))
            r = np.concatenate(residuals)  # (m,) pixel residuals
            jac = np.concatenate(jacobians)  # (m, 6)
            weight = np.where(np.abs(r) <= huber_px, 1.0, huber_px / np.maximum(np.abs(r), 1e-12))
            jw = jac * weight[:, None]
            hessian = jw.T @ jac
            gradient = jw.T @ r
            try:
                delta = -np.linalg.solve(hessian, gradient)
            except np.linalg.LinAlgError:
                return cur_from_prev
            update = np.eye(4)
            update[:3, :3] = cv2.Rodrigues(delta[:3])[0]
            update[:3, 3] = delta[3:]
            transform = update @ transform
            if np.linalg.norm(delta) < 1e-9:
                break
        return transform

    def _project(self, points_m: np.ndarray, cur_from_prev: np.ndarray) -> np.ndarray:
        """(n, 3): pixel u, v and depth of points of the previous camera seen from the current one."""
        x = points_m @ cur_from_prev[:3, :3].T + cur_from_prev[:3, 3]
        z = np.where(np.abs(x[:, 2]) < 1e-9, 1e-9, x[:, 2])
        return np.column_stack([self.fx * x[:, 0] / z + self.cx, self.fy * x[:, 1] / z + self.cy, x[:, 2]])

    def _rmse(self, cur_from_prev: np.ndarray, points_m: np.ndarray, pixels: np.ndarray) -> float:
        projected = self._project(points_m, cur_from_prev)[:, :2]
        return float(np.sqrt(np.mean(np.sum((projected - pixels) ** 2, axis=1))))

    def _plausible(self, step: np.ndarray, dt_s: float) -> bool:
        angle = np.arccos(np.clip((np.trace(step[:3, :3]) - 1) / 2, -1.0, 1.0))
        return (
            bool(np.isfinite(step).all())
            and np.linalg.norm(step[:3, 3]) <= self.params.max_speed_m_s * dt_s
            and angle <= self.params.max_yaw_rate_rad_s * dt_s
        )


def _planar_motion(forward_m: float, yaw_rad: float) -> np.ndarray:
    """camera_prev_from_camera_cur of a forward move and a turn about the camera's −y axis (left +)."""
    step = np.eye(4)
    step[:3, :3] = cv2.Rodrigues(np.array([0.0, -yaw_rad, 0.0]))[0]
    step[2, 3] = forward_m
    return step


def _skew(v: np.ndarray) -> np.ndarray:
    """(n, 3, 3) cross-product matrices of (n, 3) vectors."""
    s = np.zeros(v.shape[:-1] + (3, 3))
    s[..., 0, 1], s[..., 0, 2] = -v[..., 2], v[..., 1]
    s[..., 1, 0], s[..., 1, 2] = v[..., 2], -v[..., 0]
    s[..., 2, 0], s[..., 2, 1] = -v[..., 1], v[..., 0]
    return s


def _scale_step(step: np.ndarray, factor: float) -> np.ndarray:
    """The SE(3) step scaled in time by `factor` (rotation angle and translation), for the motion prior."""
    if abs(factor - 1.0) < 1e-9:
        return step.copy()
    rvec = cv2.Rodrigues(step[:3, :3])[0] * factor
    out = np.eye(4)
    out[:3, :3] = cv2.Rodrigues(rvec)[0]
    out[:3, 3] = step[:3, 3] * factor
    return out
