"""What the stereo odometry does to images: corners (`detect`), pyramidal KLT tracks from a guess (`track`),
their forward–backward checks (`track_back`), stereo matches checked and refined (`stereo_check`), and the
warped-window refinement of a match (`refined`, Rust `hippo_vo::tracks`). No trajectory state: the tracker
(`odometry.StereoOdometry`) decides what is matched where. Why each choice: `odometry.py`'s module doc, "Cost".
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from hippo_nav._core import _refine_matches
from hippo_nav.datasets.base import StereoCalibration
from hippo_nav.vo.settings import SMALL_CHECK_FROM_PX as _SMALL_CHECK_FROM_PX
from hippo_nav.vo.settings import SMALL_CHECK_PX as _SMALL_CHECK_PX
from hippo_nav.vo.settings import VoParams

__all__ = ["NO_PIXELS", "Image", "ImageMatcher"]

NO_PIXELS = np.zeros((0, 2), np.float32)
_NO_PIXELS = NO_PIXELS


class Image(NamedTuple):
    """A gray image and its half-resolution copy (pixel (u, v) there is (u/2, v/2))."""

    full: np.ndarray
    half: np.ndarray


def _grid_cell(xy: np.ndarray, side_px: float, width_px: int) -> np.ndarray:
    """(n,) int64: the index of the `side_px` square of an image `width_px` wide that each pixel (x, y) lies in."""
    columns = int(width_px // side_px) + 1
    return (xy[:, 1] // side_px).astype(np.int64) * columns + (xy[:, 0] // side_px).astype(np.int64)


class ImageMatcher:
    """The odometry's image operations, set up once for a camera and its settings (module doc)."""

    def __init__(self, calibration: StereoCalibration, params: VoParams) -> None:
        self.params = params
        p = params
        w = (p.klt_window_px or int(np.clip(calibration.image_size_px[0] // 25, 11, 15))) | 1
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
        # A KLT search from afar runs in two calls: the pyramid levels above the image on the half-size
        # images with a small window (they only bring the point within reach), then the full-resolution
        # window on the image alone. Each level costs about one window's worth of work, so this halves
        # the cost of a point while the final estimate is still made by the full window.
        self.klt_coarse = None
        if p.klt_levels > 0:
            wc = (p.klt_coarse_window_px or w) | 1
            self.klt_coarse = {"winSize": (wc, wc), "maxLevel": p.klt_levels - 1, "criteria": criteria}
        self.klt_fine = {"winSize": (w, w), "maxLevel": 0, "criteria": criteria}
        self.refine_half_px = w // 2  # the warped-window refinement uses KLT's window (`refine_matches`)
        self.klt_short = {
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
        self.klt_check = {**self.klt_short, "winSize": (check, check)}
        self._fast = cv2.FastFeatureDetector_create(p.fast_threshold, nonmaxSuppression=True)
        r = int(np.ceil(p.min_feature_distance_px))
        self._keep_out = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        self._fx = calibration.fx
        self._yaw_window: np.ndarray | None = None

    def detect(self, image: np.ndarray, wanted: int, kept_px: np.ndarray) -> np.ndarray:
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

    def track(self, a: Image, b: Image, pts: np.ndarray, guess: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(positions in `b`, found) of `pts` of `a` by pyramidal KLT started at `guess` (coarse, then fine)."""
        if len(pts) == 0:
            return guess, np.zeros(0, bool)
        found = np.ones(len(pts), bool)
        if self.klt_coarse is not None:
            coarse, ok, _ = cv2.calcOpticalFlowPyrLK(
                a.half, b.half, pts * 0.5, guess * 0.5, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self.klt_coarse
            )
            guess, found = coarse * 2.0, ok.ravel() == 1
        tracked, ok, _ = cv2.calcOpticalFlowPyrLK(
            a.full, b.full, pts, guess, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self.klt_fine
        )
        return tracked, found & (ok.ravel() == 1)

    def track_back(self, b: np.ndarray, a: np.ndarray, tracked: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """Forward–backward check: KLT from the tracked positions in `b` back into `a`, started at the
        original points (a short pyramid: a good track comes back to where it began)."""
        if len(pts) == 0:
            return np.zeros(0, bool)
        back, ok, _ = cv2.calcOpticalFlowPyrLK(
            b, a, tracked, pts.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self.klt_check
        )
        return (ok.ravel() == 1) & (np.linalg.norm(back - pts, axis=1) < self.params.forward_backward_px)

    def stereo_check(
        self,
        left: Image,
        right: Image,
        pts: np.ndarray,
        in_right: np.ndarray,
        found: np.ndarray,
        offset_px: float,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(matched mask, disparity px, right-image positions) of left pixels and their KLT positions in the
        right image: back into the left (left–right consistency), a small row error and a positive
        disparity (corrected by `offset_px`, the odometry's disparity offset); the kept matches refined with a row-shear window (`refine_matches`)."""
        p = self.params
        disparity = pts[:, 0] - in_right[:, 0] + offset_px
        keep = (
            found
            & (np.abs(in_right[:, 1] - pts[:, 1]) < p.stereo_row_tolerance_px)
            & (disparity > p.min_disparity_px)
        )
        keep[keep] = self.track_back(right.full, left.full, in_right[keep], pts[keep])
        if p.refine_matches and keep.any():
            in_right = in_right.copy()
            in_right[keep] = self.refined(left.full, right.full, pts[keep], in_right[keep], "row_shear")
            disparity = pts[:, 0] - in_right[:, 0] + offset_px
            keep &= disparity > p.min_disparity_px
        return keep, disparity, in_right

    def refined(
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
            self.refine_half_px,
        )
        return refined.astype(np.float32)

    def image_yaw_rad(self, prev_half: np.ndarray, cur_half: np.ndarray) -> float:
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
        return float(np.arctan2(shift_px * factor, self._fx))
