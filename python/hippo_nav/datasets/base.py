"""The stereo dataset protocol, the loader contract every loader follows, and the records they yield.

- `StereoDataset`: what the pipeline reads (a protocol: any object with these members is a dataset).
- `DatasetExtras`: the optional attributes a dataset may have beyond the protocol (a note, warnings, missing
  frames, …), with their defaults; `DatasetExtras.of(dataset)` is the one place they are read.
- `StereoLoader`: the base class of the registered loaders (`hippo_nav.datasets.LOADERS`). Its class
  attributes are the contract `open_dataset` and the CLI read: `KIND` (the name), `TITLE` and `LAYOUT` (for
  messages), `OPTIONS` (the keywords its constructor takes besides root and sequence), `FLAGS` (the
  `LoaderFlag`s: those of its options the command line offers as flags, `--left-topic` for `left_topic`, in
  `hippo-nav run` and `hippo-nav sweep` and as sweep-file keys), `DEFAULT_SEQUENCE`; a static `detect(path)` recognises its layout; the constructor is
  `Loader(root, sequence, **options)`. The base owns the shared skeleton: the extras with their defaults,
  length, bounds-checked indexing (a subclass reads frame i in `_frame(i)`), iteration, ground truth.

Conventions (docs/spec.md §9): images are rectified 8-bit gray; camera 0 is the left camera, camera 1
the right one, displaced by `baseline_m` along camera 0's +x axis. Camera frame: x right, y down,
z forward.
`P_i = K [I | t_i]` projects a point in camera-0 coordinates into camera i's image, so for a rectified
pair `P1[0, 3] = −fx · baseline_m`. Poses are `world_from_camera` (camera 0) 4×4 matrices.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

from hippo_nav.io.errors import DatasetError


@dataclass(frozen=True)
class StereoCalibration:
    """Projection matrices of a rectified stereo rig (3×4 float64) and the image size of its images. `P0`, `P1`
    are the pair the odometry uses, left and right (for KITTI's colour pair, P2 and P3 put in camera 2's frame);
    `P2`, `P3` are KITTI's colour-camera lines as written, when the file has them."""

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


# What a real stereo camera looks like (`check_calibration`): a calibration outside these ranges is a typo, a
# value in the wrong unit (mm for m), or a file of another camera.
FIELD_OF_VIEW_DEG = (1.0, 175.0)
"""Horizontal field of view of a rectified (pinhole) camera: a telephoto lens to a fisheye's pinhole part."""
MAX_FOCAL_RATIO = 2.0
"""fx / fy (either way): pixels are square within this factor (anamorphic lenses stay under 2)."""
PRINCIPAL_POINT_MARGIN = 0.5
"""The principal point lies in the image widened by this fraction of its size on every side."""
BASELINE_M = (1e-3, 20.0)
"""Distance between the stereo cameras: a phone's or a micro drone's pair to a survey rig's."""
MAX_IMAGE_PIXELS = 1 << 26
"""Pixels of an image at most (67 million: 8192 × 8192; KITTI's have 0.47 million). A larger image, or a
file that declares one, is refused before it is decoded: its buffers would take gigabytes."""


def check_intrinsics(
    fx: float, fy: float, cx: float, cy: float, image_size_px: tuple[int, int], where: str
) -> None:
    """Raise a `DatasetError` naming `where`, the value and the plausible range when a pinhole camera's
    focal lengths and principal point (pixels) cannot be those of a real camera with images of
    `image_size_px` (width, height)."""
    width, height = image_size_px
    if not (width >= 1 and height >= 1 and width * height <= MAX_IMAGE_PIXELS):
        raise DatasetError(
            f"{where}: image size {width}x{height} px; images of 1 to {MAX_IMAGE_PIXELS} pixels are read"
        )
    low_deg, high_deg = FIELD_OF_VIEW_DEG
    fx_min = width / (2.0 * math.tan(math.radians(high_deg) / 2.0))
    fx_max = width / (2.0 * math.tan(math.radians(low_deg) / 2.0))
    if not fx_min <= fx <= fx_max:
        problem = (
            f"gives a horizontal field of view of {math.degrees(2.0 * math.atan(width / (2.0 * fx))):.2f}° over "
            f"{width} px"
            if fx > 0
            else "is not a focal length"
        )
        raise DatasetError(
            f"{where}: fx = {fx:g} px {problem}; a camera sees {low_deg:g}° to {high_deg:g}°, i.e. fx from "
            f"{fx_min:.4g} to {fx_max:.4g} px at this width"
        )
    if not fx / MAX_FOCAL_RATIO <= fy <= fx * MAX_FOCAL_RATIO:
        raise DatasetError(
            f"{where}: fy = {fy:g} px against fx = {fx:g} px; pixels are square within a factor "
            f"{MAX_FOCAL_RATIO:g} (fy from {fx / MAX_FOCAL_RATIO:.4g} to {fx * MAX_FOCAL_RATIO:.4g} px)"
        )
    for name, value, side in (("cx", cx, width), ("cy", cy, height)):
        low, high = -PRINCIPAL_POINT_MARGIN * side, (1.0 + PRINCIPAL_POINT_MARGIN) * side
        if not low <= value <= high:
            raise DatasetError(
                f"{where}: the principal point's {name} = {value:g} px lies far outside the {width}x{height} "
                f"px image; it must lie from {low:g} to {high:g} px (the image centre is "
                f"{(width - 1) / 2:g}, {(height - 1) / 2:g})"
            )


def check_calibration(calibration: StereoCalibration, where: str) -> StereoCalibration:
    """`calibration` when it is a plausible rectified stereo rig (`check_intrinsics` of camera 0, a
    baseline within `BASELINE_M`), else a `DatasetError` naming `where`, the value and the plausible range.
    Every loader checks the calibration it builds here, once, when the dataset is opened."""
    if not (np.isfinite(calibration.P0).all() and np.isfinite(calibration.P1).all()):
        raise DatasetError(f"{where}: the projection matrices hold NaN or infinity")
    check_intrinsics(
        calibration.fx, calibration.fy, calibration.cx, calibration.cy, calibration.image_size_px, where
    )
    if not calibration.P1[0, 0] > 0:
        raise DatasetError(
            f"{where}: the right camera's fx (P1[0,0] = {calibration.P1[0, 0]:g}) must be positive"
        )
    baseline_m = calibration.baseline_m
    low_m, high_m = BASELINE_M
    if not low_m <= baseline_m <= high_m:
        raise DatasetError(
            f"{where}: the stereo baseline is {baseline_m:g} m; a stereo rig's lies from {low_m * 1000:g} mm to "
            f"{high_m:g} m (check the unit, metres, and that P1[0,3] = −fx·baseline)"
        )
    return calibration


@dataclass(frozen=True)
class LoaderFlag:
    """A loader option offered on the command line: `keyword` (one of the loader's `OPTIONS`) becomes the
    flag `--keyword` (underscores as dashes) of `hippo-nav run` and `hippo-nav sweep` and a sweep-file key;
    `metavar` and `help` are its help (the CLI puts the kinds of the loaders that take it in front)."""

    keyword: str
    metavar: str
    help: str

    @property
    def flag(self) -> str:
        """The command-line flag: `--left-topic` for `left_topic`."""
        return "--" + self.keyword.replace("_", "-")


@dataclass(frozen=True)
class StereoFrame:
    """One rectified stereo pair; `index` is the frame number in the sequence (file name NNNNNN)."""

    index: int
    timestamp_s: float
    left: np.ndarray  # uint8 (H, W), camera 0
    right: np.ndarray  # uint8 (H, W), camera 1


def check_stereo_images(frame: StereoFrame, image_size_px: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The frame's (left, right) as contiguous 8-bit gray (H, W) arrays of the calibration's size, or a
    `DatasetError` saying which is not: images of another size than their calibration would leave every frame
    without odometry, a run of zeros that says nothing of why."""
    where = f"frame {getattr(frame, 'index', '?')}"
    images = []
    for name in ("left", "right"):
        image = np.asarray(getattr(frame, name))
        if image.ndim != 2 or image.dtype != np.uint8:
            raise DatasetError(
                f"{where}: the {name} image must be 8-bit gray (H, W), got {image.dtype} {image.shape}"
            )
        images.append(np.ascontiguousarray(image))
    left, right = images
    if left.shape != right.shape:
        raise DatasetError(f"{where}: left {left.shape} and right {right.shape} image sizes differ")
    width, height = image_size_px
    if left.shape != (height, width):
        raise DatasetError(
            f"{where}: image is {left.shape[1]}×{left.shape[0]} px but the calibration is for "
            f"{width}×{height}; give the calibration of these images"
        )
    return left, right


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


@dataclass(frozen=True)
class DatasetExtras:
    """What a dataset may tell besides the protocol, with the defaults of one that tells nothing."""

    note: str = ""  # one line about what is used (e.g. "stereo images exist for 51 of 1101 frames")
    warnings: list[str] = field(default_factory=list)  # data problems that are not errors
    missing_frames: list[int] = field(default_factory=list)  # frame numbers skipped inside the range
    frames_without_timestamp: int = 0
    stride: int = 1  # the step between yielded frame numbers (a larger step is a hole in the data)

    @classmethod
    def of(cls, dataset: object) -> DatasetExtras:
        """The extras of any dataset: its attributes of these names, or the defaults."""
        default = cls()
        return cls(
            note=str(getattr(dataset, "note", default.note) or ""),
            warnings=list(getattr(dataset, "warnings", default.warnings)),
            missing_frames=[int(f) for f in getattr(dataset, "missing_frames", default.missing_frames)],
            frames_without_timestamp=int(getattr(dataset, "frames_without_timestamp", 0)),
            stride=int(getattr(dataset, "stride", 1) or 1),
        )


class StereoLoader(ABC):
    """The base of every registered loader (module doc). A subclass sets `name`, `calibration`,
    `frame_indices` and `timestamps_s` (and `_ground_truth`, poses of the yielded frames, when it has
    them) in its constructor, after `super().__init__(stride)`, and ends it with `self._finish_note()`."""

    KIND: ClassVar[str]
    """The loader's name in `LOADERS` and `--dataset-kind`."""
    TITLE: ClassVar[str]
    """What it reads, in messages ("KITTI odometry roots")."""
    LAYOUT: ClassVar[str]
    """Which path to give it, for the error when no loader recognises a path."""
    OPTIONS: ClassVar[tuple[str, ...]] = ("start", "stop", "stride")
    """The keywords the constructor takes besides root and sequence."""
    FLAGS: ClassVar[tuple[LoaderFlag, ...]] = ()
    """Those of `OPTIONS` the command line offers as flags (`LoaderFlag`); the first loader in `LOADERS`
    to declare a keyword gives its flag's metavar and help."""
    DEFAULT_SEQUENCE: ClassVar[str | None] = None
    """The sequence opened when none is named."""

    name: str
    calibration: StereoCalibration
    frame_indices: np.ndarray
    timestamps_s: np.ndarray

    def __init__(self, stride: int = 1) -> None:
        self.note = ""
        self.warnings: list[str] = []
        self.missing_frames: list[int] = []
        self.frames_without_timestamp = 0
        self.stride = int(stride)
        self._ground_truth: np.ndarray | None = None

    @staticmethod
    @abstractmethod
    def detect(path: Path) -> bool:
        """True when `path` has this loader's layout."""

    @abstractmethod
    def _frame(self, i: int) -> StereoFrame:
        """Read yielded frame `i` (already checked to be in range)."""

    def _finish_note(self) -> None:
        """`note` ends with the warnings, so that one line says everything odd about the data."""
        if self.warnings:
            self.note = "; ".join([self.note, *self.warnings] if self.note else self.warnings)

    def __len__(self) -> int:
        return len(self.frame_indices)

    def __getitem__(self, i: int) -> StereoFrame:
        n = len(self.frame_indices)
        if not -n <= i < n:
            raise IndexError(f"frame {i} out of range for a dataset of {n} frames")
        return self._frame(i)

    def __iter__(self) -> Iterator[StereoFrame]:
        for i in range(len(self)):
            yield self[i]

    def ground_truth(self) -> np.ndarray | None:
        """(len, 4, 4) `world_from_camera` of camera 0 for the yielded frames, or None when unknown."""
        return None if self._ground_truth is None else self._ground_truth.copy()
