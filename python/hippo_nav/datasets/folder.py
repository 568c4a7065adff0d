"""A plain folder of rectified left/right image pairs and a small calibration file.

```
<folder>/left/*.png            left images (camera 0), 8-bit gray or colour; any of .png .jpg .pgm …
<folder>/right/*.png           right images, as many as left; pairs are matched in name order
<folder>/calibration.yaml      fx, fy, cx, cy (pixels), baseline_m (metres, > 0); optional width, height
<folder>/times.txt             optional: one timestamp (s) per pair, increasing; else frame_rate_hz (10 Hz)
<folder>/ground_truth.tum      optional: TUM lines "t x y z qx qy qz qw" of camera 0 (world_from_camera),
                               matched to the image times (interpolated between samples)
```

The images must already be rectified (row-aligned, same K): the calibration is P0 = K[I|0] and
P1 = K[I|(−baseline_m, 0, 0)]. Names sort naturally (`2.png` before `10.png`). Frame numbers are positions
in that order. `baseline` is accepted for `baseline_m`. Problems in these files are errors raised when the
folder is opened: unequal counts, missing keys, sizes that differ from width/height, a times.txt with
another count, an unreadable TUM line.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from hippo_nav.datasets.base import StereoFrame, StereoLoader
from hippo_nav.datasets.common import (
    IMAGE_SUFFIXES,
    FrameSelection,
    check_increasing,
    check_time_unit,
    ground_truth_at_frames,
    natural_key,
    read_image,
    read_yaml,
    rectified_calibration,
    yaml_number,
)
from hippo_nav.io.errors import DatasetError, file_error, read_text
from hippo_nav.io.poses import MAX_TIMESTAMP_S, check_regular_file, read_tum

CALIBRATION_FILE = "calibration.yaml"
TIMES_FILE = "times.txt"
GROUND_TRUTH_FILE = "ground_truth.tum"


CALIBRATION_KEYS = ("fx", "fy", "cx", "cy", "baseline_m", "baseline", "width", "height")


def list_images(folder: Path) -> list[Path]:
    """The image files of `folder` in natural name order."""
    if not folder.is_dir():
        raise DatasetError(f"{folder}: folder missing; a stereo folder needs left/ and right/ image folders")
    images = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
    if not images:
        raise DatasetError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)})")
    return sorted(images, key=lambda p: natural_key(p.name))


def check_pairs_by_number(left: list[Path], right: list[Path]) -> None:
    """Pairs are matched by position in name order: an image missing on each side keeps the counts equal and
    pairs every frame between them with another moment's image, a stereo pair with a wrong depth. Where the
    names' last numbers agree on a first pair and then stop agreeing, that happened (names numbered by each
    camera's own clock may differ throughout, and are not judged)."""
    numbers = [(_last_number(a.name), _last_number(b.name)) for a, b in zip(left, right)]
    if not any(a is not None and a == b for a, b in numbers):
        return
    for k, (a, b) in enumerate(numbers):
        if a != b:
            lacks = "right/" if a is not None and b is not None and a < b else "left/"
            raise DatasetError(
                f"{left[k].parent.parent}: the images are paired in name order, and image {k} of each is "
                f"left/{left[k].name} but right/{right[k].name}, where the pairs before agreed: {lacks} lacks "
                "an image there; give every frame both images (or remove the unpaired one)"
            )


def _last_number(name: str) -> int | None:
    runs = re.findall(r"\d+", name)
    return int(runs[-1]) if runs else None


def read_times_file(path: Path, count: int) -> np.ndarray:
    check_regular_file(path, "timestamps file", "one timestamp (s) per image pair")
    stamps: list[float] = []
    for number, text in enumerate(read_text(path, "timestamps file").splitlines(), start=1):
        if not text.strip() or text.lstrip().startswith("#"):
            continue
        try:
            value = float(text.split()[0])
        except ValueError:
            raise file_error(path, f"not a timestamp: {text.strip()[:40]!r}", number) from None
        if not np.isfinite(value):
            raise file_error(path, f"timestamp {value} is not finite", number)
        if abs(value) > MAX_TIMESTAMP_S:
            raise file_error(
                path, f"timestamp {value:g} is beyond ±{MAX_TIMESTAMP_S:g} s; times.txt holds seconds", number
            )
        if stamps and value <= stamps[-1]:
            raise file_error(path, f"timestamp {value} does not increase (previous {stamps[-1]})", number)
        stamps.append(value)
    if len(stamps) != count:
        raise file_error(path, f"holds {len(stamps)} timestamps for {count} image pairs; give one per pair")
    return np.array(stamps)


class StereoFolder(StereoLoader):
    """A folder of rectified stereo pairs as a `StereoDataset` (layout and semantics: module doc)."""

    KIND = "folder"
    TITLE = "stereo folders"
    LAYOUT = "for a stereo folder one with left/, right/ and calibration.yaml"
    OPTIONS = ("start", "stop", "stride", "frame_rate_hz", "trim_to_ground_truth")

    def __init__(
        self,
        root: str | Path,
        sequence: str | None = None,
        start: int | None = None,
        stop: int | None = None,
        stride: int = 1,
        frame_rate_hz: float = 10.0,
        trim_to_ground_truth: bool = True,
    ) -> None:
        super().__init__(stride)
        self.root = Path(root) / sequence if sequence else Path(root)
        if not self.root.is_dir():
            raise DatasetError(f"{self.root}: folder not found")
        self.name = self.root.name
        self._left = list_images(self.root / "left")
        self._right = list_images(self.root / "right")
        if len(self._left) != len(self._right):
            raise DatasetError(
                f"{self.root}: left/ holds {len(self._left)} images but right/ holds {len(self._right)}; "
                "every left image needs its right image (pairs are matched in name order)"
            )
        check_pairs_by_number(self._left, self._right)
        n = len(self._left)

        calib_path = self.root / CALIBRATION_FILE
        calib = read_yaml(calib_path, "calibration (fx, fy, cx, cy, baseline_m)")
        # The images must be rectified already: a distortion (k1, D, …) given here would be dropped without a
        # word, and a typo (`widht`) leave its check undone.
        unknown = sorted(str(k) for k in set(calib) - set(CALIBRATION_KEYS))
        if unknown:
            raise file_error(
                calib_path,
                f"unknown key(s) {', '.join(unknown)}; known: {', '.join(CALIBRATION_KEYS)} (the images must be "
                "rectified, so no distortion is taken)",
            )
        if "baseline" in calib and "baseline_m" in calib:
            raise file_error(calib_path, "gives both baseline and baseline_m; give baseline_m only")
        if "baseline_m" not in calib and "baseline" in calib:
            calib["baseline_m"] = calib["baseline"]
        fx, fy = (yaml_number(calib, k, calib_path, positive=True) for k in ("fx", "fy"))
        cx, cy = (yaml_number(calib, k, calib_path) for k in ("cx", "cy"))
        baseline_m = yaml_number(calib, "baseline_m", calib_path, positive=True)
        first = read_image(self._left[0])
        size = (first.shape[1], first.shape[0])
        for key, actual in (("width", size[0]), ("height", size[1])):
            if key in calib and yaml_number(calib, key, calib_path) != actual:
                raise file_error(
                    calib_path,
                    f"{key}: {calib[key]} but {self._left[0].name} is {size[0]}x{size[1]} px; "
                    "the calibration is for other images",
                )
        self.calibration = rectified_calibration(fx, fy, cx, cy, baseline_m, size, str(calib_path))

        times_path = self.root / TIMES_FILE
        if times_path.is_file():
            all_times_s = read_times_file(times_path, n)
        else:
            if not frame_rate_hz > 0:
                raise DatasetError(f"frame_rate_hz must be positive, got {frame_rate_hz}")
            all_times_s = np.arange(n) / float(frame_rate_hz)
        selection = FrameSelection(np.arange(n), n, start, stop, stride, f"{self.root / 'left'}")
        frames = selection.frames
        times_s = all_times_s[frames]
        check_time_unit(self.name, frames, times_s)  # before trimming to a ground truth in another unit

        gt_path = self.root / GROUND_TRUTH_FILE
        if gt_path.is_file():
            gt_s, gt_poses = read_tum(gt_path)
            check_increasing(gt_s, str(gt_path))
            gt, keep, notes = ground_truth_at_frames(
                gt_s, gt_poses, times_s, trim_to_ground_truth, str(gt_path)
            )
            self.warnings += notes
            frames, times_s, self._ground_truth = frames[keep], times_s[keep], gt
        self.frame_indices = frames
        self.timestamps_s = times_s
        self._finish_note()

    def _frame(self, i: int) -> StereoFrame:
        frame = int(self.frame_indices[i])
        left_path, right_path = self._left[frame], self._right[frame]
        left, right = read_image(left_path), read_image(right_path)
        for path, image in ((left_path, left), (right_path, right)):
            if (image.shape[1], image.shape[0]) != self.calibration.image_size_px:
                raise DatasetError(
                    f"{path}: size {image.shape[::-1]} differs from the first left image "
                    f"{self.calibration.image_size_px}; all images must have one size"
                )
        return StereoFrame(frame, float(self.timestamps_s[i]), left, right)

    @staticmethod
    def detect(path: Path) -> bool:
        """True when `path` holds left/, right/ and calibration.yaml."""
        return (path / "left").is_dir() and (path / "right").is_dir() and (path / CALIBRATION_FILE).is_file()

    def __repr__(self) -> str:
        return f"StereoFolder(root={str(self.root)!r}, frames={len(self)})"
