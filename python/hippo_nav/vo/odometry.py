"""Feature-based stereo visual odometry with OpenCV (the paper used direct sparse stereo odometry).

Per stereo frame k (rectified pair, camera x right, y down, z forward; docs/spec.md §9):

1. Temporal: the points of frame k−1 (pixel + 3-D point) are projected into frame k with the motion prior
   (the last step, constant velocity) and KLT-tracked from there, with a forward–backward check. The
   prediction is what keeps 40 px image motion near facades trackable.
2. Pose: PnP with RANSAC on (points of k−1, pixels in k) gives `camera_cur_from_camera_prev`; the
   inliers are refined with Levenberg–Marquardt, then by a joint Gauss–Newton fit of the reprojection
   error in *both* images of frame k (the right-image residual constrains depth along the baseline,
   which halves the translation error on forward motion).
3. Stereo: each inlier is KLT-matched into the right image, started at the disparity the pose predicts,
   and back (left–right consistency); a rectified pair allows only a small row error and a positive
   disparity. Every match, temporal and stereo, is then refined with a window that may shear and stretch
   (`refine_matches`, Rust `hippo_vo::tracks`): KLT's square window is biased on a slanted road, and the
   bias has one sign, so it drifts the pitch. These matches feed step 2's right-image residual, and their
   depth `Z = fx · b / d` is the point's 3-D position in camera k: the inliers are carried into frame k+1
   (feature tracking).
4. New corners: where no carried point lies within the minimum distance, FAST corners (the strongest per
   cell of a min-distance grid) top the frame up to `max_features`; they are stereo-matched like in step 3
   but from a typical disparity (a point 20 m away), so on the full pyramid.
5. Window (`window.max_keyframes` ≥ 2, the default 8): a well-tracked frame that moved becomes a keyframe; the
   last keyframes and the landmarks they share (ids kept while a point is tracked) are refined jointly by a
   stereo bundle adjustment in Rust (`hippo_nav._core._SlidingWindow`, crates/hippo_vo), the frame's pose is
   the refined one, and its points carry their refined positions into the next frame (landmarks with an
   outlier observation are dropped). docs/vo.md, "Windowed refinement".
6. Checks: too few tracked points or inliers (low texture, blur, a covered lens) or a step beyond the
   plausible speed or turn makes the frame *flagged*: the motion prior stands in for the step, the
   carried points are dropped (the next frame detects afresh) and the status says why, so the odometry
   never crashes or jumps on a bad frame.
7. The stereo pair itself: over the first frames with texture, the new corners' stereo matches are pooled
   (`_judge_stereo_geometry`). Where most matches on their row lie further *right* in the right image, the
   images are swapped; where matches lie a few pixels apart vertically, the pair is not rectified; where they
   lie exactly where they were, one image was given twice. Each leaves no point with a depth, which looks like
   a textureless scene frame after frame; the odometry warns once with what to fix and says so in
   `stereo_fault`.

Cost. KLT is almost all of it, and its cost is per point and per pyramid level (each level costs about one
window's worth of work, whatever the start). So: a search from afar runs the levels above the image on
the half-size images with a small window, then the full-resolution window on the image alone; a search
whose start is known to a pixel (the backward checks, the right-image match at a predicted disparity) uses
a short pyramid; carried points need no new detection nor a search from afar in the right image. OpenCV's
Python binding does not take prebuilt pyramids (`buildOpticalFlowPyramid`'s output is refused by
`calcOpticalFlowPyrLK` in OpenCV 5.0), but building them is a small part of a call.

The step returned is `camera_prev_from_camera_cur` (4×4): the current camera's pose in the previous
camera's frame, so `world_from_cur = world_from_prev @ step`. `planar_step` reduces it to the map's
(forward, left, yaw) and `VoStep.planar_velocities` to the engine's yaw rate and speed.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from hippo_nav._core import HippoNavError, _SlidingWindow
from hippo_nav.datasets.base import check_stereo_images
from hippo_nav.geometry import planar_step
from hippo_nav.vo.matching import NO_PIXELS as _NO_PIXELS
from hippo_nav.vo.matching import Image, ImageMatcher
from hippo_nav.vo.projection import project, refine_stereo_step, reprojection_rmse, triangulate
from hippo_nav.vo.settings import VoParams
from hippo_nav.vo.stereo_pair import StereoPairWatch

log = logging.getLogger("hippo_nav.vo")

STATUSES = ("first", "ok", "low_texture", "rejected")
"""`VoStep.status`: first frame (identity); a measured step; too few features, tracks or inliers (prior
used); a measured step beyond the plausibility limits (prior used)."""


@dataclass(frozen=True)
class VoStep:
    """The outcome of one frame."""

    camera_prev_from_camera_cur: np.ndarray  # (4, 4) SE(3)
    status: str  # one of STATUSES
    dt_s: float  # time since the previous frame (0 on the first)
    n_features: int  # stereo-matched points of this frame (the points tracked into the next)
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
    left: Image
    pixels: np.ndarray  # (n, 2) float32, left image
    points_m: np.ndarray  # (n, 3) float64, camera frame: where tracking puts them (refined by the window)
    stereo_m: np.ndarray  # (n, 3) float64, camera frame: from this frame's disparity alone
    ids: np.ndarray  # (n,) int64, the same while a point is tracked (the window's landmark ids)
    right_u: np.ndarray  # (n,) float64, right-image column corrected by `disparity_offset_px`


@dataclass
class _Tracks:
    """One tracking + PnP attempt: the pose (None when it failed), counts, and the inlier pairs."""

    cur_from_prev: np.ndarray | None
    n_tracked: int
    n_inliers: int
    object_points: np.ndarray | None = None  # (n, 3) inlier points of the previous frame
    image_px: np.ndarray | None = None  # (n, 2) float32, where they are in the current left image
    ids: np.ndarray | None = None  # (n,) int64, their ids
    stereo_m: np.ndarray | None = None  # (n, 3) their points from the previous frame's disparity alone
    # Every track that passed KLT's checks, inliers or not (the disparity self-calibration's candidates):
    # (points_m, image_px, stereo_m) as above, and where the inliers are among them.
    tracked: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None


_NO_POINTS = np.zeros((0, 3))
_NO_IDS = np.zeros(0, np.int64)
_NO_KEPT = (_NO_PIXELS, _NO_POINTS, _NO_IDS, np.zeros(0))


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
        p = self.params
        self._camera = (self.fx, self.fy, self.cx, self.cy, self.baseline_m)
        self._match = ImageMatcher(calibration, p)
        self._window: _SlidingWindow | None = None
        if p.window.max_keyframes >= 2:
            self._window = _SlidingWindow(
                self.fx, self.fy, self.cx, self.cy, self.baseline_m, p.window_params_json()
            )
        # What the odometry learns of its stereo pair; its disparity offset outlives `reset` (a new trajectory
        # is the same cameras).
        self._pair = StereoPairWatch(p, (self.fx, self.fy, self.cx, self.cy, self.baseline_m))
        self._calibration = self._pair.calibration
        self.reset()

    def reset(self) -> None:
        """Forget the previous frame and the motion prior (the next frame starts a new trajectory)."""
        cv2.setRNGSeed(self.params.seed)
        self._previous: _StereoPoints | None = None
        self._previous_time_s: float | None = None
        self._prior_step = np.eye(4)  # camera_prev_from_camera_cur of the last good frame
        self._prior_dt_s = self.params.default_dt_s
        self._next_id = 0
        # Where the last step handed out ended (the previous frame's pose, refined when it was a keyframe),
        # and the last keyframe's pose.
        self._world_from_previous = np.eye(4)
        self._world_from_keyframe: np.ndarray | None = None
        if self._window is not None:
            self._window.clear()
        self._pair.reset()

    # ------------------------------------------------------------------------------------------------
    def process(self, frame) -> VoStep:
        """The step from the previous frame to `frame` (identity with status "first" on the first).

        With the window on, the step ends at the frame's refined pose and starts where the previous
        step ended: a refinement of earlier keyframes that moves this one enters this step, so the
        chain of steps is the trajectory the VO estimates in real time (each frame as refined when it
        was the newest)."""
        left, right = (Image(image, cv2.pyrDown(image)) for image in self._check_images(frame))
        stamp = float(frame.timestamp_s)
        if self._previous is None:
            current = self._stereo_points(left, right, *_NO_KEPT)
            current, _ = self._keyframe(current, np.eye(4))
            self._previous, self._previous_time_s = current, stamp
            return VoStep(np.eye(4), "first", 0.0, len(current.pixels), 0, 0, float("nan"))
        dt_s = stamp - float(self._previous_time_s or 0.0)
        if not (np.isfinite(dt_s) and dt_s > 0):
            dt_s = self.params.default_dt_s
        # The prior scaled to this frame interval (constant velocity through a dropped frame).
        if dt_s > self.params.max_prior_gap_s:
            prior = np.eye(4)
        else:
            prior = _scale_step(self._prior_step, dt_s / self._prior_dt_s)
        step, status, n_tracked, n_inliers, rmse, kept = self._measure(self._previous, left, right, prior)
        if status == "ok" and not self._plausible(step, dt_s):
            status = "rejected"
        if status != "ok":
            step = prior
        if status != "ok" or not self.params.track_features:
            kept = _NO_KEPT  # detect afresh (after a bad frame the tracks are suspect too)
        current = self._stereo_points(left, right, *kept)
        if status == "ok" and self._window is not None:
            world_from_current = _orthonormal(self._world_from_previous @ step)
            current, world_from_current = self._keyframe(current, world_from_current)
            step = np.linalg.inv(self._world_from_previous) @ world_from_current
            self._world_from_previous = world_from_current
        else:  # the step as measured (window off: exactly the frame-to-frame VO)
            self._world_from_previous = _orthonormal(self._world_from_previous @ step)
        if status == "ok":
            self._prior_step, self._prior_dt_s = step, dt_s  # constant velocity: the step handed out
        self._previous, self._previous_time_s = current, stamp
        return VoStep(step, status, dt_s, len(current.pixels), n_tracked, n_inliers, rmse)

    def _keyframe(
        self, current: _StereoPoints, world_from_current: np.ndarray
    ) -> tuple[_StereoPoints, np.ndarray]:
        """(points carried on, pose) of a well-tracked frame, refined in the window when it is a keyframe.

        Points whose landmark the window found to be an outlier (a moving object, a track that slid) are
        not tracked further; the others carry their refined position into the next frame."""
        p = self.params
        if self._window is None:
            return current, world_from_current
        if self._world_from_keyframe is not None:
            moved = np.linalg.inv(self._world_from_keyframe) @ world_from_current
            angle = np.arccos(np.clip((np.trace(moved[:3, :3]) - 1) / 2, -1.0, 1.0))
            if np.linalg.norm(moved[:3, 3]) < p.keyframe_min_m and angle < p.keyframe_min_rad:
                return current, world_from_current
        outcome = self._window.add_keyframe(
            np.linalg.inv(world_from_current), current.ids, current.pixels.astype(np.float64), current.right_u
        )
        world_from_current = self._world_from_keyframe = np.linalg.inv(outcome["camera_from_world"])
        keep = ~outcome["outlier"]
        points_m = current.points_m
        if p.track_window_points:
            refined = outcome["point_camera"]
            usable = np.isfinite(refined).all(axis=1) & (refined[:, 2] > 0)
            points_m = np.where(usable[:, None], refined, points_m)
        kept = _StereoPoints(
            current.left,
            current.pixels[keep],
            points_m[keep],
            current.stereo_m[keep],
            current.ids[keep],
            current.right_u[keep],
        )
        return kept, world_from_current

    # ------------------------------------------------------------------------------------------------
    def _check_images(self, frame) -> tuple[np.ndarray, np.ndarray]:
        return check_stereo_images(frame, self.calibration.image_size_px)

    def _stereo_points(
        self,
        left: Image,
        right: Image,
        kept_px: np.ndarray,
        kept_m: np.ndarray,
        kept_ids: np.ndarray,
        kept_right_u: np.ndarray,
    ) -> _StereoPoints:
        """This frame's points: those kept from tracking, plus new corners (new ids) where the image has none."""
        p = self.params
        corners = self._match.detect(left.full, p.max_features - len(kept_px), kept_px)
        if len(corners) == 0:
            return _StereoPoints(left, kept_px, kept_m, kept_m, kept_ids, kept_right_u)
        guess = corners.copy()
        guess[:, 0] -= self.fx * self.baseline_m / p.stereo_guess_depth_m - self.disparity_offset_px
        in_right, found = self._match.track(left, right, corners, guess)
        if not self._pair.judged:
            self._pair.judge_geometry(corners[found], in_right[found])
        keep, disparity, in_right = self._match.stereo_check(
            left, right, corners, in_right, found, self.disparity_offset_px
        )
        n_new = int(keep.sum())
        new_ids = np.arange(self._next_id, self._next_id + n_new, dtype=np.int64)
        self._next_id += n_new
        points_m = np.concatenate([kept_m, triangulate(self._camera, corners[keep], disparity[keep])])
        return _StereoPoints(
            left,
            np.concatenate([kept_px, corners[keep]]),
            points_m,
            points_m,
            np.concatenate([kept_ids, new_ids]),
            np.concatenate([kept_right_u, (corners[keep, 0] - disparity[keep]).astype(np.float64)]),
        )

    def _measure(self, prev: _StereoPoints, left: Image, right: Image, prior: np.ndarray):
        """(step, status, n_tracked, n_inliers, rmse, kept) from tracking `prev`'s points into `left`.

        `kept` = (pixels, points_m, ids, right columns) of the inliers that also matched in `right`: the points this frame
        carries on. A sudden change of motion (a car turning into a corner) makes the prior's prediction
        wrong by tens of pixels, and KLT started there can settle on a consistent but wrong set of matches
        in repetitive texture; so several motion hypotheses are tried in turn (see below)."""
        p = self.params
        failed = (prior, "low_texture", 0, 0, float("nan"), _NO_KEPT)
        if len(prev.pixels) < p.min_inliers:
            return failed
        best = self._best_hypothesis(prev, left, prior)
        if (
            best.cur_from_prev is None
            or best.object_points is None
            or best.image_px is None
            or best.n_inliers < p.min_inliers
            or best.n_inliers < p.min_accept_ratio * best.n_tracked
        ):
            return (*failed[:2], best.n_tracked, best.n_inliers, *failed[4:])
        object_points, image_px = best.object_points, best.image_px
        assert best.ids is not None  # set with the inliers
        rvec, _ = cv2.Rodrigues(best.cur_from_prev[:3, :3])
        tvec = best.cur_from_prev[:3, 3].reshape(3, 1).copy()
        rvec, tvec = cv2.solvePnPRefineLM(
            object_points, image_px.astype(np.float64), self.K, None, rvec, tvec
        )
        cur_from_prev = np.eye(4)
        cur_from_prev[:3, :3] = cv2.Rodrigues(rvec)[0]
        cur_from_prev[:3, 3] = tvec.ravel()
        # The inliers' right-image positions, KLT started at the disparity the pose predicts: they refine
        # the step and give the depths the points carry into the next frame.
        has_right, disparity, in_right = self._match_right(
            left, right, image_px, object_points, cur_from_prev
        )
        if p.stereo_refinement:
            cur_from_prev = refine_stereo_step(
                cur_from_prev,
                object_points,
                image_px,
                in_right,
                has_right,
                self._camera,
                p.ransac_reprojection_px,
                self.disparity_offset_px,
            )
        # Judged on the previous frame's own stereo points: the window's refined ones are not what the
        # disparities measured.
        assert best.stereo_m is not None
        if p.disparity_self_calibration and self._pair.calibration.wants_frame():
            assert best.tracked is not None and best.image_px is not None
            tracks = self._pair.fit_tracks(
                best.tracked,
                (best.stereo_m, best.image_px, in_right, has_right),
                cur_from_prev,
                lambda px, points_m: self._match_right(left, right, px, points_m, cur_from_prev),
            )
            self._pair.calibrate(cur_from_prev, *tracks)
        self._pair.judge_bias(cur_from_prev, best.stereo_m, disparity, has_right)
        rmse = reprojection_rmse(self._camera, cur_from_prev, object_points, image_px.astype(np.float64))
        kept = (
            image_px[has_right],
            triangulate(self._camera, image_px[has_right], disparity[has_right]),
            best.ids[has_right],
            (image_px[has_right, 0] - disparity[has_right]).astype(np.float64),
        )
        return (np.linalg.inv(cur_from_prev), "ok", best.n_tracked, best.n_inliers, rmse, kept)

    def _best_hypothesis(self, prev: _StereoPoints, left: Image, prior: np.ndarray) -> _Tracks:
        """The tracking + PnP of `prev`'s points into `left` under the first motion hypothesis that most tracks
        agree with (else the one with most inliers)."""
        p = self.params
        # Hypotheses for where the points went, tried in turn until most tracks agree with the PnP
        # solution (else the one with most inliers wins): the motion prior; a turn by the image's
        # global horizontal shift (phase correlation; a car entering a corner turns faster than the
        # prior says) at the prior's speed; straight ahead at that speed; no motion.
        speed_m = float(np.linalg.norm(prior[:3, 3]))
        hypotheses = (
            lambda: prior,
            lambda: _planar_motion(speed_m, self._match.image_yaw_rad(prev.left.half, left.half)),
            lambda: _planar_motion(speed_m, 0.0),
            lambda: np.eye(4),
        )
        best: _Tracks | None = None
        for hypothesis in hypotheses:
            outcome = self._track_and_pnp(prev, left, np.linalg.inv(hypothesis()))
            if best is None or outcome.n_inliers > best.n_inliers:
                best = outcome
            if (
                outcome.n_inliers >= p.min_inliers
                and outcome.n_inliers >= p.min_inlier_ratio * outcome.n_tracked
            ):
                break
        assert best is not None  # the hypotheses are never empty
        return best

    def _track_and_pnp(self, prev: _StereoPoints, left: Image, cur_from_prev: np.ndarray) -> _Tracks:
        """KLT of `prev`'s points started where `cur_from_prev` puts them, with a forward–backward check,
        then PnP RANSAC: the pose and its inliers."""
        p = self.params
        predicted = project(self._camera, prev.points_m, cur_from_prev)
        guess = np.where(predicted[:, 2:] > 0, predicted[:, :2], prev.pixels).astype(np.float32)
        tracked, found = self._match.track(prev.left, left, prev.pixels, guess)
        h, w = left.full.shape
        good = (
            found
            & (tracked[:, 0] >= 0)
            & (tracked[:, 0] <= w - 1)
            & (tracked[:, 1] >= 0)
            & (tracked[:, 1] <= h - 1)
        )
        good[good] = self._match.track_back(left.full, prev.left.full, tracked[good], prev.pixels[good])
        if p.refine_matches:
            tracked[good] = self._match.refined(
                prev.left.full, left.full, prev.pixels[good], tracked[good], "affine"
            )
        n_tracked = int(good.sum())
        if n_tracked < p.min_inliers:
            return _Tracks(None, n_tracked, 0)
        object_points = prev.points_m[good]
        image_px = tracked[good]
        rvec0, _ = cv2.Rodrigues(cur_from_prev[:3, :3])
        found_pose, rvec, tvec, inliers = cv2.solvePnPRansac(
            object_points,
            image_px.astype(np.float64),
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
        if not found_pose or n_inliers < 6:
            return _Tracks(None, n_tracked, n_inliers)
        idx = inliers.ravel()
        pose = np.eye(4)
        pose[:3, :3] = cv2.Rodrigues(rvec)[0]
        pose[:3, 3] = tvec.ravel()
        return _Tracks(
            pose,
            n_tracked,
            n_inliers,
            object_points[idx],
            image_px[idx],
            prev.ids[good][idx],
            prev.stereo_m[good][idx],
            (object_points, image_px, prev.stereo_m[good], idx),
        )

    @property
    def tracked_pixels(self) -> np.ndarray:
        """(n, 2) float32: left-image pixels of the stereo points the last frame carries into the next
        (what a viewer draws as the tracked features; empty before the first frame)."""
        return _NO_PIXELS.copy() if self._previous is None else self._previous.pixels.copy()

    @property
    def disparity_offset_px(self) -> float:
        """The disparity offset in use (px): `disparity_offset_px` as configured, or as the self-calibration
        moved it (`disparity_self_calibration`, `hippo_nav.vo.disparity`)."""
        return self._pair.calibration.offset_px

    @property
    def disparity_offset_frames(self) -> int:
        """Estimates behind the disparity offset in use (`DisparityCalibration.evidence_frames`): what a saved
        memory keeps with the offset, so that a later session does not overturn it on its first street."""
        return self._pair.calibration.evidence_frames

    @property
    def stereo_bias_px(self) -> float:
        """`StereoPairWatch.bias_px`: the median disparity residual, px (NaN before its window fills)."""
        return self._pair.bias_px

    @property
    def stereo_fault(self) -> str | None:
        """The stereo pair's verdict (module doc, 7): None while unjudged or fine; "swapped", "unrectified"
        or "identical"."""
        return self._pair.stereo_fault

    @property
    def warnings(self) -> list[str]:
        """What is wrong with the stereo pair, once each, in words (also logged)."""
        return self._pair.warnings

    def _match_right(
        self,
        left: Image,
        right: Image,
        image_px: np.ndarray,
        points_m: np.ndarray,
        cur_from_prev: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`_stereo_check`'s (matched mask, disparity px, right-image positions) of left pixels `image_px`
        whose points `points_m` (previous camera) the step `cur_from_prev` moves there: KLT started at the
        disparity the pose predicts, so a short search suffices."""
        predicted_z = project(self._camera, points_m, cur_from_prev)[:, 2]
        guess = image_px.copy()
        predicted_disparity = self.fx * self.baseline_m / np.maximum(predicted_z, 1e-3)
        guess[:, 0] -= (predicted_disparity - self.disparity_offset_px).astype(np.float32)
        in_right, ok, _ = cv2.calcOpticalFlowPyrLK(
            left.full,
            right.full,
            image_px,
            guess,
            flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
            **self._match.klt_short,
        )
        return self._match.stereo_check(
            left, right, image_px, in_right, ok.ravel() == 1, self.disparity_offset_px
        )

    def _plausible(self, step: np.ndarray, dt_s: float) -> bool:
        angle = np.arccos(np.clip((np.trace(step[:3, :3]) - 1) / 2, -1.0, 1.0))
        return bool(
            np.isfinite(step).all()
            and np.linalg.norm(step[:3, 3]) <= self.params.max_speed_m_s * dt_s
            and angle <= self.params.max_yaw_rate_rad_s * dt_s
        )


def _planar_motion(forward_m: float, yaw_rad: float) -> np.ndarray:
    """camera_prev_from_camera_cur of a forward move and a turn about the camera's −y axis (left +)."""
    step = np.eye(4)
    step[:3, :3] = cv2.Rodrigues(np.array([0.0, -yaw_rad, 0.0]))[0]
    step[2, 3] = forward_m
    return step


def _orthonormal(pose: np.ndarray) -> np.ndarray:
    """The pose with its rotation projected back onto SO(3) (a long chain of products drifts from it)."""
    u, _, vt = np.linalg.svd(pose[:3, :3])
    out = pose.copy()
    out[:3, :3] = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return out


def _scale_step(step: np.ndarray, factor: float) -> np.ndarray:
    """The SE(3) step scaled in time by `factor` (rotation angle and translation), for the motion prior."""
    if abs(factor - 1.0) < 1e-9:
        return step.copy()
    rvec = cv2.Rodrigues(step[:3, :3])[0] * factor
    out = np.eye(4)
    out[:3, :3] = cv2.Rodrigues(rvec)[0]
    out[:3, 3] = step[:3, 3] * factor
    return out
