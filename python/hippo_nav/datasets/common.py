"""What the EuRoC, ROS bag and plain-folder loaders share: YAML calibration files, frame selection,
stereo pairing by timestamp, ground truth at the image timestamps, and 8-bit gray images.

Frame numbers: a loader numbers the images of its left camera 0, 1, 2, … in time order; `start`, `stop`
and `stride` select from those numbers exactly as for KITTI (`range(start, stop, stride)`), and a left
image without a right partner is skipped and listed in `missing_frames` (the pipeline then measures the
motion across the hole as one step and flags it).

Ground truth at an image time `t` is interpolated between the two samples around it: positions linearly,
rotations by slerp. Frames before the first or after the last ground-truth sample have none; by default
(`trim_to_ground_truth=True`) such frames at the ends are not yielded (EuRoC's ground truth starts a
moment after the cameras), and `.note` says how many were left out.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from hippo_nav.datasets.base import StereoCalibration
from hippo_nav.io.errors import DatasetError, file_error, read_text
from hippo_nav.io.poses import matrix_from_quaternion, quaternion_from_matrix

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".ppm", ".bmp", ".tif", ".tiff")

# Rectified pairs share K; files print it with 6–9 significant digits.
INTRINSICS_TOLERANCE = 1e-6


def read_yaml(path: Path, what: str) -> dict[str, Any]:
    """A YAML mapping; OpenCV's `%YAML:1.0` first line (EuRoC's sensor.yaml files have it) is skipped."""
    import yaml

    if not path.is_file():
        raise DatasetError(f"{path}: {what} not found")
    text = read_text(path, what)
    skipped = 0
    if text.startswith("%YAML:"):
        text, skipped = (text.split("\n", 1)[1] if "\n" in text else ""), 1
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        line = None if mark is None else mark.line + 1 + skipped
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise file_error(path, f"not valid YAML ({problem})", line) from None
    if not isinstance(data, dict):
        raise file_error(path, f"expected a YAML mapping of keys ({what}), got {type(data).__name__}")
    return data


def yaml_number(data: dict[str, Any], key: str, path: Path, *, positive: bool = False) -> float:
    """`data[key]` as a finite float (positive if asked); the error names the file and the key."""
    if key not in data:
        raise file_error(path, f"no '{key}' key")
    value = data[key]
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise file_error(path, f"'{key}: {value}' is not a number") from None
    if not np.isfinite(number) or (positive and number <= 0):
        raise file_error(path, f"'{key}: {value}' must be a {'positive ' if positive else ''}finite number")
    return number


def yaml_numbers(data: dict[str, Any], key: str, path: Path, count: int | None, what: str) -> np.ndarray:
    """`data[key]` as a flat float64 array of `count` finite numbers (any length when None)."""
    if key not in data:
        raise file_error(path, f"no '{key}' key ({what})")
    value = data[key]
    if isinstance(value, dict) and "data" in value:  # OpenCV/Kalibr matrices: {rows, cols, data}
        value = value["data"]
    try:
        array = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise file_error(path, f"'{key}' must be a list of numbers ({what})") from None
    if count is not None and array.size != count:
        raise file_error(path, f"'{key}' needs {count} numbers ({what}), found {array.size}")
    if not np.all(np.isfinite(array)):
        raise file_error(path, f"'{key}' contains NaN or infinity")
    return array


def rectified_calibration(
    fx: float, fy: float, cx: float, cy: float, baseline_m: float, image_size_px: tuple[int, int]
) -> StereoCalibration:
    """The calibration of an already rectified pair: P0 = K[I|0], P1 = K[I|(−b, 0, 0)]."""
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    p0 = np.hstack([K, np.zeros((3, 1))])
    p1 = p0.copy()
    p1[0, 3] = -fx * baseline_m
    return StereoCalibration(p0, p1, None, None, image_size_px)


def natural_key(name: str) -> list[Any]:
    """Sort key that orders `img2.png` before `img10.png` (digit runs compare as numbers)."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def to_gray(image: np.ndarray, where: str) -> np.ndarray:
    """(H, W) uint8 gray of an 8-bit gray, BGR or BGRA image; other depths are an error naming `where`."""
    if image.dtype != np.uint8:
        raise DatasetError(f"{where}: image has dtype {image.dtype}; this loader reads 8-bit images only")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    if image.ndim != 2:
        raise DatasetError(f"{where}: image has shape {image.shape}; expected (H, W) or (H, W, 3)")
    return np.ascontiguousarray(image)


def read_image(path: Path) -> np.ndarray:
    """Load an 8-bit image file as (H, W) uint8 gray."""
    if not path.is_file():
        raise DatasetError(f"{path}: image not found")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise DatasetError(f"{path}: image is corrupt or not a format OpenCV can read; replace the file")
    return to_gray(image, str(path))


def check_increasing(stamps_s: np.ndarray, what: str) -> None:
    """Timestamps must increase strictly (the pipeline's dt, and TUM files paired by time)."""
    steps = np.diff(stamps_s)
    if steps.size and not np.all(steps > 0):
        k = int(np.flatnonzero(steps <= 0)[0])
        how = "repeats" if steps[k] == 0 else "goes back from"
        raise DatasetError(
            f"{what}: timestamp {stamps_s[k + 1]!r} (entry {k + 2}) {how} the previous one; "
            "timestamps must increase"
        )


def pair_by_time(
    left_s: np.ndarray, right_s: np.ndarray, tolerance_s: float | None
) -> tuple[np.ndarray, np.ndarray, float]:
    """Pair each left timestamp with the nearest right one within `tolerance_s`, one to one.

    `tolerance_s` None: a quarter of the median left frame interval (hardware-triggered cameras share
    stamps; software-synchronised ones differ by far less than a frame). Returns (left indices, right
    indices, tolerance used), both sorted by time."""
    left_s, right_s = np.asarray(left_s, dtype=np.float64), np.asarray(right_s, dtype=np.float64)
    if tolerance_s is None:
        interval = float(np.median(np.diff(left_s))) if len(left_s) > 1 else 1.0
        tolerance_s = 0.25 * interval
    if len(left_s) == 0 or len(right_s) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), tolerance_s
    slot = np.clip(np.searchsorted(right_s, left_s), 1, len(right_s) - 1) if len(right_s) > 1 else None
    if slot is None:
        nearest = np.zeros(len(left_s), dtype=np.int64)
    else:
        before, after = slot - 1, slot
        nearest = np.where(np.abs(right_s[before] - left_s) <= np.abs(right_s[after] - left_s), before, after)
    gap = np.abs(right_s[nearest] - left_s)
    # Greedy by gap: a right image claimed by a closer left image is not reused.
    taken: set[int] = set()
    pairs: list[tuple[int, int]] = []
    for i in np.argsort(gap, kind="stable"):
        j = int(nearest[i])
        if gap[i] <= tolerance_s and j not in taken:
            taken.add(j)
            pairs.append((int(i), j))
    pairs.sort()
    left_idx = np.array([p[0] for p in pairs], dtype=np.int64)
    right_idx = np.array([p[1] for p in pairs], dtype=np.int64)
    return left_idx, right_idx, tolerance_s


class FrameSelection:
    """`range(start, stop, stride)` of the left camera's frame numbers, minus those without a stereo pair.

    `frames` are the frame numbers yielded; `missing_frames` those inside the yielded range skipped for
    lack of a partner; `warnings` says so in a line."""

    def __init__(
        self,
        paired: np.ndarray,
        n_frames: int,
        start: int | None,
        stop: int | None,
        stride: int,
        where: str,
    ) -> None:
        if stride < 1:
            raise DatasetError(f"stride must be >= 1, got {stride}")
        lo = 0 if start is None else int(start)
        hi = n_frames if stop is None else int(stop)
        if not 0 <= lo < hi <= n_frames:
            raise DatasetError(
                f"frame range [{lo}, {hi}) is empty or outside the sequence: {where} has {n_frames} frames"
            )
        wanted = np.arange(lo, hi, stride, dtype=np.int64)
        have = np.isin(wanted, paired)
        if not have.any():
            raise DatasetError(f"{where}: no frame in [{lo}, {hi}) has both a left and a right image")
        self.frames = wanted[have]
        inside = wanted[(wanted > self.frames[0]) & (wanted < self.frames[-1]) & ~have]
        self.missing_frames = [int(f) for f in inside]
        self.warnings: list[str] = []
        if self.missing_frames:
            shown = ", ".join(str(f) for f in self.missing_frames[:5])
            more = f" and {len(self.missing_frames) - 5} more" if len(self.missing_frames) > 5 else ""
            self.warnings.append(
                f"{len(self.missing_frames)} left image(s) inside frames {self.frames[0]}..{self.frames[-1]} "
                f"have no right image at their time and are skipped ({shown}{more})"
            )


def _slerp(q0: np.ndarray, q1: np.ndarray, u: float) -> np.ndarray:
    if np.dot(q0, q1) < 0:
        q1 = -q1  # the short way round
    dot = float(np.clip(np.dot(q0, q1), -1.0, 1.0))
    if dot > 0.9995:
        q = q0 + u * (q1 - q0)
        return q / np.linalg.norm(q)
    angle = np.arccos(dot)
    return (np.sin((1 - u) * angle) * q0 + np.sin(u * angle) * q1) / np.sin(angle)


def interpolate_poses(
    stamps_s: np.ndarray, poses: np.ndarray, query_s: np.ndarray, tolerance_s: float = 1e-6
) -> tuple[np.ndarray, np.ndarray]:
    """Poses at `query_s`: (len(query), 4, 4) and a mask of the queries inside the samples' time span.

    Positions are interpolated linearly, rotations by slerp, between the samples around each query; a
    query within `tolerance_s` of a sample takes that sample exactly. Outside the span: NaN, mask False."""
    stamps_s = np.asarray(stamps_s, dtype=np.float64)
    out = np.full((len(query_s), 4, 4), np.nan)
    covered = np.zeros(len(query_s), dtype=bool)
    if len(stamps_s) == 0:
        return out, covered
    quaternions = np.array([quaternion_from_matrix(p[:3, :3]) for p in poses])
    for k, t in enumerate(np.asarray(query_s, dtype=np.float64)):
        j = int(np.searchsorted(stamps_s, t))
        if j < len(stamps_s) and abs(stamps_s[j] - t) <= tolerance_s:
            out[k], covered[k] = poses[j], True
        elif j > 0 and abs(stamps_s[j - 1] - t) <= tolerance_s:
            out[k], covered[k] = poses[j - 1], True
        elif 0 < j < len(stamps_s):
            u = (t - stamps_s[j - 1]) / (stamps_s[j] - stamps_s[j - 1])
            pose = np.eye(4)
            pose[:3, :3] = matrix_from_quaternion(_slerp(quaternions[j - 1], quaternions[j], u))
            pose[:3, 3] = (1 - u) * poses[j - 1, :3, 3] + u * poses[j, :3, 3]
            out[k], covered[k] = pose, True
    return out, covered


def ground_truth_at_frames(
    stamps_s: np.ndarray,
    poses: np.ndarray,
    frame_times_s: np.ndarray,
    trim: bool,
    where: str,
) -> tuple[np.ndarray | None, np.ndarray, list[str]]:
    """Ground truth of the selected frames: (poses or None, mask of frames to keep, notes).

    With `trim`, frames before/after the ground truth's span are dropped (the mask); without it, or when
    the ground truth covers none of the frames, every frame is kept and the ground truth is None."""
    at_frames, covered = interpolate_poses(stamps_s, poses, frame_times_s)
    keep = np.ones(len(frame_times_s), dtype=bool)
    if covered.all():
        return at_frames, keep, []
    span = f"{stamps_s[0]:.6f}..{stamps_s[-1]:.6f} s" if len(stamps_s) else "empty"
    if not covered.any():
        return None, keep, [f"{where}: its time span ({span}) holds none of the image times; no ground truth"]
    if not trim:
        note = (
            f"{where}: covers {int(covered.sum())} of {len(covered)} frames ({span}); no ground truth is "
            "given (open with trim_to_ground_truth=True to use only the frames it covers)"
        )
        return None, keep, [note]
    first, last = np.flatnonzero(covered)[[0, -1]]
    keep[:] = False
    keep[first : last + 1] = True
    # Inside the span every frame is covered (interpolation), so the kept frames all have a pose.
    dropped = len(covered) - int(keep.sum())
    note = f"{dropped} frame(s) outside the ground truth's time span ({span}) are left out"
    return at_frames[keep], keep, [note]
