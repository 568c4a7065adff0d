"""The stereo pair's disparity offset, estimated from the motion while the odometry runs (docs/vo.md,
"Disparity self-calibration").

A right image shifted against its calibration by δ px turns every depth into Z = fx·b / (d − δ): wrong by a
factor that grows with depth (far points, with small disparities, most). No rigid step moves near and far
points alike under wrong depths, so the motion measures δ where a scale error alone (a wrong baseline) is
invisible. KITTI 01 as the project has it needs about +1 px (its steps come out 15 % long without it),
06 about +0.15–0.25 px (docs/vo.md); at 6 px of disparity, 0.1 px is 1.7 % of scale.

Per tracked frame, `frame_offset_px` fits one extra offset ε to the frame's tracks jointly with the
step and the inverse depth of every point — a two-frame stereo bundle adjustment: the previous frame's right
column and the current frame's left and right pixels of each point (the previous left pixel fixes the
point's ray). Fitting the depths too, rather than taking them from the noisy previous disparities, keeps
the estimate unbiased where disparities are a few pixels (taking the depths as given read +0.05–0.08 px
on renders with no offset at all; this fit +0.03). Per frame the estimate scatters by 0.15–0.5 px, so
`DisparityCalibration` pools the estimates since the offset last changed and moves the offset by their
median only when it is beyond `deadband_px` and three standard errors, judged when the pool has doubled:
on a consistent rig the offset in use never moves (a render's scale changes by ~1 % for every 0.03 px at
320×96 px).

Which tracks: every one within a wide gate of the step (`VoParams.disparity_calibration_gate_px`), not PnP's
inliers. RANSAC's tight gate is judged on depths made with the offset in use, so it keeps the points whose
noise cancels that offset's error and drops the ones that show it; on those the fit read about 0.6–0.7 of an
offset (docs/vo.md, "Which tracks the fit takes"). The mistracks a wide gate lets in are dropped by a refit
without the points whose residuals stay large (`reject_px`).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from hippo_nav._core import _frame_offset

__all__ = ["LIMIT_PX", "MAX_POINTS", "DisparityCalibration", "frame_offset_px"]

LIMIT_PX = 5.0  # the range of `VoParams.disparity_offset_px`
SETTLED_STRIDE = 5  # with a full pool, one frame in this many is fitted
MAX_POINTS = 200  # a 0.03 px formal error per frame; the fit costs per point


def frame_offset_px(
    cur_from_prev: np.ndarray,
    prev_points_m: np.ndarray,
    left_px: np.ndarray,
    right_u_px: np.ndarray,
    has_right: np.ndarray,
    camera: tuple[float, float, float, float, float],
    huber_px: float,
    reject_px: float | None = None,
) -> tuple[float, float] | None:
    """(offset px to add to the one in use, its formal standard error px), fitted to one frame's tracks
    (module doc), or None when the fit is not possible (too few points, a point behind a camera, a singular
    system). The standard error is large where the motion cannot tell an offset (the camera standing still).

    `prev_points_m` (n, 3): the points in the previous camera as its stereo pair measured them (the
    disparity in use applied); `left_px` (n, 2): their tracks in the current left image; `right_u_px` (n,):
    their current right-image columns, corrected by the offset in use, valid where `has_right`;
    `camera` = (fx, fy, cx, cy, baseline_m); `cur_from_prev` the step's estimate to start from. With
    `reject_px`, the points with a residual beyond it after the fit are dropped and the fit repeated once."""
    z0 = prev_points_m[:, 2]
    if len(z0) < 12 or not (z0 > 0).all():
        return None
    if len(z0) > MAX_POINTS:  # evenly thinned: deterministic
        pick = np.linspace(0, len(z0) - 1, MAX_POINTS).astype(np.int64)
        prev_points_m, left_px, right_u_px, has_right = (
            prev_points_m[pick],
            left_px[pick],
            right_u_px[pick],
            has_right[pick],
        )
    if not (np.isfinite(prev_points_m).all() and np.isfinite(left_px).all()):
        return None
    has_right = np.asarray(has_right, bool)
    # A column without a right match is never read; the fit takes only finite numbers.
    right = np.where(has_right, np.asarray(right_u_px, np.float64), 0.0)
    fx, fy, cx, cy, baseline_m = (float(c) for c in camera)
    # The fit itself runs in Rust (hippo_vo::disparity): in numpy, nearly all of its ~3 ms a frame was
    # per-call overhead on 200 points (docs/vo.md, "Disparity self-calibration").
    return _frame_offset(
        np.asarray(cur_from_prev, np.float64),
        np.asarray(prev_points_m, np.float64),
        np.asarray(left_px, np.float64),
        right,
        has_right,
        (fx, fy, cx, cy, baseline_m),
        float(huber_px),
        None if reject_px is None else float(reject_px),
    )


class DisparityCalibration:
    """The offset in use and the evidence for changing it (module doc): `add(ε, σ)` per frame, ε measured
    against the offset in use; `offset_px` is what the odometry applies.

    The estimates since the last change are pooled (at most `window`): when their median is beyond
    `deadband_px` and beyond three standard errors of a median, the offset moves by it and the pool starts
    again (estimates made against the old offset no longer apply). A frame's fit reads almost all of a large
    offset (on KITTI 01 +1.0 of about +1.05 px), so a large one is reached in one or two moves; ten frames of a
    real street can read ±0.5 px apart, so the offset in use also wanders by that much over a short drive
    (docs/vo.md).

    `prior_frames`: estimates that earlier drives of this rig pooled for `initial_px` (a session started in a
    saved memory). The first look then waits for min(`window`, `prior_frames`) of this drive's own estimates
    instead of `min_frames`: ten frames of one street must not overturn an offset a whole drive settled (on
    the 00 render, sessions started at frames 3490 and 3500 moved it by −0.07 and −0.03 px on their first
    streets, and their odometry ran about 1 % long: docs/memory.md)."""

    def __init__(
        self,
        initial_px: float,
        window: int,
        min_frames: int,
        deadband_px: float,
        max_sigma_px: float,
        prior_frames: int = 0,
    ) -> None:
        self.offset_px = float(initial_px)
        self.min_frames = int(min_frames)
        self.deadband_px = float(deadband_px)
        self.max_sigma_px = float(max_sigma_px)
        self._estimates_px: deque[float] = deque(maxlen=int(window))
        # Frames since the last change; when to judge next; the earlier drives' estimates behind the offset.
        self._prior = max(0, int(prior_frames))
        self._pooled, self._next_look = 0, max(self.min_frames, min(int(window), self._prior))
        self._offered = 0  # frames asked about (`wants_frame`)

    def wants_frame(self) -> bool:
        """Whether this frame should be fitted: every frame until the pool is full, then every
        `SETTLED_STRIDE`-th (a rig's offset does not change from frame to frame; a frame's tracks cost ~2 ms)."""
        self._offered += 1
        return (
            len(self._estimates_px) < (self._estimates_px.maxlen or 1) or self._offered % SETTLED_STRIDE == 0
        )

    @property
    def frames(self) -> int:
        """Frames pooled since the offset last changed."""
        return len(self._estimates_px)

    @property
    def evidence_frames(self) -> int:
        """Estimates behind the offset in use: this drive's since it last changed, and the earlier drives'
        (`prior_frames`) while it has not (what a saved memory keeps for the next session)."""
        return self._prior + self._pooled

    def add(self, estimate_px: float, sigma_px: float) -> bool:
        """Take one frame's estimate (px, against the offset in use) and its standard error; True when the
        offset in use changed. A frame that cannot tell an offset (`sigma_px` above `max_sigma_px`: a camera
        standing still, a flat view) is left out."""
        if not (np.isfinite(estimate_px) and np.isfinite(sigma_px)) or sigma_px > self.max_sigma_px:
            return False
        self._estimates_px.append(float(estimate_px))
        self._pooled += 1
        # Judged when the pool has doubled since the last look (then every `window` frames), not every
        # frame: each look is another chance for noise to pass the test.
        if self._pooled < self._next_look:
            return False
        self._next_look = min(2 * self._pooled, self._pooled + (self._estimates_px.maxlen or 1))
        estimates = np.fromiter(self._estimates_px, float)
        median = float(np.median(estimates))
        # Standard error of a median, from the median absolute deviation (robust to a bad frame's fit).
        spread = 1.4826 * float(np.median(np.abs(estimates - median)))
        standard_error = 1.2533 * spread / np.sqrt(len(estimates))
        if abs(median) <= max(self.deadband_px, 3.0 * standard_error):
            return False
        # Never beyond what `vo.disparity_offset_px` may be set to: more is a broken rig, not an offset.
        self.offset_px = float(np.clip(self.offset_px + median, -LIMIT_PX, LIMIT_PX))
        self._estimates_px.clear()
        self._prior, self._pooled, self._next_look = 0, 0, self.min_frames
        return True
