"""KITTI odometry loader (the layout of docs/spec.md §9).

```
<root>/sequences/XX/image_0/NNNNNN.png   left, 8-bit gray, rectified
<root>/sequences/XX/image_1/NNNNNN.png   right
<root>/sequences/XX/image_2/NNNNNN.png   left colour camera (KITTI's colour download), rectified
<root>/sequences/XX/image_3/NNNNNN.png   right colour camera
<root>/sequences/XX/calib.txt            lines "P0: 12 numbers" … "P3: …" (row-major 3×4), optional "Tr: …"
<root>/sequences/XX/times.txt            one timestamp (s) per frame of the whole sequence
<root>/poses/XX.txt                      ground truth of camera 0, sequences 00–10 only (hippo_nav.io.poses)
```

Cameras (`cameras`): `gray` reads image_0/image_1 with P0/P1; `color` reads image_2/image_3 (converted to
gray) with P2/P3; None (the default) takes the gray pair where both of its folders exist, else the colour
pair — KITTI ships the two as separate downloads, and a user often has only one. The colour pair's calibration
is given in its left camera's frame (P2's translation moved into P3's, so `P0`/`P1` of the calibration are
the pair used), and its ground truth is camera 2's: camera 0's poses with camera 2's offset (about 6 cm to
the left, from P2) applied, `world` still camera 0 at frame 0.

Frames load lazily: constructing the dataset reads and checks calib.txt, times.txt, the ground truth (when
`poses/XX.txt` exists) and one image (for the image size), so a malformed file fails before any frame is
processed; each `__getitem__` reads one pair. With `available_only=True` and no `stop` the dataset yields
the frames (from `start` on) whose left and right images both exist — public copies often hold a prefix
of a sequence only — and says so in `.note`. An explicit `stop` asks for that range in full. Data problems
that are not errors are listed in `.warnings` (and `.note`): frames missing inside the range of available
ones (`missing_frames`), and images without a timestamp because times.txt is shorter than the image folder
(`frames_without_timestamp`).

`ground_truth()` returns the poses of the yielded frames as written in the file: `world` is camera 0 at
frame 0 of the sequence (not at the first yielded frame). Rebase with `inv(gt[0]) @ gt` if needed.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from hippo_nav.datasets.base import (
    LoaderFlag,
    StereoCalibration,
    StereoFrame,
    StereoLoader,
    check_calibration,
)
from hippo_nav.datasets.common import read_image_file
from hippo_nav.io.errors import MAX_SETTINGS_FILE_BYTES, DatasetError, file_error, read_text
from hippo_nav.io.poses import MAX_TIMESTAMP_S, check_regular_file, read_kitti_poses

# Rectified pairs share K; the public calibration files print K to 7 significant digits.
_INTRINSICS_TOLERANCE = 1e-6


CAMERAS = {"gray": (0, 1), "color": (2, 3)}
"""KITTI's stereo pairs: (left, right) camera numbers (image_N folders, PN calibration lines)."""


def read_calibration(
    calib_path: Path, image_size_px: tuple[int, int], cameras: str = "gray"
) -> StereoCalibration:
    """Parse a KITTI `calib.txt`; the pair's two lines are required (P0, P1 for `gray`, P2, P3 for `color`),
    the others optional, other keys (Tr) ignored. For `color` the calibration is put in camera 2's frame (module
    doc): its `P0`/`P1` are P2 and P3 less P2's translation."""
    check_regular_file(calib_path, "calibration file", "a KITTI sequence needs calib.txt")
    matrices: dict[str, np.ndarray] = {}
    for number, text in enumerate(
        read_text(calib_path, "calibration", MAX_SETTINGS_FILE_BYTES).splitlines(), start=1
    ):
        if not text.strip():
            continue
        key, sep, rest = text.partition(":")
        key = key.strip()
        if not sep:
            raise file_error(calib_path, f"expected 'KEY: numbers', got {text.strip()[:40]!r}", number)
        if key not in ("P0", "P1", "P2", "P3"):
            continue
        fields = rest.split()
        if len(fields) != 12:
            raise file_error(
                calib_path, f"{key} needs 12 numbers (a 3x4 matrix), found {len(fields)}", number
            )
        try:
            matrix = np.array([float(f) for f in fields], dtype=np.float64).reshape(3, 4)
        except ValueError as err:
            raise file_error(calib_path, f"{key}: not a number: {err}", number) from None
        if not np.all(np.isfinite(matrix)):
            bad = next(f for f, x in zip(fields, matrix.ravel()) if not np.isfinite(x))
            shown = bad if len(bad) <= 30 else f"{bad[:30]}… ({len(bad)} characters)"
            raise file_error(calib_path, f"{key} contains NaN or infinity: {shown}", number)
        if matrix[0, 0] <= 0 or matrix[1, 1] <= 0 or matrix[2, 2] != 1.0:
            raise file_error(
                calib_path,
                f"{key} is not a projection K[I|t]: fx = {matrix[0, 0]:g}, fy = {matrix[1, 1]:g}, P[2,2] = "
                f"{matrix[2, 2]:g} (need fx, fy > 0 and P[2,2] = 1)",
                number,
            )
        # K is upper triangular (so invertible, with fx, fy > 0): the colour pair's pose solves with P2's K.
        if matrix[1, 0] != 0 or matrix[2, 0] != 0 or matrix[2, 1] != 0:
            raise file_error(
                calib_path,
                f"{key} is not a projection K[I|t]: P[1,0], P[2,0] and P[2,1] must be 0 (they are "
                f"{matrix[1, 0]:g}, {matrix[2, 0]:g}, {matrix[2, 1]:g})",
                number,
            )
        if key in matrices:
            raise file_error(calib_path, f"a second {key} line; keep one", number)
        matrices[key] = matrix
    left_key, right_key = (f"P{n}" for n in CAMERAS[cameras])
    for required in (left_key, right_key):
        if required not in matrices:
            raise file_error(
                calib_path, f"no {required} line; {left_key} (left) and {right_key} (right) are required"
            )
    left, right = matrices[left_key], matrices[right_key]
    if np.abs(left[:, :3] - right[:, :3]).max() > _INTRINSICS_TOLERANCE * left[0, 0]:
        raise file_error(
            calib_path,
            f"{left_key} and {right_key} have different intrinsics: the images are not a rectified pair",
        )
    # In the left camera's frame: P = K[I|t] is linear in t, so the right camera's t less the left's.
    relative = right.copy()
    relative[:, 3] -= left[:, 3]
    # fx is checked for plausibility below (check_calibration); an absurd one (1e-300) must not overflow here.
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        baseline_m = -relative[0, 3] / relative[0, 0]
    if baseline_m <= 0:
        shown = f"{right_key}[0,3]" if left_key == "P0" else f"{right_key}[0,3] - {left_key}[0,3]"
        raise file_error(
            calib_path,
            f"{shown} = {relative[0, 3]:g} gives a baseline of {baseline_m:g} m; {shown} must be negative "
            "(right camera at +baseline along x)",
        )
    origin = left.copy()
    origin[:, 3] = 0.0
    calibration = StereoCalibration(origin, relative, matrices.get("P2"), matrices.get("P3"), image_size_px)
    return check_calibration(calibration, str(calib_path))


def camera0_from_camera(projection: np.ndarray) -> np.ndarray:
    """(4, 4) pose in camera 0's frame of the rectified camera whose projection is `projection` = K[I|t]
    (a KITTI PN line): it maps camera 0's points X to X + t, so the camera sits at −t."""
    out = np.eye(4)
    out[:3, 3] = -np.linalg.solve(projection[:, :3], projection[:, 3])
    return out


def read_times(times_path: Path) -> np.ndarray:
    """Timestamps (s) of every frame of the sequence, one per line, strictly increasing.

    A repeated timestamp is an error too: it would give a frame no time to move in, and the TUM files of
    the run could not be paired by timestamp (evo and this project's reader need increasing stamps)."""
    check_regular_file(times_path, "timestamps file", "a KITTI sequence needs times.txt")
    stamps: list[float] = []
    for number, text in enumerate(read_text(times_path, "timestamps file").splitlines(), start=1):
        if not text.strip():
            continue
        try:
            value = float(text)
        except ValueError:
            raise file_error(times_path, f"not a timestamp: {text.strip()[:40]!r}", number) from None
        if not np.isfinite(value):
            raise file_error(times_path, f"timestamp {value} is not finite", number)
        if abs(value) > MAX_TIMESTAMP_S:
            raise file_error(
                times_path,
                f"timestamp {value:g} is beyond ±{MAX_TIMESTAMP_S:g} s; times.txt holds seconds",
                number,
            )
        if stamps and value <= stamps[-1]:
            how = "repeats" if value == stamps[-1] else "goes back from"
            raise file_error(
                times_path,
                f"timestamp {value} {how} the previous one ({stamps[-1]}); timestamps must increase: "
                "fix or remove that line",
                number,
            )
        stamps.append(value)
    if not stamps:
        raise file_error(times_path, "holds no timestamps")
    return np.array(stamps)


def read_gray(path: Path) -> np.ndarray:
    """Load an 8-bit image as (H, W) uint8 gray; colour images are converted, other depths rejected."""
    image = read_image_file(path)
    if image.dtype != np.uint8:
        raise DatasetError(f"{path}: image has dtype {image.dtype}; KITTI images are 8-bit")
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    return image


class KittiOdometry(StereoLoader):
    """A KITTI odometry sequence as a `StereoDataset` (see the module doc for the layout and semantics)."""

    KIND = "kitti"
    TITLE = "KITTI odometry roots"
    LAYOUT = "for KITTI pass the folder that holds sequences/ and poses/"
    OPTIONS = ("start", "stop", "stride", "available_only", "cameras")
    FLAGS = (
        LoaderFlag(
            "cameras",
            "{gray,color}",
            "the stereo pair: gray (image_0, image_1) or color (image_2, image_3, read as gray) "
            "(default: gray where its folders exist, else color)",
        ),
    )
    DEFAULT_SEQUENCE = "00"

    def __init__(
        self,
        root: str | Path,
        sequence: str,
        start: int | None = None,
        stop: int | None = None,
        stride: int = 1,
        available_only: bool = True,
        cameras: str | None = None,
    ) -> None:
        super().__init__(stride)
        self.root = Path(root)
        self.sequence = str(sequence)
        self.name = f"kitti_{self.sequence}"
        if not (self.root / "sequences").is_dir():
            raise DatasetError(
                f"{self.root}: not a KITTI odometry root (no sequences/ folder); "
                "pass the folder that holds sequences/ and poses/"
            )
        self.sequence_dir = self.root / "sequences" / self.sequence
        if not self.sequence_dir.is_dir():
            present = sorted(p.name for p in (self.root / "sequences").iterdir() if p.is_dir())
            raise DatasetError(f"{self.sequence_dir}: sequence not found; present: {', '.join(present)}")
        if stride < 1:
            raise DatasetError(f"stride must be >= 1, got {stride}")
        self.cameras = self._choose_cameras(cameras)
        self._numbers = CAMERAS[self.cameras]

        all_times_s = read_times(self.sequence_dir / "times.txt")
        self.frame_indices = self._select_frames(len(all_times_s), start, stop, stride, available_only)
        self.timestamps_s = all_times_s[self.frame_indices]

        first = read_gray(self._image_path(0, int(self.frame_indices[0])))
        height, width = first.shape
        calib_path = self.sequence_dir / "calib.txt"
        self.calibration = read_calibration(calib_path, (width, height), self.cameras)
        self._poses_path = self.root / "poses" / f"{self.sequence}.txt"
        self._ground_truth = self._read_ground_truth(len(all_times_s))  # the whole file (every frame)
        if self.cameras == "color":
            assert self.calibration.P2 is not None  # the colour pair's calibration needs its P2 line
            if self._ground_truth is not None:
                self._ground_truth = self._ground_truth @ camera0_from_camera(self.calibration.P2)
            used = "the colour cameras (image_2, image_3, read as gray)"
            self.note = f"{self.note}; {used}" if self.note else f"sequence {self.sequence}: {used}"
        self._finish_note()

    def _choose_cameras(self, cameras: str | None) -> str:
        """The pair to read (module doc): the one asked for, whose folders must exist, else the first present."""
        if cameras is not None and cameras not in CAMERAS:
            raise DatasetError(
                f"cameras = {cameras!r}: use one of {', '.join(map(repr, CAMERAS))} (or None: either)"
            )
        present = {
            name: all((self.sequence_dir / f"image_{n}").is_dir() for n in numbers)
            for name, numbers in CAMERAS.items()
        }
        if cameras is not None and not present[cameras]:
            left, right = CAMERAS[cameras]
            raise DatasetError(
                f"{self.sequence_dir}: cameras = {cameras!r} needs image_{left} and image_{right}; present: "
                f"{', '.join(sorted(p.name for p in self.sequence_dir.glob('image_*'))) or 'no image folder'}"
            )
        chosen = cameras or next((name for name, here in present.items() if here), None)
        if chosen is None:
            missing = next(
                f"image_{n}" for n in CAMERAS["gray"] if not (self.sequence_dir / f"image_{n}").is_dir()
            )
            raise DatasetError(
                f"{self.sequence_dir / missing}: folder missing; a stereo sequence needs image_0 and image_1 (KITTI's "
                "gray download) or image_2 and image_3 (its colour download)"
            )
        return chosen

    def _image_path(self, camera: int, frame: int) -> Path:
        """The image of the pair's left (`camera` 0) or right (1) camera."""
        return self.sequence_dir / f"image_{self._numbers[camera]}" / f"{frame:06d}.png"

    def _image_numbers(self, camera: int) -> set[int]:
        """Frame numbers of the pair's left (0) or right (1) images (one directory listing, not a stat per
        frame)."""
        numbers = set()
        for entry in os.scandir(self.sequence_dir / f"image_{self._numbers[camera]}"):
            stem, _, suffix = entry.name.partition(".")
            if suffix == "png" and stem.isdigit():
                numbers.add(int(stem))
        return numbers

    def _select_frames(
        self, n_frames: int, start: int | None, stop: int | None, stride: int, available_only: bool
    ) -> np.ndarray:
        times = self.sequence_dir / "times.txt"
        lo = 0 if start is None else start
        hi = n_frames if stop is None else stop
        if not 0 <= lo < hi <= n_frames:
            raise DatasetError(
                f"frame range [{lo}, {hi}) is empty or outside the sequence: {times} lists {n_frames} frames"
            )
        wanted = np.arange(lo, hi, stride, dtype=np.int64)
        left, right = self._image_numbers(0), self._image_numbers(1)
        beyond = sum(1 for f in left if f >= n_frames)
        if beyond:
            self.frames_without_timestamp = beyond
            self.warnings.append(
                f"{beyond} image(s) in image_{self._numbers[0]} have no timestamp ({times} lists {n_frames} frames): "
                "they are not used; complete times.txt to use them"
            )
        if stop is not None or not available_only:
            for frame in wanted:
                for camera, numbers in ((0, left), (1, right)):
                    if int(frame) not in numbers:
                        raise DatasetError(
                            f"{self._image_path(camera, int(frame))}: image missing for requested frame "
                            f"{frame}; choose a range whose images exist"
                        )
            return wanted
        present = np.array([int(f) in left and int(f) in right for f in wanted], dtype=bool)
        if not present.any():
            raise DatasetError(
                f"{self.sequence_dir}: no frame from {lo} on has both image_{self._numbers[0]} and "
                f"image_{self._numbers[1]} images; this loader needs stereo"
            )
        frames = wanted[present]
        inside = wanted[(wanted > frames[0]) & (wanted < frames[-1])]
        self.missing_frames = [int(f) for f in inside if not (int(f) in left and int(f) in right)]
        if self.missing_frames:
            shown = ", ".join(str(f) for f in self.missing_frames[:5])
            more = f" and {len(self.missing_frames) - 5} more" if len(self.missing_frames) > 5 else ""
            self.warnings.append(
                f"{len(self.missing_frames)} frame(s) inside {frames[0]}..{frames[-1]} lack a stereo image "
                f"and are skipped ({shown}{more}); the motion across them is measured as one step"
            )
        if len(frames) < len(wanted):
            self.note = (
                f"sequence {self.sequence}: stereo images exist for {len(frames)} of {len(wanted)} frames "
                f"({frames[0]}..{frames[-1]}); using only those"
            )
        return frames

    def _read_ground_truth(self, n_frames: int) -> np.ndarray | None:
        """The whole ground-truth file, checked now (None when the sequence has none)."""
        if not self._poses_path.is_file():
            return None
        poses = read_kitti_poses(self._poses_path)
        if len(poses) != n_frames:
            raise DatasetError(
                f"{self._poses_path}: holds {len(poses)} poses but {self.sequence_dir / 'times.txt'} lists "
                f"{n_frames} frames; the pose file does not match the sequence (one line per frame)"
            )
        return poses

    def _frame(self, i: int) -> StereoFrame:
        frame = int(self.frame_indices[i])
        left_path, right_path = self._image_path(0, frame), self._image_path(1, frame)
        left, right = read_gray(left_path), read_gray(right_path)
        if left.shape != right.shape:
            raise DatasetError(
                f"{right_path}: size {right.shape[::-1]} differs from the left image {left_path} "
                f"{left.shape[::-1]}; stereo pairs must have equal sizes"
            )
        if (left.shape[1], left.shape[0]) != self.calibration.image_size_px:
            raise DatasetError(
                f"{left_path}: size {left.shape[::-1]} differs from the sequence's first image "
                f"{self.calibration.image_size_px}"
            )
        return StereoFrame(frame, float(self.timestamps_s[i]), left, right)

    def ground_truth(self) -> np.ndarray | None:
        if self._ground_truth is None:
            return None
        return self._ground_truth[self.frame_indices]

    @staticmethod
    def detect(path: Path) -> bool:
        """True when `path` looks like a KITTI odometry root."""
        return (path / "sequences").is_dir()

    def __repr__(self) -> str:
        return f"KittiOdometry(root={str(self.root)!r}, sequence={self.sequence!r}, frames={len(self)})"
