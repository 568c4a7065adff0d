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

import cv2
import numpy as np

from hippo_nav.vo.projection import pixel_rows

__all__ = ["LIMIT_PX", "MAX_POINTS", "DisparityCalibration", "frame_offset_px"]

LIMIT_PX = 5.0  # the range of `VoParams.disparity_offset_px`
SETTLED_STRIDE = 5  # with a full pool, one frame in this many is fitted
_ITERATIONS = 4
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
    fx, fy, cx, cy, baseline_m = camera
    fxb = fx * baseline_m
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
        z0 = prev_points_m[:, 2]
    n = len(z0)
    ray = prev_points_m / z0[:, None]  # (x/z, y/z, 1): fixed by the previous left pixel
    d_prev = fxb / z0  # the previous frame's disparity, offset in use applied
    inverse_depth = 1.0 / z0
    left = left_px.astype(np.float64)
    right = np.asarray(right_u_px, np.float64)
    with_right = np.flatnonzero(has_right)
    everyone = np.arange(n)
    rotation, translation = cur_from_prev[:3, :3].copy(), cur_from_prev[:3, 3].copy()
    offset = 0.0
    for _ in range(_ITERATIONS):
        points = ray / inverse_depth[:, None]
        x = points @ rotation.T + translation
        if (x[:, 2] <= 0).any() or (inverse_depth <= 0).any():
            return None
        dx_dinverse = (-points / inverse_depth[:, None]) @ rotation.T
        blocks = [
            # previous right column: measured d_prev + ε against fx·b·ρ
            (d_prev + offset - fxb * inverse_depth, np.zeros((n, 6)), np.ones(n), -fxb * np.ones(n), everyone)
        ]
        for axis, shift_m, rows, observed, offset_sign in (
            (0, 0.0, everyone, left[:, 0], 0.0),
            (1, 0.0, everyone, left[:, 1], 0.0),
            (0, baseline_m, with_right, right[with_right], 1.0),
        ):
            residual, jac_pose, d_a, d_z = pixel_rows(x[rows], axis, shift_m, (fx, fy, cx, cy))
            jac_point = d_a * dx_dinverse[rows, axis] + d_z * dx_dinverse[rows, 2]
            # the current right column is corrected by ε too: observed − ε
            blocks.append(
                (
                    residual - observed + offset_sign * offset,
                    jac_pose,
                    np.full(len(rows), offset_sign),
                    jac_point,
                    rows,
                )
            )
        r = np.concatenate([b[0] for b in blocks])
        jac = np.column_stack(
            [np.concatenate([b[1] for b in blocks]), np.concatenate([b[2] for b in blocks])]
        )
        jac_inv = np.concatenate([b[3] for b in blocks])
        point = np.concatenate([b[4] for b in blocks])
        weight = np.where(np.abs(r) <= huber_px, 1.0, huber_px / np.maximum(np.abs(r), 1e-12))
        # Normal equations with the point block eliminated (Schur complement; one unknown per point).
        jw = jac * weight[:, None]
        a = jw.T @ jac
        g = jw.T @ r
        d = np.bincount(point, weight * jac_inv**2, n) + 1e-12
        b = np.stack([np.bincount(point, jw[:, k] * jac_inv, n) for k in range(7)])
        g_point = np.bincount(point, weight * jac_inv * r, n)
        reduced = a - (b / d) @ b.T
        try:
            delta = -np.linalg.solve(reduced, g - (b / d) @ g_point)
            variance = float(np.linalg.inv(reduced)[6, 6])
        except np.linalg.LinAlgError:
            return None
        inverse_depth = inverse_depth - (g_point + b.T @ delta) / d
        update = cv2.Rodrigues(delta[:3])[0]
        rotation, translation = update @ rotation, update @ translation + delta[3:6]
        offset += float(delta[6])
        if abs(delta[6]) < 1e-4:
            break
    if reject_px is not None:
        # A point on the wrong texture keeps a large residual whatever its depth; the offset a right image
        # is shifted by does not (the fit explains it). Measured from the last iteration's residuals.
        worst = np.zeros(n)
        np.maximum.at(worst, point, np.abs(r))
        keep = worst <= reject_px
        if not keep.all():
            return frame_offset_px(
                cur_from_prev,
                prev_points_m[keep],
                left_px[keep],
                right_u_px[keep],
                has_right[keep],
                camera,
                huber_px,
            )
    # The residuals' own scatter scales the formal variance (robust: from their median absolute value).
    sigma_px = 1.4826 * float(np.median(np.abs(r))) * np.sqrt(max(variance, 0.0))
    return (offset, sigma_px) if np.isfinite(offset) and np.isfinite(sigma_px) else None


class DisparityCalibration:
    """The offset in use and the evidence for changing it (module doc): `add(ε, σ)` per frame, ε measured
    against the offset in use; `offset_px` is what the odometry applies.

    The estimates since the last change are pooled (at most `window`): when their median is beyond
    `deadband_px` and beyond three standard errors of a median, the offset moves by it and the pool starts
    again (estimates made against the old offset no longer apply). A frame's fit reads almost all of a large
    offset (on KITTI 01 +1.0 of about +1.05 px), so a large one is reached in one or two moves; ten frames of a
    real street can read ±0.5 px apart, so the offset in use also wanders by that much over a short drive
    (docs/vo.md)."""

    def __init__(
        self, initial_px: float, window: int, min_frames: int, deadband_px: float, max_sigma_px: float
    ) -> None:
        self.offset_px = float(initial_px)
        self.min_frames = int(min_frames)
        self.deadband_px = float(deadband_px)
        self.max_sigma_px = float(max_sigma_px)
        self._estimates_px: deque[float] = deque(maxlen=int(window))
        self._pooled, self._next_look = 0, self.min_frames  # frames since the last change; when to judge
        self._offered = 0  # frames asked about (`wants_frame`)

    def wants_frame(self) -> bool:
        """Whether this frame should be fitted: every frame until the pool is full, then every
        `SETTLED_STRIDE`-th (a rig's offset does not change from frame to frame; the fit costs ~1.5 ms)."""
        self._offered += 1
        return (
            len(self._estimates_px) < (self._estimates_px.maxlen or 1) or self._offered % SETTLED_STRIDE == 0
        )

    @property
    def frames(self) -> int:
        """Frames pooled since the offset last changed."""
        return len(self._estimates_px)

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
        self._pooled, self._next_look = 0, self.min_frames
        return True
