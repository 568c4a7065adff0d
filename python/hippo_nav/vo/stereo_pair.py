"""What the stereo odometry learns of its stereo pair, apart from the tracking: the disparity offset it
self-calibrates from the motion (`disparity.py`'s fit and filter), the disparity bias it warns of, and the
geometric fault it names (a swapped, unrectified or doubled pair; `odometry.py` module doc, 7). Each warning
is given once, in words saying what to fix, and logged.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from typing import Literal

import numpy as np

from hippo_nav.vo.disparity import MAX_POINTS, DisparityCalibration, frame_offset_px
from hippo_nav.vo.projection import project
from hippo_nav.vo.settings import VoParams

log = logging.getLogger("hippo_nav.vo")

__all__ = ["StereoPairWatch"]

# A frame whose fit moves the offset by more than this is not measuring it (a bad set of tracks).
_MAX_OFFSET_STEP_PX = 3.0
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


class StereoPairWatch:
    """The stereo pair's offset, bias and faults, judged from the odometry's matches (module doc). `camera`:
    (fx, fy, cx, cy, baseline_m). The offset's filter outlives `reset` (a new trajectory, the same cameras)."""

    def __init__(self, params: VoParams, camera: tuple[float, float, float, float, float]) -> None:
        self.params = params
        self._camera = camera
        p = params
        self.calibration = DisparityCalibration(
            p.disparity_offset_px,
            p.disparity_calibration_window,
            p.disparity_calibration_min_frames,
            p.disparity_calibration_deadband_px,
            p.disparity_calibration_max_sigma_px,
            p.disparity_calibration_prior_frames,
        )
        self.reset()

    def reset(self) -> None:
        """Forget the bias and the geometry verdict (a new trajectory); keep the offset."""
        self._disparity_residuals_px: deque[float] = deque(maxlen=self.params.stereo_bias_window)
        self.warnings: list[str] = []
        self._warned_offset = False
        # The stereo pair's verdict: None while unjudged or fine; "swapped", "unrectified" or "identical".
        self.stereo_fault: Literal["swapped", "unrectified", "identical"] | None = None
        self.judged = False
        self._pool: list[tuple[np.ndarray, np.ndarray]] = []  # per frame: (row error px, disparity px)

    @property
    def bias_px(self) -> float:
        """Median, over the last `stereo_bias_window` well-tracked frames, of each frame's median disparity
        residual (predicted by the step from the previous frame's points, minus measured), px; NaN before
        the window fills. A right image shifted against its calibration makes the points' depths wrong in
        a way no rigid step explains: on KITTI-size images a 1 px disparity shortfall gives about −0.06 px,
        a consistent pair < 0.01 px. Negative: measured disparities too large for the motion."""
        if len(self._disparity_residuals_px) < self.params.stereo_bias_window:
            return float("nan")
        return float(np.median(self._disparity_residuals_px))

    def fit_tracks(
        self,
        tracked: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        inliers_only: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        cur_from_prev: np.ndarray,
        match_right: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The tracks a frame's disparity-offset fit takes (`disparity_calibration_gate_px`): (previous
        stereo points, current left pixels, right-image positions, matched mask), at most `MAX_POINTS` of
        them, evenly thinned. `tracked`: every track that passed KLT's checks (points, pixels, stereo
        points, where the inliers are among them); `inliers_only`: the inliers' (stereo points, pixels,
        right matches, matched mask), reused, and all the fit takes when the gate is off; the others are
        matched by `match_right(pixels, points)` ((matched, disparity, right positions))."""
        gate_px = self.params.disparity_calibration_gate_px
        if gate_px <= 0:
            return inliers_only
        in_right, has_right = inliers_only[2], inliers_only[3]
        points_m, image_px, stereo_m, inliers = tracked
        error_px = np.linalg.norm(project(self._camera, points_m, cur_from_prev)[:, :2] - image_px, axis=1)
        near = np.flatnonzero(error_px < gate_px)
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
            matched[~reused], _, right_px[~reused] = match_right(image_px[others], points_m[others])
        return stereo_m[near], image_px[near], right_px, matched

    def calibrate(
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
        in_use = self.calibration.offset_px
        fitted = frame_offset_px(
            cur_from_prev,
            prev_points_m,
            left_px,
            right_px[:, 0].astype(np.float64) - in_use,
            has_right,
            self._camera,
            p.ransac_reprojection_px,
            p.disparity_calibration_reject_px or None,
        )
        if fitted is None or abs(fitted[0]) > _MAX_OFFSET_STEP_PX:
            return
        if not self.calibration.add(*fitted) or self._warned_offset:
            return
        applied = self.calibration.offset_px
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

    def judge_bias(
        self, cur_from_prev: np.ndarray, points_m: np.ndarray, disparity_px: np.ndarray, has_right: np.ndarray
    ) -> None:
        """Record this frame's disparity residual; warn once when the stereo pair looks biased."""
        p = self.params
        if has_right.sum() < p.min_inliers:
            return
        z_m = (points_m[has_right] @ cur_from_prev[2, :3]) + cur_from_prev[2, 3]
        if (z_m <= 0).any():
            return
        residual = self._camera[0] * self._camera[4] / z_m - disparity_px[has_right]
        self._disparity_residuals_px.append(float(np.median(residual)))
        bias = self.bias_px
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

    def judge_geometry(self, left_px: np.ndarray, right_px: np.ndarray) -> None:
        """Pool one frame's stereo matches (left pixels and KLT's right-image positions, before any check);
        once enough are pooled, judge the pair once and warn if it looks unrectified, one image given twice or
        swapped (module doc)."""
        if len(left_px) == 0:
            return
        p = self.params
        self._pool.append(
            (
                (right_px[:, 1] - left_px[:, 1]).astype(np.float64),
                (left_px[:, 0] - right_px[:, 0]).astype(np.float64),
            )
        )
        if (
            len(self._pool) < _STEREO_JUDGE_FRAMES
            or sum(len(r) for r, _ in self._pool) < _STEREO_JUDGE_MATCHES
        ):
            return
        row_px = np.concatenate([r for r, _ in self._pool])
        disparity_px = np.concatenate([d for _, d in self._pool])
        self.judged, self._pool = True, []
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
