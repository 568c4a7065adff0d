"""The stereo VO's settings (`VoParams`, the config's `vo` section) and its window's (`WindowConfig`,
`vo.window`: the parameters of the Rust `hippo_vo::WindowParams`, whose `Default` is the one source of their
defaults; they cross to Rust as its JSON). What each setting does: `odometry.py` and docs/vo.md.
"""

from __future__ import annotations

import json
import logging
from typing import Annotated, Literal

from pydantic import ConfigDict, Field, model_validator

from hippo_nav._defaults import ConfigSection, move_keys, rust_default

log = logging.getLogger("hippo_nav.vo")

__all__ = ["VoParams", "WindowConfig"]

# The forward–backward checks' window on images at least this wide (`klt_check_window_px`): a check starts
# where a consistent track comes back to, so a small window does its job; on 320-px renders it did not.
SMALL_CHECK_FROM_PX, SMALL_CHECK_PX = 640, 9

# Flat keys of the `vo` section before the window had a section of its own → its field now.
_MOVED_WINDOW_KEYS = {
    "window_keyframes": "max_keyframes",
    "window_fixed_keyframes": "fixed_keyframes",
    "window_pixel_sigma_px": "pixel_sigma_px",
    "window_right_sigma_px": "right_sigma_px",
    "window_iterations": "iterations",
    "window_min_shared": "min_shared_landmarks",
}


class WindowConfig(ConfigSection):
    """The windowed refinement (docs/vo.md, "Windowed refinement"); defaults from Rust (`WindowParams`)."""

    model_config = ConfigDict(frozen=True)

    max_keyframes: int = Field(
        rust_default("vo_window", "max_keyframes"),
        ge=0,
        le=100,
        description="keyframes refined jointly with the landmarks they share after every keyframe (the oldest "
        "fixed); 0 or 1: frame to frame only",
    )
    fixed_keyframes: int = Field(
        rust_default("vo_window", "fixed_keyframes"),
        ge=0,
        le=100,
        description="older keyframes kept beyond the window, fixed: their observations still place the "
        "landmarks the refined keyframes share with them",
    )
    pixel_sigma_px: float = Field(
        rust_default("vo_window", "pixel_sigma_px"), gt=0.0, description="σ of a tracked pixel"
    )
    right_sigma_px: float = Field(
        rust_default("vo_window", "right_sigma_px"),
        gt=0.0,
        description="σ of a right-image column (the stereo match): a stereo match of a slanted surface is less "
        "certain than a temporal track (docs/vo.md; 1 px: t_rel 1.25 % on the 05 render, 2 px: 1.03 %)",
    )
    huber_sigma: float = Field(
        rust_default("vo_window", "huber_sigma"),
        gt=0.0,
        description="Huber threshold on an observation's normalised residual",
    )
    outlier_chi2_stereo: float = Field(
        rust_default("vo_window", "outlier_chi2_stereo"),
        gt=0.0,
        description="χ² beyond which an observation with a right-image match is an outlier (χ²₃ at 95 %)",
    )
    outlier_chi2_mono: float = Field(
        rust_default("vo_window", "outlier_chi2_mono"),
        gt=0.0,
        description="the same without a right-image match (χ²₂ at 95 %)",
    )
    iterations: int = Field(
        rust_default("vo_window", "iterations"),
        ge=1,
        le=100,
        description="Levenberg–Marquardt iterations of each round",
    )
    min_shared_landmarks: int = Field(
        rust_default("vo_window", "min_shared_landmarks"),
        ge=1,
        le=100_000,
        description="a keyframe sharing fewer landmarks with the window starts a new window",
    )


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
        f"full-resolution window; None: {SMALL_CHECK_PX} px on images from {SMALL_CHECK_FROM_PX} px wide "
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
    disparity_calibration_prior_frames: int = Field(
        0,
        ge=0,
        le=10**9,
        description="estimates that earlier drives of this rig pooled for `disparity_offset_px`: the offset is "
        "first judged after min(`disparity_calibration_window`, this) of this drive's estimates instead of "
        "`disparity_calibration_min_frames` (a session started in a saved memory gets the saved run's, with its "
        "offset; docs/memory.md)",
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
    window: WindowConfig = Field(
        default_factory=WindowConfig,
        description="the windowed refinement (`WindowConfig`): keyframes refined jointly with the landmarks "
        "they share after every keyframe (a stereo bundle adjustment, the oldest fixed; docs/vo.md)",
    )
    keyframe_min_m: float = Field(
        0.2, ge=0.0, description="a frame becomes a keyframe after moving this far since the last one …"
    )
    keyframe_min_rad: float = Field(0.02, ge=0.0, description="… or turning this much")
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

    @model_validator(mode="before")
    @classmethod
    def _read_flat_window_keys(cls, data: object) -> object:
        """Configs written before the window had a section of its own (`vo.window_keyframes` →
        `vo.window.max_keyframes`, …) read as they meant, with a warning naming the new spelling."""
        if not isinstance(data, dict):
            return data
        data, moved = move_keys(
            data, lambda key: ("window", _MOVED_WINDOW_KEYS[key]) if key in _MOVED_WINDOW_KEYS else None
        )
        for old, new in moved:
            log.warning("config: vo.%s → vo.%s (the old spelling still reads; write the new one)", old, new)
        return data

    def window_params_json(self) -> str:
        """The JSON of the Rust window's `WindowParams`: this section's `window`, and the VO's
        `min_disparity_px` (the window places a landmark from the same disparities the tracker does)."""
        return json.dumps({**self.window.model_dump(), "min_disparity_px": self.min_disparity_px})
