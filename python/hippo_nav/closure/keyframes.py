"""Compact stereo keyframes: what a map vertex keeps so that a later visit can measure its pose.

A keyframe holds, for up to `keyframe_features` features of the left image that have a stereo match, the
pixel position (float32), the descriptor and the 3-D point in the camera frame (float32, x right, y down,
z forward; depth `Z = fx·b/d` from the disparity d) — no image is stored. The descriptor (`descriptor`) is
SIFT's by default, 128 bytes (148 bytes a feature, about 44 kB at 300 features), or ORB's 256 bits (52 bytes a
feature, about 16 kB): ORB's binary tests flip under another light and hard shadows, SIFT's gradient
histograms much less, and SIFT's measurements on real KITTI were about half as far off (docs/views.md).

Stereo matching follows the VO (`hippo_nav.vo`): each corner is tracked into the right image with
pyramidal KLT started at the disparity of a typical depth, checked back into the left image, and kept when
its row stays within `stereo_row_tolerance_px` and its disparity is positive; then refined with a row-sheared
window (`refine_stereo`, Rust `hippo_vo::tracks`, as the VO's matches are: KLT's square window reads a slanted
road's disparity short, which made keyframe depths ~5 % long there, docs/views.md). ORB's patch and border adapt
to small images (a 96-row render keeps most of its rows).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from hippo_nav._core import HippoNavError, _refine_matches
from hippo_nav.closure.config import ClosureConfig


@dataclass(frozen=True)
class Keyframe:
    """Stereo features of one frame: pixels (n, 2) float32, descriptors (n, 32) uint8 (ORB) or (n, 128)
    uint8 (SIFT, whose values OpenCV rounds to 0-255), 3-D points in the camera frame (n, 3) float32
    (metres)."""

    pixels_px: np.ndarray
    descriptors: np.ndarray
    points_m: np.ndarray

    def __len__(self) -> int:
        return len(self.pixels_px)

    @property
    def nbytes(self) -> int:
        return int(self.pixels_px.nbytes + self.descriptors.nbytes + self.points_m.nbytes)


DESCRIPTOR_BYTES = {"orb": 32, "sift": 128}
_SIFT_MAX_WIDTH_PX = 640.0  # SIFT runs on the left image shrunk to at most this width
_MIN_BATCH = 32  # features matched into the right image at least per KLT call (each call builds pyramids)


def _empty_keyframe(descriptor_bytes: int) -> Keyframe:
    return Keyframe(
        np.zeros((0, 2), np.float32), np.zeros((0, descriptor_bytes), np.uint8), np.zeros((0, 3), np.float32)
    )


class KeyframeExtractor:
    """`KeyframeExtractor(calibration, config)(left, right) -> Keyframe` for a rectified stereo pair."""

    def __init__(
        self, calibration, config: ClosureConfig | None = None, disparity_offset_px: float = 0.0
    ) -> None:
        self.config = config or ClosureConfig()
        # The rig's disparity correction (the VO's `disparity_offset_px`): a keyframe's depths come from the
        # same stereo pair as the odometry's, so a biased pair must be corrected here too, or every loop
        # link is measured at the wrong scale (KITTI 01 as given: 15 % long, docs/vo.md).
        if not np.isfinite(disparity_offset_px) or abs(disparity_offset_px) > 16.0:
            raise HippoNavError(
                f"disparity_offset_px = {disparity_offset_px}: a stereo correction of more than 16 px is not "
                "a correction; check the calibration's baseline and rectification instead"
            )
        self.disparity_offset_px = float(disparity_offset_px)
        self.calibration = calibration
        self.fx, self.fy = float(calibration.fx), float(calibration.fy)
        self.cx, self.cy = float(calibration.cx), float(calibration.cy)
        self.baseline_m = float(calibration.baseline_m)
        if not (self.fx > 0 and self.fy > 0 and self.baseline_m > 0):
            raise HippoNavError(
                f"calibration unusable for stereo keyframes: fx={self.fx}, fy={self.fy}, "
                f"baseline={self.baseline_m} m (need positive focal lengths and baseline)"
            )
        width, height = calibration.image_size_px
        # ORB's descriptor patch and border: 31 px on KITTI-size images, smaller on small renders so that
        # most rows stay usable (a 96-row image would keep only 34 rows at 31 px).
        patch = int(np.clip(height // 6, 15, 31)) | 1
        self.descriptor_bytes = DESCRIPTOR_BYTES[self.config.descriptor]
        self._detector: Any
        # SIFT describes the left image shrunk to at most `_SIFT_MAX_WIDTH_PX` wide (OpenCV's SIFT doubles
        # its input first, so a 1226-px KITTI image cost 6.3x ORB's extraction; at 640 px 2.8x, and the
        # measurements on real 06 and 01 were as good or better, docs/views.md).
        self._sift_scale = min(1.0, _SIFT_MAX_WIDTH_PX / float(width))
        if self.config.descriptor == "sift":
            self._detector = cv2.SIFT.create(nfeatures=self.config.orb_features)
        else:
            self._detector = cv2.ORB.create(
                nfeatures=self.config.orb_features,
                scaleFactor=1.2,
                nlevels=4,
                edgeThreshold=patch,
                patchSize=patch,
                fastThreshold=10,
            )
        window = int(np.clip(width // 25, 11, 15)) | 1
        self._klt: dict[str, Any] = {
            "winSize": (window, window),
            "maxLevel": 3,
            "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01),
        }

    def __call__(
        self, left: np.ndarray, right: np.ndarray, disparity_offset_px: float | None = None
    ) -> Keyframe:
        """The keyframe of a stereo pair; `disparity_offset_px`: the correction the odometry applies now
        (its self-calibration moves it), None: the one this extractor was made with."""
        cfg = self.config
        offset_px = self.disparity_offset_px if disparity_offset_px is None else float(disparity_offset_px)
        scale = self._sift_scale if cfg.descriptor == "sift" else 1.0
        image = left
        if scale < 1.0:
            size = (round(left.shape[1] * scale), round(left.shape[0] * scale))
            image = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
        keypoints, descriptors = self._detector.detectAndCompute(image, None)
        if descriptors is None or len(keypoints) == 0:
            return _empty_keyframe(self.descriptor_bytes)
        # SIFT's float descriptors hold whole numbers 0-255: kept as bytes, exactly, like ORB's.
        descriptors = np.clip(np.rint(descriptors), 0, 255).astype(np.uint8)
        pixels = np.array([k.pt for k in keypoints], dtype=np.float32)
        if scale < 1.0:  # back to full-size pixels (pixel centres at integers in both images)
            pixels = ((pixels + 0.5) / scale - 0.5).astype(np.float32)
        response = np.array([k.response for k in keypoints], dtype=np.float32)
        in_right = np.zeros_like(pixels)
        disparity = np.zeros(len(pixels), np.float32)
        # The strongest features with a stereo match, strongest first (ties in detection order). KLT tracks
        # every point on its own, so matching the strongest first, and the next ones only while fewer than
        # `keyframe_features` have matched, keeps exactly the features that matching all of them would
        # (on real KITTI 06 about 410 of the 500 are tracked and 340 tracked back: 0.9x the single-thread
        # CPU of a keyframe).
        order = np.argsort(-response, kind="stable")
        chosen: list[np.ndarray] = []
        wanted, start = cfg.keyframe_features, 0
        while wanted > 0 and start < len(order):
            batch = order[start : start + max(wanted + wanted // 4, _MIN_BATCH)]
            start += len(batch)
            matched, in_right[batch], disparity[batch] = self._stereo_matches(
                left, right, pixels[batch], offset_px
            )
            chosen.append(batch[matched][:wanted])
            wanted -= len(chosen[-1])
        index = np.concatenate(chosen) if chosen else np.zeros(0, np.int64)
        if index.size == 0:
            return _empty_keyframe(self.descriptor_bytes)
        if cfg.refine_stereo:
            refined, _ = _refine_matches(
                np.ascontiguousarray(left),
                np.ascontiguousarray(right),
                pixels[index].astype(np.float64),
                in_right[index].astype(np.float64),
                "row_shear",
                self._klt["winSize"][0] // 2,
            )
            disparity[index] = pixels[index, 0] - refined[:, 0].astype(np.float32) + offset_px
            index = index[disparity[index] > 0.5]
            if index.size == 0:
                return _empty_keyframe(self.descriptor_bytes)
        px = pixels[index]
        z = self.fx * self.baseline_m / disparity[index].astype(np.float64)
        points = np.column_stack([(px[:, 0] - self.cx) * z / self.fx, (px[:, 1] - self.cy) * z / self.fy, z])
        return Keyframe(
            np.ascontiguousarray(px, dtype=np.float32),
            np.ascontiguousarray(descriptors[index]),
            points.astype(np.float32),
        )

    def _stereo_matches(
        self, left: np.ndarray, right: np.ndarray, pixels: np.ndarray, offset_px: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(matched, right-image positions, disparities px) of left `pixels`: KLT into the right image from
        the disparity of `stereo_guess_depth_m`, kept within `stereo_row_tolerance_px` of the row, with a
        positive disparity, and back into the left image within `forward_backward_px` (tracked back only
        where the rest holds)."""
        cfg = self.config
        guess = pixels.copy()
        guess[:, 0] -= self.fx * self.baseline_m / cfg.stereo_guess_depth_m - offset_px
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
        in_right, ok, _ = cv2.calcOpticalFlowPyrLK(left, right, pixels, guess, flags=flags, **self._klt)
        disparity = pixels[:, 0] - in_right[:, 0] + offset_px
        matched = (
            (ok.ravel() == 1)
            & (np.abs(in_right[:, 1] - pixels[:, 1]) < cfg.stereo_row_tolerance_px)
            & (disparity > 0.5)
        )
        if matched.any():
            back, ok_back, _ = cv2.calcOpticalFlowPyrLK(
                right, left, in_right[matched], pixels[matched].copy(), flags=flags, **self._klt
            )
            matched[matched] = (ok_back.ravel() == 1) & (
                np.linalg.norm(back - pixels[matched], axis=1) < cfg.forward_backward_px
            )
        return matched, in_right, disparity
