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
from typing import Any, Literal

import cv2
import numpy as np
from pydantic import ConfigDict, Field

from hippo_nav._core import HippoNavError, _refine_matches
from hippo_nav._defaults import ConfigSection


class ClosureConfig(ConfigSection):
    """Geometric loop-closure parameters (the map's `closure` mode chooses whether they are used)."""

    model_config = ConfigDict(frozen=True)

    orb_features: int = Field(
        500, ge=16, le=20000, description="features (ORB corners or SIFT blobs) detected per left image"
    )
    descriptor: Literal["orb", "sift"] = Field(
        "sift",
        description="what a keyframe's features are described by: SIFT (128 bytes, L2) or ORB (32 bytes, "
        "Hamming). Across a change of light, shadows, noise and blur (the `strong` renders) SIFT matches "
        "true revisits where ORB does not, and on real KITTI its measurements are about half as far off, at "
        "2-3x ORB's extraction time (docs/views.md, docs/results.md)",
    )
    keyframe_features: int = Field(
        300, ge=16, le=20000, description="strongest stereo features a keyframe keeps"
    )
    ratio_test: float = Field(0.8, gt=0.0, le=1.0, description="Lowe's ratio for descriptor matches")
    ransac_reprojection_px: float = Field(2.0, gt=0.0, description="PnP RANSAC inlier threshold")
    ransac_iterations: int = Field(300, ge=10, le=100_000)
    min_inliers: int = Field(
        30, ge=6, le=20000, description="fewer PnP inliers reject a closure (unrelated places give < 10)"
    )
    min_inlier_ratio: float = Field(
        0.25, ge=0.0, le=1.0, description="inliers / descriptor matches below this reject a closure"
    )
    max_distance_m: float = Field(
        4.0,
        gt=0.0,
        description="a keyframe measured farther away is rejected: closures join places within 4 m (the "
        "vertex spacing is ~3 m); far keyframes are seen at grazing angles with few, weak matches, and their "
        "range is measured worst (one measured within 5 m was 5.85 m away in truth, on the 00 render)",
    )
    max_sigma_m: float = Field(
        1.5,
        gt=0.0,
        description="a measurement whose position is less certain than this (largest σ of the covariance the "
        "map gets, m) is refused (noted `uncertain`): on the 00 render at `strong` the accepted measurements "
        "3 m or more off had 1.5-1.6 m, those within 0.6 m of the truth mostly under 1.3 m",
    )
    sigma_floor_xy_m: float = Field(0.05, gt=0.0, description="least position uncertainty of a loop link")
    sigma_floor_yaw_rad: float = Field(0.005, gt=0.0, description="least heading uncertainty of a loop link")
    covariance_inflation: float = Field(
        4.0,
        ge=1.0,
        le=1e6,
        description="factor on the measured pose's covariance (for errors the model leaves out)",
    )
    pixel_sigma_px: float = Field(
        0.7, gt=0.0, le=10.0, description="standard deviation of an ORB corner's position (px)"
    )
    disparity_sigma_px: float = Field(
        0.3, gt=0.0, le=10.0, description="standard deviation of a stereo disparity (px)"
    )
    candidates_per_frame: int = Field(
        2, ge=1, le=100, description="candidate vertices measured per frame at most"
    )
    anchor_neighbours: int = Field(
        1,
        ge=0,
        le=20,
        description="vertices on either side of a familiar view's anchor vertex that may be measured (the "
        "nearest `candidates_per_frame` by the odometry's prediction are)",
    )
    closure_spacing_m: float = Field(
        3.0, ge=0.0, description="travel (m) between accepted closures; closer ones add little"
    )
    view_cell_confirmed_min_inliers: int = Field(
        15,
        ge=6,
        le=20000,
        description="a familiar view's candidate measured with fewer than `min_inliers` PnP inliers but at least "
        "this many is proposed only when a path neighbour of its vertex, measured from the same frame, confirms "
        "it (as a proximity one, `proximity_agreement_*`): another sun or lane leaves a true revisit 15-30 "
        "inliers, unrelated places at most 9 (docs/views.md). Set it to `min_inliers` to turn it off",
    )
    proximity: bool = Field(
        True,
        description="a frame whose familiar view gives no closure (or that has none) also measures the nearest "
        "vertex inside the map's loop gate, confirmed by a neighbour of that vertex (`proximity_confirm`): "
        "closes revisits whose look changed too much for the view cells (docs/results.md)",
    )
    proximity_min_inliers: int = Field(
        15,
        ge=6,
        le=20000,
        description="PnP inliers a proximity measurement needs (the gate has already placed the vertex; "
        "unrelated real and rendered places give at most 9, docs/views.md)",
    )
    proximity_radius_m: float = Field(
        8.0,
        gt=0.0,
        description="a proximity measurement is tried only when the odometry puts the nearest gated vertex "
        "this close: `max_distance_m` plus the odometry's likely error (farther ones were 90 % of the failed "
        "tries on the 06 render, and their cost)",
    )
    proximity_radius_per_m: float = Field(
        0.01,
        ge=0.0,
        description="beyond `proximity_radius_m`, the proximity search also reaches this share of the travel "
        "since the last closure (an odometry drifts about 1 % of its path: on the 02 render at `strong` the "
        "two passes of a street were 27-31 m apart after 2.9-3.4 km), measuring one vertex of that ring a "
        "frame, in turn; 0: only `proximity_radius_m`",
    )
    proximity_max_radius_m: float = Field(
        50.0, gt=0.0, description="the proximity search reaches at most this far (m)"
    )
    proximity_confirm: bool = Field(
        True,
        description="a proximity measurement is proposed only when a neighbour of its vertex along the path, "
        "measured from the same frame, puts that neighbour where the first measurement and the map do "
        "(`proximity_agreement_*`): a wrong PnP pose from few matches is not repeated by a second keyframe",
    )
    proximity_confirm_min_inliers: int = Field(
        10, ge=6, le=20000, description="PnP inliers the confirming neighbour's measurement needs"
    )
    proximity_confirm_max_distance_m: float = Field(
        7.0,
        gt=0.0,
        description="the confirming neighbour may be measured this far away (`max_distance_m` plus a vertex "
        "spacing)",
    )
    proximity_agreement_m: float = Field(
        1.5,
        gt=0.0,
        description="a confirmed proximity closure's two measurements put the neighbour within this of each "
        "other (pairs within 1 m of the truth on the `strong` renders: 0.1-1.2 m; with a wrong one: 2.4-4.9 m, "
        "docs/results.md)",
    )
    proximity_agreement_rad: float = Field(0.1, gt=0.0, description="… and within this heading")
    birdseye: bool = Field(
        False,
        description="also propose closures by registering bird's-eye submaps of stereo structure (heading "
        "invariant, for streets driven the other way; docs/map.md) when no view or proximity closure is "
        "proposed; off by default for its cost where the map has old places around (docs/results.md, "
        "'Reverse loops (08)')",
    )
    birdseye_submap_m: float = Field(
        40.0, gt=0.0, description="path a submap spans: the query's behind it, a stored place's around it"
    )
    birdseye_radius_m: float = Field(
        30.0, gt=0.0, description="a submap keeps points this close to its centre"
    )
    birdseye_max_depth_m: float = Field(
        15.0,
        gt=0.0,
        description="stereo points deeper than this are left out: a post seen from several vertices smears "
        "along the line of sight by its depth error (0.3 px of disparity is 0.7 m at 15 m on a 320-px render)",
    )
    birdseye_camera_height_m: float = Field(1.65, gt=0.0, description="the camera's height over the road")
    birdseye_min_height_m: float = Field(
        0.5, description="points lower than this over the road are road, and left out"
    )
    birdseye_spacing_m: float = Field(
        3.0, gt=0.0, description="travel between bird's-eye attempts (one per new vertex at most)"
    )
    birdseye_search_m: float = Field(
        40.0,
        gt=0.0,
        description="the registration searches the map this far around where the odometry puts the agent (or "
        "the loop gate, if smaller): the odometry's likely drift between closures, not the gate's bound",
    )
    birdseye_search_rad: float = Field(
        0.35,
        gt=0.0,
        description="… and within this heading of the odometry's (or the loop gate's, if smaller)",
    )
    birdseye_min_points: int = Field(
        150,
        ge=10,
        le=100_000,
        description="a submap with fewer structure points neither proposes nor is proposed",
    )
    birdseye_min_peak_ratio: float = Field(
        1.15, ge=1.0, description="the correlation peak over the best alignment elsewhere, at least"
    )
    birdseye_min_inliers: int = Field(
        150, ge=3, le=100_000, description="fitting query points a registration needs"
    )
    birdseye_min_overlap: float = Field(
        0.5, ge=0.0, le=1.0, description="fitting share of the query points on the shared area, at least"
    )
    birdseye_max_self_similarity: float = Field(
        1.0,
        ge=0.0,
        le=1.0,
        description="a submap whose structure correlates with itself shifted 5 m more than this slides along "
        "itself (a straight street of walls) and is not registered",
    )
    birdseye_confirm: bool = Field(
        True,
        description="a bird's-eye registration is proposed only when an earlier one, from another stretch of "
        "path within 30 m of travel, implies the same correction of the map (within 1.5 m and 0.05 rad)",
    )
    relocalisation_min_inliers: int = Field(
        60,
        ge=6,
        le=20000,
        description="PnP inliers a measurement needs to relocalise in a loaded map (no odometry gate checks it, "
        "so twice the closure bar)",
    )
    relocalisation_confirmations: int = Field(
        2,
        ge=1,
        le=100,
        description="measurements from different frames that must agree on where the session lies in the "
        "loaded map before it is joined",
    )
    relocalisation_window_m: float = Field(
        30.0, gt=0.0, description="travel within which the agreeing measurements must fall"
    )
    relocalisation_agreement_m: float = Field(
        1.0, gt=0.0, description="agreeing measurements put the agent within this distance of each other"
    )
    relocalisation_agreement_rad: float = Field(
        0.05, gt=0.0, description="… and within this heading of each other"
    )

    stereo_row_tolerance_px: float = Field(1.5, gt=0.0)
    refine_stereo: bool = Field(
        True,
        description="refine each stereo match with a row-sheared window (as the VO does, docs/vo.md): KLT's "
        "square window is biased on a slanted road, which made measured links a few percent long",
    )
    stereo_guess_depth_m: float = Field(20.0, gt=0.0, description="depth whose disparity starts stereo KLT")
    forward_backward_px: float = Field(1.0, gt=0.0, description="max left-right-left KLT error")


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
        guess = pixels.copy()
        guess[:, 0] -= self.fx * self.baseline_m / cfg.stereo_guess_depth_m - offset_px
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
        in_right, ok, _ = cv2.calcOpticalFlowPyrLK(left, right, pixels, guess, flags=flags, **self._klt)
        back, ok_back, _ = cv2.calcOpticalFlowPyrLK(
            right, left, in_right, pixels.copy(), flags=flags, **self._klt
        )
        disparity = pixels[:, 0] - in_right[:, 0] + offset_px
        keep = (
            (ok.ravel() == 1)
            & (ok_back.ravel() == 1)
            & (np.linalg.norm(back - pixels, axis=1) < cfg.forward_backward_px)
            & (np.abs(in_right[:, 1] - pixels[:, 1]) < cfg.stereo_row_tolerance_px)
            & (disparity > 0.5)
        )
        index = np.flatnonzero(keep)
        index = index[np.argsort(-response[index], kind="stable")[: cfg.keyframe_features]]
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
