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
5. Window (`window_keyframes` ≥ 2, the default 8): a well-tracked frame that moved becomes a keyframe; the
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
from collections import deque
from dataclasses import dataclass
from typing import Annotated, Literal, NamedTuple

import cv2
import numpy as np
from pydantic import ConfigDict, Field

from hippo_nav._core import HippoNavError, _refine_matches, _SlidingWindow
from hippo_nav._defaults import ConfigSection
from hippo_nav.geometry import planar_step
from hippo_nav.vo.disparity import MAX_POINTS, DisparityCalibration, frame_offset_px
from hippo_nav.vo.projection import pixel_rows

log = logging.getLogger("hippo_nav.vo")

# A frame whose fit moves the offset by more than this is not measuring it (a bad set of tracks).
_MAX_OFFSET_STEP_PX = 3.0
# The forward–backward checks' window on images at least this wide (`klt_check_window_px`): a check starts
# where a consistent track comes back to, so a small window does its job; on 320-px renders it did not.
_SMALL_CHECK_FROM_PX, _SMALL_CHECK_PX = 640, 9
# The self-calibration warns once when the offset it applies is this far from the configured one.
_WARN_OFFSET_PX = 0.3
# The stereo pair is judged once this many new-corner stereo matches from this many frames are pooled. Pooled
# so, real KITTI 06 and 01 (from frames 0 and 30) and the renders (00, 02, 05, 06, 08 from frames 0 and 1000;
# `mild`, `strong`) put 77–99 % of KLT's right-image matches within the row tolerance, median row error at most
# 0.38 px; of those with a clear disparity at most 3.8 % negative; at most 1.4 % within 0.01 px of where they
# are in the left image (the renders' sky, at infinity; real: none). A swapped pair: 100 % negative; a pair 6 px off its rows: 1 % on their row; one image
# given twice: 100 % within 0.01 px (docs/vo.md, "A swapped or unrectified pair").
_STEREO_JUDGE_MATCHES = 300
_STEREO_JUDGE_FRAMES = 3
_SWAPPED_SHARE = 0.8  # of the matches on their row with a clear disparity, at least this share negative
_ON_ROW_SHARE = 0.5  # an unrectified pair: fewer matches on their row than this share, and a median row
# error beyond the row tolerance
_IDENTICAL_PX = 0.01  # one image given as both: at least `_IDENTICAL_SHARE` of the matches lie within this
_IDENTICAL_SHARE = 0.5  # of where they are in the left image, in both coordinates (KLT converges exactly)

STATUSES = ("first", "ok", "low_texture", "rejected")
"""`VoStep.status`: first frame (identity); a measured step; too few features, tracks or inliers (prior
used); a measured step beyond the plausibility limits (prior used)."""


class VoParams(ConfigSection):
    """Stereo VO parameters; pixel values refer to the input image resolution."""

    model_config = ConfigDict(frozen=True)

    max_features: int = Field(
        650,
        ge=8,
        le=100_000,
        description="points per frame at most (tracked + new corners); 650 on KITTI-size images costs a quarter "
        "less than 1 000, with the accuracy measured in docs/vo.md, 'How many points' (a little worse on the "
        "real frames, most on KITTI 01 as given); small images have fewer",
    )
    corner_detector: Literal["fast", "shi_tomasi"] = Field(
        "fast", description="new corners: FAST, strongest per min-distance cell; or Shi–Tomasi (slower)"
    )
    fast_threshold: int = Field(
        10,
        ge=1,
        le=255,
        description="FAST intensity threshold (gray levels); corners are then ranked by score",
    )
    feature_quality: float = Field(0.005, gt=0.0, lt=1.0, description="Shi–Tomasi quality level (shi_tomasi)")
    min_feature_distance_px: float = Field(7.0, gt=0.0, description="minimum distance between corners")
    corner_bucket_px: int = Field(
        0,
        ge=0,
        le=100_000,
        description="when there are more new corners than room, spread them over squares of this side: the "
        "strongest of each square first, then the second of each, and so on (far, faint texture keeps its "
        "share); 0: the strongest overall",
    )
    track_features: bool = Field(
        True,
        description="carry the inliers and their stereo depths into the next frame and detect corners only "
        "where the image has none; False: detect and stereo-match every corner anew in each frame",
    )
    klt_window_px: int | None = Field(
        None,
        ge=5,
        le=255,
        description="KLT window side (odd) on the full image; None: width/25 within 11–15 px (13 at 320 px, "
        "15 on KITTI)",
    )
    klt_levels: int = Field(4, ge=0, le=8, description="KLT pyramid levels above the image")
    klt_coarse_window_px: int | None = Field(
        9,
        ge=5,
        le=255,
        description="KLT window side (odd) on the pyramid levels above the image, which only bring a point "
        "within reach of the full-resolution window; None: the full-resolution window",
    )
    klt_short_levels: int = Field(
        1,
        ge=0,
        le=8,
        description="KLT pyramid levels where the start is known to about a pixel: the backward check, "
        "and the right-image match of a tracked point at the disparity its motion predicts",
    )
    klt_check_window_px: Annotated[int, Field(ge=5, le=255)] | Literal["full"] | None = Field(
        None,
        description="KLT window side (odd, 5–255) of the forward–backward checks; 'full': the "
        f"full-resolution window; None: {_SMALL_CHECK_PX} px on images from {_SMALL_CHECK_FROM_PX} px wide "
        "(the VO about a tenth faster on KITTI images, as accurate since the self-calibration's fix), the "
        "full window below (9 px made the windowed VO worse on the 320-px renders; docs/vo.md, 'A smaller "
        "window for the checks')",
    )
    refine_matches: bool = Field(
        True,
        description="refine every KLT match with a warped window (affine for tracks, a row shear for stereo "
        "matches), started at KLT's answer: a square window on a slanted road is biased by a tenth of a "
        "pixel with one sign, which the odometry turns into pitch drift (docs/vo.md, 'Warped-window "
        "refinement'); False: KLT's matches as they are",
    )
    forward_backward_px: float = Field(1.0, gt=0.0, description="max forward–backward KLT error")
    stereo_row_tolerance_px: float = Field(1.5, gt=0.0, description="max row difference of a stereo match")
    min_disparity_px: float = Field(1.0, gt=0.0, description="nearer than fx·b/this: farther points dropped")
    stereo_guess_depth_m: float = Field(20.0, gt=0.0, description="depth whose disparity starts stereo KLT")
    ransac_reprojection_px: float = Field(1.0, gt=0.0, description="PnP RANSAC inlier threshold")
    ransac_iterations: int = Field(200, ge=10, le=100_000)
    ransac_confidence: float = Field(0.999, gt=0.0, lt=1.0)
    min_inliers: int = Field(
        25, ge=6, le=100_000, description="fewer PnP inliers flag the frame (prior used)"
    )
    min_inlier_ratio: float = Field(
        0.6, ge=0.0, le=1.0, description="below this inlier share, tracking is retried without the prior"
    )
    min_accept_ratio: float = Field(
        0.4, ge=0.0, le=1.0, description="below this inlier share the step is not trusted (prior used)"
    )
    stereo_refinement: bool = Field(True, description="refine the step on left and right reprojections")
    disparity_offset_px: float = Field(
        0.0,
        ge=-5.0,
        le=5.0,
        description="added to every measured disparity: corrects a stereo pair whose right image is "
        "shifted against its calibration (KITTI 01's shared frames need about +1 px); where the "
        "self-calibration starts (`disparity_self_calibration`), else fixed (then see `stereo_bias_px` and "
        "the warning it raises)",
    )
    disparity_self_calibration: bool = Field(
        True,
        description="estimate the disparity offset from the motion while running and apply it "
        "(`hippo_nav.vo.disparity`, docs/vo.md); `disparity_offset_px` is where it starts",
    )
    disparity_calibration_window: int = Field(
        200, ge=1, le=100_000, description="at most this many frames' estimates are pooled"
    )
    disparity_calibration_min_frames: int = Field(
        10, ge=1, le=100_000, description="estimates pooled before the offset in use may change"
    )
    disparity_calibration_max_sigma_px: float = Field(
        0.1,
        gt=0.0,
        description="a frame whose fit has a larger standard error is left out (it cannot tell an offset: "
        "a camera standing still; a moving car's frames have 0.01–0.04 px)",
    )
    disparity_calibration_gate_px: float = Field(
        10.0,
        ge=0.0,
        description="each frame's fit takes every track within this reprojection error of the step, not only "
        "PnP's inliers: RANSAC's gate is judged on depths made with the offset in use, so it keeps the points "
        "whose noise hides the offset and drops those that show it (on KITTI 01 the inliers alone read 0.57 px "
        "of about 1.05, these 1.02; docs/vo.md); 0: PnP's inliers",
    )
    disparity_calibration_reject_px: float = Field(
        3.0,
        ge=0.0,
        description="after a frame's fit, the points with a residual beyond this are dropped and the fit is "
        "repeated (the wide gate lets mistracks in: on the 06 render they moved the offset 0.13 px and back); "
        "0: no refit",
    )
    disparity_calibration_deadband_px: float = Field(
        0.1,
        ge=0.0,
        description="the offset in use changes only when the pooled estimate is beyond this (and three "
        "standard errors): the estimate's own bias is about ±0.05 px (+0.03 on renders with no offset; "
        "0.16 against the best 0.2–0.25 on KITTI 06), so a smaller change is not a measurement",
    )
    stereo_bias_window: int = Field(
        50,
        ge=5,
        le=100_000,
        description="well-tracked frames over which the stereo bias (`stereo_bias_px`) is judged",
    )
    stereo_bias_warn_px: float = Field(
        0.03,
        gt=0.0,
        description="warn when the median disparity residual over `stereo_bias_window` frames exceeds this "
        "(a consistent calibration gives < 0.01 px; a 1 px offset about 0.05–0.08 px)",
    )
    max_speed_m_s: float = Field(60.0, gt=0.0, description="a faster step is rejected (prior used)")
    max_yaw_rate_rad_s: float = Field(3.0, gt=0.0, description="a faster turn is rejected (prior used)")
    window_keyframes: int = Field(
        8,
        ge=0,
        le=100,
        description="keyframes refined jointly with the landmarks they share after every keyframe (a stereo "
        "bundle adjustment, the oldest fixed; docs/vo.md); 0 or 1: frame to frame only",
    )
    window_fixed_keyframes: int = Field(
        0,
        ge=0,
        le=100,
        description="older keyframes kept beyond the window, fixed: their observations still place the "
        "landmarks the refined keyframes share with them",
    )
    keyframe_min_m: float = Field(
        0.2, ge=0.0, description="a frame becomes a keyframe after moving this far since the last one …"
    )
    keyframe_min_rad: float = Field(0.02, ge=0.0, description="… or turning this much")
    window_pixel_sigma_px: float = Field(1.0, gt=0.0, description="σ of a tracked pixel in the window")
    window_right_sigma_px: float = Field(
        2.0,
        gt=0.0,
        description="σ of a right-image column (the stereo match) in the window: a stereo match of a slanted "
        "surface is less certain than a temporal track (docs/vo.md; 1 px: t_rel 1.25 % on the 05 render, 2 px: "
        "1.03 %)",
    )
    window_iterations: int = Field(
        6, ge=1, le=100, description="Levenberg–Marquardt iterations of each round"
    )
    window_min_shared: int = Field(
        20,
        ge=1,
        le=100_000,
        description="a keyframe sharing fewer landmarks with the window starts a new window",
    )
    track_window_points: bool = Field(
        True,
        description="track each point into the next frame from its refined landmark (else from this frame's "
        "stereo depth alone)",
    )
    seed: int = Field(
        0, ge=0, le=2**31 - 1, description="seeds OpenCV's RNG (RANSAC) on reset, so runs are repeatable"
    )
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


class _Image(NamedTuple):
    """A gray image and its half-resolution copy (pixel (u, v) there is (u/2, v/2))."""

    full: np.ndarray
    half: np.ndarray


@dataclass
class _StereoPoints:
    left: _Image
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


_NO_PIXELS = np.zeros((0, 2), np.float32)
_NO_POINTS = np.zeros((0, 3))
_NO_IDS = np.zeros(0, np.int64)
_NO_KEPT = (_NO_PIXELS, _NO_POINTS, _NO_IDS, np.zeros(0))


def _grid_cell(xy: np.ndarray, side_px: float, width_px: int) -> np.ndarray:
    """(n,) int64: the index of the `side_px` square of an image `width_px` wide that each pixel (x, y) lies in."""
    columns = int(width_px // side_px) + 1
    return (xy[:, 1] // side_px).astype(np.int64) * columns + (xy[:, 0] // side_px).astype(np.int64)


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
        w = (p.klt_window_px or int(np.clip(calibration.image_size_px[0] // 25, 11, 15))) | 1
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
        # A KLT search from afar runs in two calls: the pyramid levels above the image on the half-size
        # images with a small window (they only bring the point within reach), then the full-resolution
        # window on the image alone. Each level costs about one window's worth of work, so this halves
        # the cost of a point while the final estimate is still made by the full window.
        self._klt_coarse = None
        if p.klt_levels > 0:
            wc = (p.klt_coarse_window_px or w) | 1
            self._klt_coarse = {"winSize": (wc, wc), "maxLevel": p.klt_levels - 1, "criteria": criteria}
        self._klt_fine = {"winSize": (w, w), "maxLevel": 0, "criteria": criteria}
        self._refine_half_px = w // 2  # the warped-window refinement uses KLT's window (`refine_matches`)
        self._klt_short = {
            "winSize": (w, w),
            "maxLevel": min(p.klt_short_levels, p.klt_levels),
            "criteria": criteria,
        }
        check = p.klt_check_window_px
        if check is None:
            check = _SMALL_CHECK_PX if calibration.image_size_px[0] >= _SMALL_CHECK_FROM_PX else w
        elif check == "full":
            check = w
        check |= 1
        self._klt_check = {**self._klt_short, "winSize": (check, check)}
        self._yaw_window: np.ndarray | None = None
        self._fast = cv2.FastFeatureDetector_create(p.fast_threshold, nonmaxSuppression=True)
        r = int(np.ceil(p.min_feature_distance_px))
        self._keep_out = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        self._window: _SlidingWindow | None = None
        if p.window_keyframes >= 2:
            self._window = _SlidingWindow(
                self.fx,
                self.fy,
                self.cx,
                self.cy,
                self.baseline_m,
                max_keyframes=p.window_keyframes,
                fixed_keyframes=p.window_fixed_keyframes,
                pixel_sigma_px=p.window_pixel_sigma_px,
                right_sigma_px=p.window_right_sigma_px,
                iterations=p.window_iterations,
                min_shared_landmarks=p.window_min_shared,
                min_disparity_px=p.min_disparity_px,
            )
        # The rig's disparity offset outlives `reset`: a new trajectory is the same cameras.
        self._calibration = DisparityCalibration(
            p.disparity_offset_px,
            p.disparity_calibration_window,
            p.disparity_calibration_min_frames,
            p.disparity_calibration_deadband_px,
            p.disparity_calibration_max_sigma_px,
        )
        self.reset()

    def reset(self) -> None:
        """Forget the previous frame and the motion prior (the next frame starts a new trajectory)."""
        cv2.setRNGSeed(self.params.seed)
        self._previous: _StereoPoints | None = None
        self._previous_time_s: float | None = None
        self._prior_step = np.eye(4)  # camera_prev_from_camera_cur of the last good frame
        self._prior_dt_s = self.params.default_dt_s
        self._disparity_residuals_px: deque[float] = deque(maxlen=self.params.stereo_bias_window)
        self._next_id = 0
        # Where the last step handed out ended (the previous frame's pose, refined when it was a keyframe),
        # and the last keyframe's pose.
        self._world_from_previous = np.eye(4)
        self._world_from_keyframe: np.ndarray | None = None
        if self._window is not None:
            self._window.clear()
        self.warnings: list[str] = []
        self._warned_offset = False
        # The stereo pair's verdict (module doc, 7): None while unjudged or fine; "swapped" or "unrectified".
        self.stereo_fault: Literal["swapped", "unrectified", "identical"] | None = None
        self._stereo_judged = False
        self._stereo_pool: list[tuple[np.ndarray, np.ndarray]] = []  # per frame: (row error px, disparity px)

    # ------------------------------------------------------------------------------------------------
    def process(self, frame) -> VoStep:
        """The step from the previous frame to `frame` (identity with status "first" on the first).

        With the window on, the step ends at the frame's refined pose and starts where the previous
        step ended: a refinement of earlier keyframes that moves this one enters this step, so the
        chain of steps is the trajectory the VO estimates in real time (each frame as refined when it
        was the newest)."""
        left, right = (_Image(image, cv2.pyrDown(image)) for image in self._check_images(frame))
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

    def _stereo_points(
        self,
        left: _Image,
        right: _Image,
        kept_px: np.ndarray,
        kept_m: np.ndarray,
        kept_ids: np.ndarray,
        kept_right_u: np.ndarray,
    ) -> _StereoPoints:
        """This frame's points: those kept from tracking, plus new corners (new ids) where the image has none."""
        p = self.params
        corners = self._detect(left.full, p.max_features - len(kept_px), kept_px)
        if len(corners) == 0:
            return _StereoPoints(left, kept_px, kept_m, kept_m, kept_ids, kept_right_u)
        guess = corners.copy()
        guess[:, 0] -= self.fx * self.baseline_m / p.stereo_guess_depth_m - self.disparity_offset_px
        in_right, found = self._track(left, right, corners, guess)
        if not self._stereo_judged:
            self._judge_stereo_geometry(corners[found], in_right[found])
        keep, disparity, in_right = self._stereo_check(left, right, corners, in_right, found)
        n_new = int(keep.sum())
        new_ids = np.arange(self._next_id, self._next_id + n_new, dtype=np.int64)
        self._next_id += n_new
        points_m = np.concatenate([kept_m, self._triangulate(corners[keep], disparity[keep])])
        return _StereoPoints(
            left,
            np.concatenate([kept_px, corners[keep]]),
            points_m,
            points_m,
            np.concatenate([kept_ids, new_ids]),
            np.concatenate([kept_right_u, (corners[keep, 0] - disparity[keep]).astype(np.float64)]),
        )

    def _detect(self, image: np.ndarray, wanted: int, kept_px: np.ndarray) -> np.ndarray:
        """(n ≤ wanted, 2) float32: new corners, `min_feature_distance_px` apart and as far from kept points."""
        p = self.params
        if wanted <= 0:
            return _NO_PIXELS
        mask = None
        if len(kept_px):
            mask = np.full(image.shape, 255, np.uint8)
            xy = np.clip(np.rint(kept_px).astype(int), 0, [image.shape[1] - 1, image.shape[0] - 1])
            mask[xy[:, 1], xy[:, 0]] = 0
            mask = cv2.erode(mask, self._keep_out)
        if p.corner_detector == "shi_tomasi":
            corners = cv2.goodFeaturesToTrack(
                image, wanted, p.feature_quality, p.min_feature_distance_px, mask=mask, blockSize=5
            )
            return _NO_PIXELS if corners is None else corners.reshape(-1, 2).astype(np.float32)
        keypoints = self._fast.detect(image, mask)
        if not keypoints:
            return _NO_PIXELS
        xy = cv2.KeyPoint_convert(keypoints)
        score = np.array([k.response for k in keypoints], np.float32)
        # The strongest corner of each cell of a min-distance grid, strongest cells first.
        cell = _grid_cell(xy, p.min_feature_distance_px, image.shape[1])
        order = np.lexsort((-score, cell))
        best_of_cell = order[np.r_[True, cell[order][1:] != cell[order][:-1]]]
        if p.corner_bucket_px > 0 and len(best_of_cell) > wanted:
            # More corners than room: each square's strongest, then each one's second, ... (ties by score).
            bucket = _grid_cell(xy[best_of_cell], p.corner_bucket_px, image.shape[1])
            by_bucket = np.lexsort((-score[best_of_cell], bucket))  # squares in turn, strongest first
            _, first, count = np.unique(bucket[by_bucket], return_index=True, return_counts=True)
            rank = np.empty(len(by_bucket), np.int64)
            rank[by_bucket] = np.arange(len(by_bucket)) - np.repeat(first, count)  # place within its square
            chosen = np.lexsort((-score[best_of_cell], rank))[:wanted]
            best_of_cell = best_of_cell[np.sort(chosen)]
        return xy[best_of_cell[np.argsort(-score[best_of_cell], kind="stable")[:wanted]]]

    def _track(
        self, a: _Image, b: _Image, pts: np.ndarray, guess: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(positions in `b`, found) of `pts` of `a` by pyramidal KLT started at `guess` (coarse, then fine)."""
        if len(pts) == 0:
            return guess, np.zeros(0, bool)
        found = np.ones(len(pts), bool)
        if self._klt_coarse is not None:
            coarse, ok, _ = cv2.calcOpticalFlowPyrLK(
                a.half, b.half, pts * 0.5, guess * 0.5, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self._klt_coarse
            )
            guess, found = coarse * 2.0, ok.ravel() == 1
        tracked, ok, _ = cv2.calcOpticalFlowPyrLK(
            a.full, b.full, pts, guess, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self._klt_fine
        )
        return tracked, found & (ok.ravel() == 1)

    def _track_back(self, b: np.ndarray, a: np.ndarray, tracked: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """Forward–backward check: KLT from the tracked positions in `b` back into `a`, started at the
        original points (a short pyramid: a good track comes back to where it began)."""
        if len(pts) == 0:
            return np.zeros(0, bool)
        back, ok, _ = cv2.calcOpticalFlowPyrLK(
            b, a, tracked, pts.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self._klt_check
        )
        return (ok.ravel() == 1) & (np.linalg.norm(back - pts, axis=1) < self.params.forward_backward_px)

    def _stereo_check(
        self, left: _Image, right: _Image, pts: np.ndarray, in_right: np.ndarray, found: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(matched mask, disparity px, right-image positions) of left pixels and their KLT positions in the
        right image: back into the left (left–right consistency), a small row error and a positive
        disparity; the kept matches refined with a row-shear window (`refine_matches`)."""
        p = self.params
        disparity = pts[:, 0] - in_right[:, 0] + self.disparity_offset_px
        keep = (
            found
            & (np.abs(in_right[:, 1] - pts[:, 1]) < p.stereo_row_tolerance_px)
            & (disparity > p.min_disparity_px)
        )
        keep[keep] = self._track_back(right.full, left.full, in_right[keep], pts[keep])
        if p.refine_matches and keep.any():
            in_right = in_right.copy()
            in_right[keep] = self._refined(left.full, right.full, pts[keep], in_right[keep], "row_shear")
            disparity = pts[:, 0] - in_right[:, 0] + self.disparity_offset_px
            keep &= disparity > p.min_disparity_px
        return keep, disparity, in_right

    def _refined(
        self,
        image_a: np.ndarray,
        image_b: np.ndarray,
        points_a: np.ndarray,
        matched_b: np.ndarray,
        model: str,
    ) -> np.ndarray:
        """`matched_b` refined by a warped window (`refine_matches`; Rust `hippo_vo::tracks`), float32; a
        match that cannot be refined stays as it was."""
        if len(points_a) == 0:
            return matched_b
        refined, _ = _refine_matches(
            np.ascontiguousarray(image_a),
            np.ascontiguousarray(image_b),
            points_a.astype(np.float64),
            matched_b.astype(np.float64),
            model,
            self._refine_half_px,
        )
        return refined.astype(np.float32)

    def _triangulate(self, pts: np.ndarray, disparity_px: np.ndarray) -> np.ndarray:
        z = self.fx * self.baseline_m / disparity_px.astype(np.float64)
        x = (pts[:, 0] - self.cx) * z / self.fx
        y = (pts[:, 1] - self.cy) * z / self.fy
        return np.column_stack([x, y, z])

    def _measure(self, prev: _StereoPoints, left: _Image, right: _Image, prior: np.ndarray):
        """(step, status, n_tracked, n_inliers, rmse, kept) from tracking `prev`'s points into `left`.

        `kept` = (pixels, points_m, ids, right columns) of the inliers that also matched in `right`: the points this frame
        carries on. A sudden change of motion (a car turning into a corner) makes the prior's prediction
        wrong by tens of pixels, and KLT started there can settle on a consistent but wrong set of matches
        in repetitive texture; so several motion hypotheses are tried in turn (see below)."""
        p = self.params
        failed = (prior, "low_texture", 0, 0, float("nan"), _NO_KEPT)
        if len(prev.pixels) < p.min_inliers:
            return failed
        # Hypotheses for where the points went, tried in turn until most tracks agree with the PnP
        # solution (else the one with most inliers wins): the motion prior; a turn by the image's
        # global horizontal shift (phase correlation; a car entering a corner turns faster than the
        # prior says) at the prior's speed; straight ahead at that speed; no motion.
        speed_m = float(np.linalg.norm(prior[:3, 3]))
        hypotheses = (
            lambda: prior,
            lambda: _planar_motion(speed_m, self._image_yaw_rad(prev.left.half, left.half)),
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
            cur_from_prev = self._refine_stereo(cur_from_prev, object_points, image_px, in_right, has_right)
        # Judged on the previous frame's own stereo points: the window's refined ones are not what the
        # disparities measured.
        assert best.stereo_m is not None
        if p.disparity_self_calibration and self._calibration.wants_frame():
            tracks = self._calibration_tracks(best, cur_from_prev, left, right, in_right, has_right)
            self._calibrate_disparity(cur_from_prev, *tracks)
        self._judge_stereo_bias(cur_from_prev, best.stereo_m, disparity, has_right)
        rmse = self._rmse(cur_from_prev, object_points, image_px.astype(np.float64))
        kept = (
            image_px[has_right],
            self._triangulate(image_px[has_right], disparity[has_right]),
            best.ids[has_right],
            (image_px[has_right, 0] - disparity[has_right]).astype(np.float64),
        )
        return (np.linalg.inv(cur_from_prev), "ok", best.n_tracked, best.n_inliers, rmse, kept)

    def _track_and_pnp(self, prev: _StereoPoints, left: _Image, cur_from_prev: np.ndarray) -> _Tracks:
        """KLT of `prev`'s points started where `cur_from_prev` puts them, with a forward–backward check,
        then PnP RANSAC: the pose and its inliers."""
        p = self.params
        predicted = self._project(prev.points_m, cur_from_prev)
        guess = np.where(predicted[:, 2:] > 0, predicted[:, :2], prev.pixels).astype(np.float32)
        tracked, found = self._track(prev.left, left, prev.pixels, guess)
        h, w = left.full.shape
        good = (
            found
            & (tracked[:, 0] >= 0)
            & (tracked[:, 0] <= w - 1)
            & (tracked[:, 1] >= 0)
            & (tracked[:, 1] <= h - 1)
        )
        good[good] = self._track_back(left.full, prev.left.full, tracked[good], prev.pixels[good])
        if p.refine_matches:
            tracked[good] = self._refined(
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
    def stereo_bias_px(self) -> float:
        """Median, over the last `stereo_bias_window` well-tracked frames, of each frame's median disparity
        residual (predicted by the step from the previous frame's points, minus measured), px; NaN before
        the window fills. A right image shifted against its calibration makes the points' depths wrong in
        a way no rigid step explains: on KITTI-size images a 1 px disparity shortfall gives about −0.06 px,
        a consistent pair < 0.01 px. Negative: measured disparities too large for the motion."""
        if len(self._disparity_residuals_px) < self.params.stereo_bias_window:
            return float("nan")
        return float(np.median(self._disparity_residuals_px))

    @property
    def disparity_offset_px(self) -> float:
        """The disparity offset in use (px): `disparity_offset_px` as configured, or as the self-calibration
        moved it (`disparity_self_calibration`, `hippo_nav.vo.disparity`)."""
        return self._calibration.offset_px

    def _match_right(
        self,
        left: _Image,
        right: _Image,
        image_px: np.ndarray,
        points_m: np.ndarray,
        cur_from_prev: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`_stereo_check`'s (matched mask, disparity px, right-image positions) of left pixels `image_px`
        whose points `points_m` (previous camera) the step `cur_from_prev` moves there: KLT started at the
        disparity the pose predicts, so a short search suffices."""
        predicted_z = self._project(points_m, cur_from_prev)[:, 2]
        guess = image_px.copy()
        predicted_disparity = self.fx * self.baseline_m / np.maximum(predicted_z, 1e-3)
        guess[:, 0] -= (predicted_disparity - self.disparity_offset_px).astype(np.float32)
        in_right, ok, _ = cv2.calcOpticalFlowPyrLK(
            left.full, right.full, image_px, guess, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self._klt_short
        )
        return self._stereo_check(left, right, image_px, in_right, ok.ravel() == 1)

    def _calibration_tracks(
        self,
        best: _Tracks,
        cur_from_prev: np.ndarray,
        left: _Image,
        right: _Image,
        in_right: np.ndarray,
        has_right: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The tracks a frame's disparity-offset fit takes (`disparity_calibration_gate_px`): (previous
        stereo points, current left pixels, right-image positions, matched mask), at most
        `MAX_POINTS` of them, evenly thinned; the inliers' right matches (`in_right`, `has_right`) are
        reused, the others are matched here."""
        assert best.tracked is not None and best.stereo_m is not None and best.image_px is not None
        if self.params.disparity_calibration_gate_px <= 0:
            return best.stereo_m, best.image_px, in_right, has_right
        points_m, image_px, stereo_m, inliers = best.tracked
        error_px = np.linalg.norm(self._project(points_m, cur_from_prev)[:, :2] - image_px, axis=1)
        near = np.flatnonzero(error_px < self.params.disparity_calibration_gate_px)
        if len(near) > MAX_POINTS:  # the fit would thin them anyway: fewer to match
            near = near[np.linspace(0, len(near) - 1, MAX_POINTS).astype(np.int64)]
        as_inlier = np.full(len(points_m), -1)
        as_inlier[inliers] = np.arange(len(inliers))
        at = as_inlier[near]
        reused = at >= 0
        right_px = np.zeros((len(near), 2), np.float32)
        matched = np.zeros(len(near), bool)
        right_px[reused], matched[reused] = in_right[at[reused]], has_right[at[reused]]
        others = near[~reused]
        if len(others):
            matched[~reused], _, right_px[~reused] = self._match_right(
                left, right, image_px[others], points_m[others], cur_from_prev
            )
        return stereo_m[near], image_px[near], right_px, matched

    def _calibrate_disparity(
        self,
        cur_from_prev: np.ndarray,
        prev_points_m: np.ndarray,
        left_px: np.ndarray,
        right_px: np.ndarray,
        has_right: np.ndarray,
    ) -> None:
        """One frame's estimate of the offset into the calibration; warn once when it moves far from the
        configured offset (the calibration, not the odometry, should be fixed)."""
        p = self.params
        in_use = self._calibration.offset_px
        fitted = frame_offset_px(
            cur_from_prev,
            prev_points_m,
            left_px,
            right_px[:, 0].astype(np.float64) - in_use,
            has_right,
            (self.fx, self.fy, self.cx, self.cy, self.baseline_m),
            p.ransac_reprojection_px,
            p.disparity_calibration_reject_px or None,
        )
        if fitted is None or abs(fitted[0]) > _MAX_OFFSET_STEP_PX:
            return
        if not self._calibration.add(*fitted) or self._warned_offset:
            return
        applied = self._calibration.offset_px
        if abs(applied - p.disparity_offset_px) >= _WARN_OFFSET_PX:
            self._warned_offset = True
            message = (
                f"the stereo pair looks biased: the motion says its disparities need {applied:+.2f} px so far "
                f"(configured disparity_offset_px {p.disparity_offset_px:+.2f}), which the odometry now "
                "applies and keeps estimating (vo.disparity_self_calibration; the final value is "
                "metrics.json's data.disparity_offset_px). Check the calibration's baseline and rectification"
            )
            self.warnings.append(message)
            log.warning("%s", message)

    def _judge_stereo_bias(
        self, cur_from_prev: np.ndarray, points_m: np.ndarray, disparity_px: np.ndarray, has_right: np.ndarray
    ) -> None:
        """Record this frame's disparity residual; warn once when the stereo pair looks biased."""
        p = self.params
        if has_right.sum() < p.min_inliers:
            return
        z_m = (points_m[has_right] @ cur_from_prev[2, :3]) + cur_from_prev[2, 3]
        if (z_m <= 0).any():
            return
        residual = self.fx * self.baseline_m / z_m - disparity_px[has_right]
        self._disparity_residuals_px.append(float(np.median(residual)))
        bias = self.stereo_bias_px
        if not self.warnings and np.isfinite(bias) and abs(bias) > p.stereo_bias_warn_px:
            # Measured on shifted images: a disparity shortfall (right image shifted right) gives a
            # negative residual, an excess a positive one.
            sign = "positive" if bias < 0 else "negative"
            message = (
                f"the stereo pair looks biased: over {p.stereo_bias_window} frames the measured disparities "
                f"disagree with the motion (median residual {bias:+.3f} px, beyond ±{p.stereo_bias_warn_px} px; "
                f"a consistent calibration gives about 0.01 px), so the odometry's scale is off and depends on depth. Check "
                f"the calibration's baseline and rectification, or try a {sign} vo.disparity_offset_px "
                f"(this residual is what a disparity {'shortfall' if bias < 0 else 'excess'} gives)"
            )
            self.warnings.append(message)
            log.warning("%s", message)

    def _judge_stereo_geometry(self, left_px: np.ndarray, right_px: np.ndarray) -> None:
        """Pool one frame's stereo matches (left pixels and KLT's right-image positions, before any check);
        once enough are pooled, judge the pair once and warn if it looks unrectified, one image given twice or
        swapped (module doc)."""
        if len(left_px) == 0:
            return
        p = self.params
        self._stereo_pool.append(
            (
                (right_px[:, 1] - left_px[:, 1]).astype(np.float64),
                (left_px[:, 0] - right_px[:, 0]).astype(np.float64),
            )
        )
        if (
            len(self._stereo_pool) < _STEREO_JUDGE_FRAMES
            or sum(len(r) for r, _ in self._stereo_pool) < _STEREO_JUDGE_MATCHES
        ):
            return
        row_px = np.concatenate([r for r, _ in self._stereo_pool])
        disparity_px = np.concatenate([d for _, d in self._stereo_pool])
        self._stereo_judged, self._stereo_pool = True, []
        on_row = np.abs(row_px) < p.stereo_row_tolerance_px
        negative = int((on_row & (disparity_px < -p.min_disparity_px)).sum())
        positive = int((on_row & (disparity_px > p.min_disparity_px)).sum())
        median_row_px = float(np.median(row_px))
        if on_row.mean() < _ON_ROW_SHARE and abs(median_row_px) < p.stereo_row_tolerance_px:
            return  # matches scattered over rows both ways: no consistent verdict (nor a fault named wrongly)
        if on_row.mean() < _ON_ROW_SHARE:
            self.stereo_fault = "unrectified"
            message = (
                f"the stereo pair does not look rectified: the right image's matches of {len(row_px)} corners lie "
                f"a median {abs(median_row_px):.1f} px {'lower' if median_row_px > 0 else 'higher'} than in the "
                f"left image, and only {100 * on_row.mean():.0f} % within the {p.stereo_row_tolerance_px:g} px of "
                "its row a rectified pair allows, so almost no point gets a depth. Rectify the images (and use "
                "the rectified calibration), or check that the right images belong to this sequence"
            )
        elif (
            unmoved := int(((np.abs(disparity_px) < _IDENTICAL_PX) & (np.abs(row_px) < _IDENTICAL_PX)).sum())
        ) >= _IDENTICAL_SHARE * len(row_px):
            self.stereo_fault = "identical"
            message = (
                f"the left and right images look identical: {unmoved} of {len(row_px)} stereo matches lie within "
                f"{_IDENTICAL_PX:g} px of where they are in the left image, so no point gets a depth. The right "
                "images must come from the pair's other camera (KITTI: image_1): check that the two image "
                "folders or topics differ"
            )
        elif negative + positive > 0 and negative >= _SWAPPED_SHARE * (negative + positive):
            self.stereo_fault = "swapped"
            message = (
                f"the left and right images look swapped: {negative} of {negative + positive} stereo matches on "
                "their row lie further right in the right image (a negative disparity), where a rectified pair "
                "puts every point further left. Give the left camera's images as the left ones (KITTI: image_0 "
                "left, image_1 right; a stereo folder or bag: swap the two); from this pair the odometry "
                "measures no depth"
            )
        else:
            return
        self.warnings.append(message)
        log.warning("%s", message)

    def _image_yaw_rad(self, prev_half: np.ndarray, cur_half: np.ndarray) -> float:
        """Yaw (left positive) that explains the global horizontal image shift between two frames.

        Measured on the half-size images, halved again while wider than 320 px: a KLT start needs the
        shift to a pixel or two, not to a tenth."""
        factor = 2
        while prev_half.shape[1] > 320:
            prev_half, cur_half, factor = cv2.pyrDown(prev_half), cv2.pyrDown(cur_half), factor * 2
        if self._yaw_window is None or self._yaw_window.shape != prev_half.shape:
            self._yaw_window = cv2.createHanningWindow(prev_half.shape[::-1], cv2.CV_32F)
        (shift_px, _), _ = cv2.phaseCorrelate(
            prev_half.astype(np.float32), cur_half.astype(np.float32), self._yaw_window
        )
        # A left turn moves the scene right (positive shift).
        return float(np.arctan2(shift_px * factor, self.fx))

    def _refine_stereo(
        self,
        cur_from_prev: np.ndarray,
        points_m: np.ndarray,
        left_px: np.ndarray,
        right_px: np.ndarray,
        has_right: np.ndarray,
    ) -> np.ndarray:
        """Gauss–Newton on left + right reprojection in the current frame.

        Points without a consistent right match (`has_right` false) keep only their left residual.
        Robust (Huber) weights keep a few bad tracks from pulling the step."""
        huber_px = self.params.ransac_reprojection_px
        left_obs = left_px.astype(np.float64)
        right_u = right_px[has_right, 0].astype(np.float64) - self.disparity_offset_px
        transform = cur_from_prev.copy()
        for _ in range(5):
            x = points_m @ transform[:3, :3].T + transform[:3, 3]
            if (x[:, 2] <= 0).any():
                return cur_from_prev
            # The right image adds only u (the disparity): its v repeats the left one, plus whatever
            # row offset the rectification left, which would tilt the pitch.
            rows = (
                self._pixel_rows(x, 0.0, 0, left_obs[:, 0]),
                self._pixel_rows(x, 0.0, 1, left_obs[:, 1]),
                self._pixel_rows(x[has_right], self.baseline_m, 0, right_u),
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

    def _pixel_rows(
        self, x: np.ndarray, offset_m: float, axis: int, observed: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(residuals (n,), Jacobian (n, 6) on a left perturbation (ω, τ) of the pose) of pixel coordinate
        `axis` (0: u, 1: v) of points `x` (current left camera frame) seen by a camera `offset_m` to its right
        (`hippo_nav.vo.projection.pixel_rows`)."""
        predicted, jac, _, _ = pixel_rows(x, axis, offset_m, (self.fx, self.fy, self.cx, self.cy))
        return predicted - observed, jac

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
