"""The odometry plug point: anything with `process(frame) -> step`, where the step has
`camera_prev_from_camera_cur` (4 × 4 SE(3), identity on the first frame) and `status`. Optional attributes
(`tracked_pixels`, `warnings`, `stereo_bias_px`, `stereo_fault`, `disparity_offset_px`) are read in one place,
`hippo_nav.pipeline.frontend.OdometryExtras`. The registry is `vo.ODOMETRIES`.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from hippo_nav.datasets.base import StereoFrame

__all__ = ["Odometry", "OdometryStep"]


class OdometryStep(Protocol):
    @property
    def camera_prev_from_camera_cur(self) -> np.ndarray: ...

    @property
    def status(self) -> str: ...


class Odometry(Protocol):
    def process(self, frame: StereoFrame) -> OdometryStep: ...
