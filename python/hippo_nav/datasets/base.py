"""The stereo dataset protocol every loader implements, and the calibration/frame records it yields.

Conventions (docs/spec.md §9): images are rectified 8-bit gray; camera 0 is the left camera, camera 1
the right one, displaced by `baseline_m` along camera 0's +x axis. Camera frame: x right, y down,
z forward.
`P_i = K [I | t_i]` projects a point in camera-0 coordinates into camera i's image, so for a rectified
pair `P1[0, 3] = −fx · baseline_m`. Poses are `world_from_camera` (camera 0) 4×4 matrices.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class StereoCalibration:
    """Projection matrices of a rectified stereo rig (3×4 float64) and the image size of cameras 0/1."""

    P0: np.ndarray
    P1: np.ndarray
    P2: np.ndarray | None
    P3: np.ndarray | None
    image_size_px: tuple[int, int]  # (width, height)

    @property
    def fx(self) -> float:
        return float(self.P0[0, 0])

    @property
    def fy(self) -> float:
        return float(self.P0[1, 1])

    @property
    def cx(self) -> float:
        return float(self.P0[0, 2])

    @property
    def cy(self) -> float:
        return float(self.P0[1, 2])

    @property
    def K(self) -> np.ndarray:
        """3×3 intrinsics of camera 0 (a copy)."""
        return np.array(self.P0[:, :3], dtype=np.float64)

    @property
    def baseline_m(self) -> float:
        """Distance between the left and right camera centres: −P1[0,3] / P1[0,0]."""
        return float(-self.P1[0, 3] / self.P1[0, 0])


@dataclass(frozen=True)
class StereoFrame:
    """One rectified stereo pair; `index` is the frame number in the sequence (file name NNNNNN)."""

    index: int
    timestamp_s: float
    left: np.ndarray  # uint8 (H, W), camera 0
    right: np.ndarray  # uint8 (H, W), camera 1


@runtime_checkable
class StereoDataset(Protocol):
    """What the pipeline needs from a stereo dataset: calibration, lazily loaded frames, ground truth."""

    name: str
    calibration: StereoCalibration
    frame_indices: np.ndarray  # int64, the sequence frames this object yields (after range and stride)
    timestamps_s: np.ndarray  # float64, one per yielded frame

    def __len__(self) -> int: ...

    def __getitem__(self, i: int) -> StereoFrame: ...

    def __iter__(self) -> Iterator[StereoFrame]: ...

    def ground_truth(self) -> np.ndarray | None:
        """(len, 4, 4) `world_from_camera` of camera 0 for the yielded frames, or None when unknown."""
        ...
