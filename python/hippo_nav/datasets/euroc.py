"""EuRoC MAV / ASL stereo loader: raw images of cam0 (left) and cam1 (right), rectified on the fly.

```
<sequence>/mav0/cam0/data.csv        "#timestamp [ns],filename", one image a line
<sequence>/mav0/cam0/data/<filename> 8-bit gray, distorted
<sequence>/mav0/cam0/sensor.yaml     intrinsics [fu, fv, cu, cv], distortion_model (radial-tangential or
                                     equidistant), distortion_coefficients, T_BS (4×4 body_from_sensor),
                                     resolution [w, h]
<sequence>/mav0/cam1/...             the same for the right camera
<sequence>/mav0/state_groundtruth_estimate0/data.csv   optional: timestamp [ns], p_RS_R xyz [m],
                                     q_RS wxyz, … (the pose of the body S in the world R)
```

`root` may be the sequence folder (holding `mav0/`), `mav0/` itself, or a folder of sequences with
`sequence` naming one. Left and right images are paired by timestamp (EuRoC triggers both cameras
together; a frame one camera dropped is skipped and reported). Frame numbers are the rows of
cam0/data.csv.

Rectification (`hippo_nav.datasets.rectify`): the pose of cam1 in cam0 is `T_BS0⁻¹ T_BS1`; the
rectified calibration is P0/P1 of `cv2.stereoRectify` (alpha 0, zero disparity), the maps are computed
once. Ground truth: the body pose `world_from_body` at each image time (interpolated, 200 Hz samples)
becomes the rectified camera 0's pose `world_from_body · T_BS0 · [R0ᵀ | 0]`. The world frame is EuRoC's
(gravity along −z); the pipeline rebases to the first frame. EuRoC's ground truth starts a moment after the
cameras: frames outside its span are left out (`trim_to_ground_truth`, see `hippo_nav.datasets.common`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hippo_nav.datasets.base import StereoFrame, StereoLoader, check_intrinsics
from hippo_nav.datasets.common import (
    FrameSelection,
    check_increasing,
    check_time_unit,
    ground_truth_at_frames,
    pair_by_time,
    read_image,
    read_yaml,
    yaml_numbers,
)
from hippo_nav.datasets.rectify import StereoRectifier, distortion_kind, rectify_rig
from hippo_nav.io.errors import DatasetError, file_error, read_text
from hippo_nav.io.poses import MAX_COORDINATE_M, check_regular_file, matrix_from_quaternion

_INT64 = (-(2**63), 2**63 - 1)
"""The timestamps (ns) an image list may hold: NumPy keeps them as int64."""


def find_mav0(path: Path) -> Path | None:
    """The `mav0` folder of an ASL sequence at `path` (the sequence folder or mav0 itself), or None."""
    if (path / "mav0" / "cam0").is_dir():
        return path / "mav0"
    if (path / "cam0").is_dir() and (path / "cam1").is_dir():
        return path
    return None


class CameraFiles:
    """One ASL camera folder: its images (timestamps ns, paths) and its sensor.yaml."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        if not folder.is_dir():
            raise DatasetError(f"{folder}: camera folder missing; a stereo ASL sequence needs cam0 and cam1")
        self.stamps_ns, self.files = self._read_list(folder / "data.csv")
        sensor = folder / "sensor.yaml"
        data = read_yaml(sensor, "camera calibration (sensor.yaml)")
        # Names must be text: anything else (a list, or an alias of a huge one) is refused before str() of it.
        for key in ("camera_model", "distortion_model"):
            if key in data and not isinstance(data[key], str):
                raise file_error(sensor, f"'{key}' must be a name (text), not a {type(data[key]).__name__}")
        if str(data.get("camera_model", "pinhole")).lower() != "pinhole":
            raise file_error(
                sensor, f"camera_model {data['camera_model'][:40]!r} is not supported; use pinhole"
            )
        fu, fv, cu, cv = yaml_numbers(data, "intrinsics", sensor, 4, "[fu, fv, cu, cv]")
        self.K = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
        self.model = str(data.get("distortion_model", "radial-tangential"))
        distortion_kind(self.model, str(sensor))
        self.D = (
            yaml_numbers(data, "distortion_coefficients", sensor, None, "k1, k2, p1, p2")
            if "distortion_coefficients" in data
            else np.zeros(4)
        )
        self.body_from_sensor = yaml_numbers(data, "T_BS", sensor, 16, "4x4 body_from_sensor").reshape(4, 4)
        if np.abs(self.body_from_sensor[3] - [0, 0, 0, 1]).max() > 1e-9:
            raise file_error(sensor, "T_BS's last row must be [0, 0, 0, 1]")
        # The rig's geometry inverts T_BS: its 3x3 block must be a rotation, its translation metres.
        rotation = self.body_from_sensor[:3, :3]
        if np.abs(rotation).max() > 1.001 or np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-3:
            raise file_error(sensor, "T_BS's upper-left 3x3 block is not a rotation (RᵀR = I)")
        if abs(np.linalg.det(rotation) - 1.0) > 1e-3:
            raise file_error(sensor, "T_BS's upper-left 3x3 block is a reflection (det -1), not a rotation")
        if np.abs(self.body_from_sensor[:3, 3]).max() > MAX_COORDINATE_M:
            raise file_error(sensor, "T_BS's translation is not in metres (beyond 1e9)")
        width, height = yaml_numbers(data, "resolution", sensor, 2, "[width, height]")
        if not (width.is_integer() and height.is_integer() and 1 <= width <= 2**16 and 1 <= height <= 2**16):
            raise file_error(
                sensor, f"resolution [{width:g}, {height:g}] must be whole pixels, 1 to 65536 a side"
            )
        self.image_size_px = (int(width), int(height))
        check_intrinsics(fu, fv, cu, cv, self.image_size_px, str(sensor))
        self.sensor_path = sensor

    @staticmethod
    def _read_list(path: Path) -> tuple[np.ndarray, list[str]]:
        check_regular_file(path, "image list", "an ASL camera folder has data.csv")
        stamps: list[int] = []
        files: list[str] = []
        for number, text in enumerate(read_text(path, "CSV file").splitlines(), start=1):
            line = text.strip()
            if not line or line.startswith("#"):
                continue
            fields = [f.strip() for f in line.split(",")]
            if len(fields) != 2:
                raise file_error(path, f"expected 'timestamp_ns,filename', got {line[:40]!r}", number)
            try:
                stamp = int(fields[0])
            except ValueError:
                raise file_error(
                    path, f"timestamp {fields[0][:30]!r} is not an integer (ns)", number
                ) from None
            if not _INT64[0] <= stamp <= _INT64[1]:
                raise file_error(
                    path, f"timestamp {fields[0][:30]!r} is beyond int64; timestamps are nanoseconds", number
                )
            if stamps and stamp <= stamps[-1]:
                raise file_error(path, f"timestamp {stamp} does not increase; sort the list by time", number)
            stamps.append(stamp)
            files.append(fields[1])
        if not stamps:
            raise file_error(path, "lists no images")
        return np.array(stamps, dtype=np.int64), files

    def image_path(self, row: int) -> Path:
        return self.folder / "data" / self.files[row]


def read_ground_truth(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """EuRoC `state_groundtruth_estimate0/data.csv`: (timestamps s, world_from_body (N, 4, 4))."""
    stamps: list[float] = []
    poses: list[np.ndarray] = []
    for number, text in enumerate(read_text(path, "CSV file").splitlines(), start=1):
        line = text.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.split(",")
        if len(fields) < 8:
            raise file_error(
                path, f"expected timestamp, p xyz, q wxyz (8+ columns), found {len(fields)}", number
            )
        try:
            stamp_ns = int(fields[0])
            values = np.array([float(f) for f in fields[1:8]])
        except ValueError:
            raise file_error(path, f"not a number in {line[:60]!r}", number) from None
        quaternion_wxyz = values[3:]
        if not np.isfinite(values).all():
            raise file_error(path, f"NaN or infinity in {line[:60]!r}", number)
        if np.abs(values[:3]).max() > MAX_COORDINATE_M:
            raise file_error(path, f"a position beyond {MAX_COORDINATE_M:g} m; positions are metres", number)
        # A component beyond 1 is no unit quaternion; checked first, as the norm of 1e200s overflows.
        big = float(np.abs(quaternion_wxyz).max())
        norm = float(np.linalg.norm(quaternion_wxyz)) if big <= 2.0 else big
        if abs(norm - 1) > 1e-3:
            raise file_error(
                path, f"the quaternion (w x y z) has norm {norm:.4g}; it must be a unit quaternion", number
            )
        if stamps and stamp_ns * 1e-9 <= stamps[-1]:
            raise file_error(path, f"timestamp {stamp_ns} does not increase", number)
        pose = np.eye(4)
        pose[:3, :3] = matrix_from_quaternion(np.roll(quaternion_wxyz, -1))
        pose[:3, 3] = values[:3]
        stamps.append(stamp_ns * 1e-9)
        poses.append(pose)
    if not stamps:
        raise file_error(path, "holds no poses")
    return np.array(stamps), np.stack(poses)


def _find_sequence(root: Path, sequence: str | None) -> Path:
    """The mav0 folder of `root` (or of `root/sequence`); the error lists the sequences `root` holds."""
    folder = root / sequence if sequence else root
    mav0 = find_mav0(folder)
    if mav0 is not None:
        return mav0
    sequences = sorted(p.name for p in root.iterdir() if p.is_dir() and find_mav0(p)) if root.is_dir() else []
    if sequences and not sequence:
        raise DatasetError(
            f"{root}: holds several ASL sequences; name one with sequence (--sequence): {', '.join(sequences)}"
        )
    present = f"; present: {', '.join(sequences)}" if sequences else ""
    raise DatasetError(f"{folder}: not an EuRoC/ASL sequence (no mav0/cam0 folder){present}")


def _open_cameras(mav0: Path) -> tuple[CameraFiles, CameraFiles]:
    """cam0 (left) and cam1 (right) of a sequence, which must have the same resolution."""
    left, right = CameraFiles(mav0 / "cam0"), CameraFiles(mav0 / "cam1")
    if left.image_size_px != right.image_size_px:
        raise DatasetError(
            f"{right.sensor_path}: resolution {right.image_size_px} differs from cam0's "
            f"{left.image_size_px}; stereo pairs must have equal sizes"
        )
    return left, right


def _rectifier(left: CameraFiles, right: CameraFiles, first_row: int) -> StereoRectifier:
    """The rig's rectification (pose of cam1 in cam0: `T_BS0⁻¹ T_BS1`), after checking that cam0's image at
    `first_row` has the resolution of sensor.yaml and that both cameras share a distortion model."""
    first = read_image(left.image_path(first_row))
    if (first.shape[1], first.shape[0]) != left.image_size_px:
        raise DatasetError(
            f"{left.image_path(first_row)}: size {first.shape[::-1]} differs from the resolution "
            f"{left.image_size_px} in {left.sensor_path}"
        )
    if right.model.lower() != left.model.lower():
        raise DatasetError(
            f"{right.sensor_path}: distortion model {right.model!r} differs from cam0's {left.model!r}"
        )
    camera0_from_camera1 = np.linalg.inv(left.body_from_sensor) @ right.body_from_sensor
    return rectify_rig(
        left.K,
        left.D,
        right.K,
        right.D,
        camera0_from_camera1,
        left.image_size_px,
        left.model,
        f"{left.sensor_path} + {right.sensor_path.parent.name}/sensor.yaml",
    )


class EurocStereo(StereoLoader):
    """An EuRoC / ASL stereo sequence as a rectified `StereoDataset` (layout and semantics: module doc)."""

    KIND = "euroc"
    TITLE = "EuRoC/ASL sequences"
    LAYOUT = "for EuRoC the folder that holds mav0/"
    OPTIONS = ("start", "stop", "stride", "max_stereo_dt_s", "trim_to_ground_truth")

    def __init__(
        self,
        root: str | Path,
        sequence: str | None = None,
        start: int | None = None,
        stop: int | None = None,
        stride: int = 1,
        max_stereo_dt_s: float | None = None,
        trim_to_ground_truth: bool = True,
    ) -> None:
        super().__init__(stride)
        mav0 = _find_sequence(Path(root), sequence)
        self.root = mav0.parent if mav0.name == "mav0" else mav0
        self.name = f"euroc_{self.root.name}"
        left, right = _open_cameras(mav0)
        self._left, self._right = left, right

        # Stereo pairs by timestamp, then the frame range.
        tolerance_s = None if max_stereo_dt_s is None else float(max_stereo_dt_s)
        where = f"{mav0 / 'cam0' / 'data.csv'}"
        frames, partner = self._select_pairs(tolerance_s, start, stop, stride, where)

        # Rectification, checked now (before any frame is processed).
        self.rectifier: StereoRectifier = _rectifier(left, right, int(frames[0]))
        self.calibration = self.rectifier.calibration

        # Ground truth at the image times, in the rectified camera 0.
        times_s = left.stamps_ns[frames] * 1e-9
        check_time_unit(where, frames, times_s)  # before trimming to a ground truth in another unit
        gt_path = mav0 / "state_groundtruth_estimate0" / "data.csv"
        if gt_path.is_file():
            frames, times_s = self._ground_truth_at(gt_path, frames, times_s, trim_to_ground_truth)
        self.frame_indices = frames
        self.timestamps_s = times_s
        check_increasing(self.timestamps_s, where)
        self._right_rows = np.array([partner[int(f)] for f in frames], dtype=np.int64)
        self._finish_note()

    def _select_pairs(
        self,
        tolerance_s: float | None,
        start: int | None,
        stop: int | None,
        stride: int,
        where: str,
    ) -> tuple[np.ndarray, dict[int, int]]:
        """(cam0 rows of the selected frames, the cam1 row of every paired cam0 row): left and right images
        paired by timestamp, then `start`/`stop`/`stride`; what is left out goes to the warnings."""
        left, right = self._left, self._right
        left_rows, right_rows, _ = pair_by_time(left.stamps_ns * 1e-9, right.stamps_ns * 1e-9, tolerance_s)
        selection = FrameSelection(left_rows, len(left.files), start, stop, stride, where)
        self.missing_frames = selection.missing_frames
        self.warnings += selection.warnings
        partner = dict(zip(left_rows.tolist(), right_rows.tolist()))
        if len(left_rows) < max(len(left.files), len(right.files)):
            self.warnings.append(
                f"cam0 lists {len(left.files)} images and cam1 {len(right.files)}: {len(left_rows)} pairs "
                "matched by timestamp, the other images are not used"
            )
        return selection.frames, partner

    def _ground_truth_at(
        self, gt_path: Path, frames: np.ndarray, times_s: np.ndarray, trim_to_ground_truth: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """Set the ground truth (`world_from_camera` of the rectified camera 0) at the frames' times; returns
        the frames and times it keeps (those outside its span are dropped when `trim_to_ground_truth`)."""
        gt_s, world_from_body = read_ground_truth(gt_path)
        world_from_camera = self.rectifier.rectified_pose(world_from_body @ self._left.body_from_sensor)
        gt, keep, notes = ground_truth_at_frames(
            gt_s, world_from_camera, times_s, trim_to_ground_truth, str(gt_path)
        )
        self.warnings += notes
        self._ground_truth = gt
        return frames[keep], times_s[keep]

    def _frame(self, i: int) -> StereoFrame:
        frame = int(self.frame_indices[i])
        left_path = self._left.image_path(frame)
        right_path = self._right.image_path(int(self._right_rows[i]))
        left, right = read_image(left_path), read_image(right_path)
        for path, image in ((left_path, left), (right_path, right)):
            if (image.shape[1], image.shape[0]) != self.calibration.image_size_px:
                raise DatasetError(
                    f"{path}: size {image.shape[::-1]} differs from the calibrated resolution "
                    f"{self.calibration.image_size_px}"
                )
        left, right = self.rectifier(left, right)
        return StereoFrame(frame, float(self.timestamps_s[i]), left, right)

    @staticmethod
    def detect(path: Path) -> bool:
        """True for an ASL sequence folder, its mav0 folder, or a folder of ASL sequences."""
        if find_mav0(path) is not None:
            return True
        return path.is_dir() and any(p.is_dir() and find_mav0(p) is not None for p in path.iterdir())

    def __repr__(self) -> str:
        return f"EurocStereo(root={str(self.root)!r}, frames={len(self)})"
