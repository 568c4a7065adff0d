"""Another system's odometry, replayed from its trajectory file, in place of the built-in stereo VO.

This lets the back-end (spatial memory, view cells, experience map) run on the odometry of ORB-SLAM3,
S-PTAM, VISO2 … so that back-ends can be compared on the same input:

```python
from hippo_nav.pipeline import run
from hippo_nav.vo.replay import ReplayOdometry, replay_odometry

replay = replay_odometry("kitti00_ORBSLAM.txt", align="start")   # reads and checks the file
result = run("runs/orb00", dataset=ROOT, sequence="00", odometry=replay)  # aligned with the opened dataset
vo = ReplayOdometry("poses.txt", dataset)            # directly, for an opened StereoDataset
step = vo.process(dataset[0])                       # a VoStep, like StereoOdometry.process
```

The command line does the same: `hippo-nav run --dataset ROOT --sequence 00 --odometry FILE
[--odometry-format kitti|tum] [--odometry-align exact|start|end]`.

File formats (read by `hippo_nav.io`, which checks every line and names `file:line` on an error):
- KITTI: line N is the `world_from_camera` pose (row-major 3×4 [R | t], 12 numbers) of frame N of the
  sequence; there are no timestamps, so lines are matched to frame numbers (`StereoFrame.index`).
- TUM: `timestamp_s x y z qx qy qz qw` per line; poses are paired with frames by timestamp: each
  processed frame takes the nearest pose within half the sequence's median frame interval.
The format is guessed from the first pose line (12 numbers: KITTI, 8: TUM) unless given.

Alignment of a KITTI file (`align`, `--odometry-align`), checked against the dataset when the replay
is built, before any frame is processed:
- `exact` (default): one pose per frame of the whole sequence (the length of `times.txt` for a KITTI
  sequence; for a dataset without one, the file must cover the frames the dataset yields).
- `start`: line 0 is frame 0; poses after the sequence's end are ignored (a file with a few extra
  lines, such as the ORB-SLAM3 file for KITTI 00 with 4 544 lines for 4 541 frames).
- `end`: the file's last line is the sequence's last frame (a file that starts late).
Under any alignment, a processed frame (after --start/--stop/--stride) without a line is an error. A TUM
file needs a pose for every processed frame; `start` and `end` do not apply to it (timestamps align it).

Frames: the world frame is whatever the file uses (steps are relative, so it cancels). `process(frame)`
returns `camera_prev_from_camera_cur = inv(P_prev) @ P_cur` between the file poses of the previous
*processed* frame and this one (with --stride 2 a step spans two file lines), so chaining the steps
from the identity reproduces the file's trajectory rebased to the first processed frame, exactly (the
inverse is the full matrix inverse, so the product telescopes even when the file's rotations were
written with few digits).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav.datasets.base import StereoDataset
from hippo_nav.datasets.common import frame_interval_s
from hippo_nav.datasets.kitti import read_times
from hippo_nav.io import DatasetError, read_kitti_poses, read_text, read_tum
from hippo_nav.io.errors import file_error, os_error_words
from hippo_nav.vo.odometry import VoStep

FORMATS = ("kitti", "tum")
"""Trajectory file formats `read_pose_file` reads."""

ALIGNMENTS = ("exact", "start", "end")
"""How the lines of a KITTI file map to the sequence's frames (see the module doc)."""

_FIELDS_OF_FORMAT = {12: "kitti", 8: "tum"}


@dataclass(frozen=True)
class PoseFile:
    """A trajectory file read and checked: its poses and, for TUM, their timestamps."""

    path: Path
    file_format: str  # one of FORMATS
    world_from_camera: np.ndarray  # (N, 4, 4) float64, as written in the file
    timestamps_s: np.ndarray | None  # (N,) for TUM; None for KITTI (line N = frame N)

    def __len__(self) -> int:
        return len(self.world_from_camera)


def guess_pose_format(path: str | Path) -> str:
    """ "kitti" or "tum" from the number of fields of the file's first pose line (12 or 8)."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: pose file not found (check the path)")
    try:
        lines = read_text(path, "pose file").splitlines()
    except OSError as err:
        raise file_error(path, f"cannot be read ({os_error_words(err)})") from None
    for number, text in enumerate(lines, start=1):
        stripped = text.strip()
        if not stripped or stripped.startswith("#"):
            continue
        n_fields = len(stripped.replace(",", " ").split())
        if n_fields in _FIELDS_OF_FORMAT:
            return _FIELDS_OF_FORMAT[n_fields]
        raise file_error(
            path,
            f"cannot tell the trajectory format from {n_fields} numbers on the first pose line "
            "(KITTI has 12: a row-major 3x4 pose; TUM has 8: timestamp x y z qx qy qz qw); "
            "fix the file or give the format (--odometry-format kitti|tum)",
            number,
        )
    raise file_error(path, "holds no poses; expected a KITTI (12 numbers a line) or TUM (8) trajectory")


def read_pose_file(path: str | Path, file_format: str | None = None) -> PoseFile:
    """Read a KITTI or TUM trajectory (`file_format` None: guessed); at least 2 poses are required."""
    if file_format is None:
        file_format = guess_pose_format(path)
    if file_format not in FORMATS:
        raise DatasetError(f"unknown trajectory format {file_format!r}; known: {', '.join(FORMATS)}")
    path = Path(path)
    if file_format == "kitti":
        timestamps_s, world_from_camera = None, read_kitti_poses(path)
    else:
        timestamps_s, world_from_camera = read_tum(path)
    if len(world_from_camera) < 2:
        raise file_error(path, f"holds {len(world_from_camera)} pose; replaying odometry needs at least 2")
    return PoseFile(path, file_format, world_from_camera, timestamps_s)


def _check_alignment(align: str, file_format: str | None = None) -> None:
    if align not in ALIGNMENTS:
        raise DatasetError(
            f"unknown alignment {align!r}; use one of {', '.join(ALIGNMENTS)} (--odometry-align)"
        )
    if file_format == "tum" and align != "exact":
        raise DatasetError(
            f"--odometry-align {align} applies to KITTI files (poses by line); a TUM file's poses are paired "
            "with frames by timestamp, so use the default (exact) and restrict the run with --start/--stop "
            "to the frames the file covers"
        )


def sequence_frame_count(dataset: StereoDataset) -> int | None:
    """Frames of the dataset's whole sequence (before range and stride): the length of a KITTI sequence's
    times.txt; None for a dataset that does not say (only its yielded frame indices are known)."""
    sequence_dir = getattr(dataset, "sequence_dir", None)
    if sequence_dir is None:
        return None
    return len(read_times(Path(sequence_dir) / "times.txt"))


def _describe_sequence(dataset: StereoDataset, n_frames: int) -> str:
    sequence = getattr(dataset, "sequence", None) or getattr(dataset, "name", None)
    label = f"sequence {sequence}" if sequence is not None else "the sequence"
    sequence_dir = getattr(dataset, "sequence_dir", None)
    where = f" ({Path(sequence_dir) / 'times.txt'})" if sequence_dir is not None else ""
    return f"{label} has {n_frames} frames{where}"


def _missing_lines_error(
    pose_file: PoseFile, align: str, frame_indices: np.ndarray, missing: np.ndarray, first_frame: int
) -> DatasetError:
    n_missing, n_frames = int(missing.sum()), len(frame_indices)
    first = int(frame_indices[np.argmax(missing)])
    last_frame = first_frame + len(pose_file) - 1
    return file_error(
        pose_file.path,
        f"holds {len(pose_file)} poses, i.e. frames {first_frame}..{last_frame} with "
        f"--odometry-align {align}, "
        f"but {n_missing} of the {n_frames} processed frames have no line (the first: frame {first}); "
        "restrict the run to the frames the file covers (--start/--stop) or check the alignment",
    )


def align_kitti_lines(
    pose_file: PoseFile,
    frame_indices: np.ndarray,
    n_sequence_frames: int | None,
    align: str,
    dataset: Any = None,
) -> np.ndarray:
    """The file line (0-based) of each processed frame of a KITTI pose file, under `align`.

    `n_sequence_frames` is the whole sequence's length (None when unknown: `exact` then only asks the file
    to cover the processed frames, and `end` takes the last processed frame as the sequence's last)."""
    _check_alignment(align, pose_file.file_format)
    frames = np.asarray(frame_indices, dtype=np.int64)
    n_poses = len(pose_file)
    if align == "exact" and n_sequence_frames is not None and n_poses != n_sequence_frames:
        raise file_error(
            pose_file.path,
            f"holds {n_poses} poses but {_describe_sequence(dataset, n_sequence_frames)}; a KITTI file needs "
            "one line per frame: if its first line is frame 0 (extra or missing poses at the end) pass "
            "--odometry-align start, if its last line is the sequence's last frame pass --odometry-align end",
        )
    if align == "end":
        last_frame = n_sequence_frames - 1 if n_sequence_frames is not None else int(frames.max())
        first_frame = last_frame - (n_poses - 1)  # negative when the file holds poses before frame 0
    else:
        first_frame = 0
    lines = frames - first_frame
    missing = (lines < 0) | (lines >= n_poses)
    if missing.any():
        raise _missing_lines_error(pose_file, align, frames, missing, first_frame)
    return lines


def pair_by_timestamp(
    pose_timestamps_s: np.ndarray,
    frame_timestamps_s: np.ndarray,
    tolerance_s: float,
) -> np.ndarray:
    """For each frame timestamp, the index of the nearest pose timestamp within `tolerance_s`, else −1.

    Pose timestamps must increase. A pose is given to one frame only (the nearest), so no step is ever
    the identity because two frames shared a pose."""
    stamps = np.asarray(pose_timestamps_s, dtype=np.float64).reshape(-1)
    times = np.asarray(frame_timestamps_s, dtype=np.float64).reshape(-1)
    if len(stamps) == 0:
        return np.full(len(times), -1, dtype=np.int64)
    after = np.searchsorted(stamps, times)
    before = np.clip(after - 1, 0, len(stamps) - 1)
    after = np.clip(after, 0, len(stamps) - 1)
    nearest = np.where(np.abs(stamps[before] - times) <= np.abs(stamps[after] - times), before, after)
    offset_s = np.abs(stamps[nearest] - times)
    paired = np.where(offset_s <= tolerance_s, nearest, -1)
    # Frames closer together than the tolerance (uneven timing) can meet the same pose: the nearer keeps it.
    poses, counts = np.unique(paired[paired >= 0], return_counts=True)
    for pose in poses[counts > 1]:
        sharing = np.flatnonzero(paired == pose)
        paired[np.delete(sharing, np.argmin(offset_s[sharing]))] = -1
    return paired


def align_tum_poses(
    pose_file: PoseFile, frame_indices: np.ndarray, frame_timestamps_s: np.ndarray
) -> np.ndarray:
    """The pose index of each processed frame of a TUM file (paired by timestamp; all must pair)."""
    assert pose_file.timestamps_s is not None
    stamps = pose_file.timestamps_s
    interval_s = frame_interval_s(frame_indices, frame_timestamps_s)
    if interval_s is None:  # a single frame or frozen timestamps: the file's own rate is the best guess
        interval_s = float(np.median(np.diff(stamps)))
    tolerance_s = 0.5 * interval_s
    paired = pair_by_timestamp(stamps, frame_timestamps_s, tolerance_s)
    missing = paired < 0
    if missing.any():
        k = int(np.argmax(missing))
        times = np.asarray(frame_timestamps_s, dtype=np.float64)
        raise file_error(
            pose_file.path,
            f"no pose within ±{tolerance_s * 1e3:.1f} ms (half the frame interval) for {int(missing.sum())} "
            f"of the {len(paired)} processed frames (the first: frame {int(frame_indices[k])} at "
            f"t = {times[k]:.3f} s); "
            f"the file's poses span t = {stamps[0]:.3f}..{stamps[-1]:.3f} s, the frames "
            f"t = {times.min():.3f}..{times.max():.3f} s; a TUM file needs a pose for every processed frame "
            "(stamped with the sequence's times.txt): restrict the run (--start/--stop) to the frames it "
            "covers",
        )
    return paired


class ReplayOdometry:
    """`ReplayOdometry(pose_file, dataset, align=...).process(frame) -> VoStep`: a pose file as odometry.

    `pose_file` is a path (format guessed unless `file_format` is given) or a `PoseFile`. The file is
    aligned with `dataset` (a `StereoDataset`: `frame_indices`, `timestamps_s`; a `KittiOdometry` also
    gives the sequence length via `sequence_dir/times.txt`) here, so a file that does not fit fails with a
    `DatasetError` before any frame runs. Every step has status "ok" (the first: identity, "first"); the
    feature counts of `VoStep` are 0 and the RMSE NaN (nothing was measured here).
    """

    def __init__(
        self,
        pose_file: PoseFile | str | Path,
        dataset: Any,
        *,
        align: str = "exact",
        file_format: str | None = None,
    ) -> None:
        if not isinstance(pose_file, PoseFile):
            pose_file = read_pose_file(pose_file, file_format)
        _check_alignment(align, pose_file.file_format)
        self.pose_file = pose_file
        self.align = align
        self.frame_indices = np.asarray(dataset.frame_indices, dtype=np.int64).reshape(-1)
        if len(self.frame_indices) == 0:
            raise DatasetError(f"{pose_file.path}: the dataset yields no frames; nothing to replay")
        if pose_file.file_format == "kitti":
            rows = align_kitti_lines(
                pose_file, self.frame_indices, sequence_frame_count(dataset), align, dataset
            )
            how = f"KITTI lines {int(rows[0])}..{int(rows[-1])}, --odometry-align {align}"
        else:
            timestamps_s = np.asarray(dataset.timestamps_s, dtype=np.float64).reshape(-1)
            rows = align_tum_poses(pose_file, self.frame_indices, timestamps_s)
            assert pose_file.timestamps_s is not None
            worst_ms = np.abs(pose_file.timestamps_s[rows] - timestamps_s).max() * 1e3
            how = f"TUM poses paired by timestamp, largest offset {worst_ms:.1f} ms"
        self.world_from_camera = pose_file.world_from_camera[rows]  # (n, 4, 4), one per processed frame
        self._row_of_frame = {int(f): k for k, f in enumerate(self.frame_indices)}
        self.note = (
            f"odometry replayed from {pose_file.path} ({how}; frames {int(self.frame_indices[0])}.."
            f"{int(self.frame_indices[-1])}; {len(rows)} of the file's {len(pose_file)} poses used)"
        )
        self.reset()

    def reset(self) -> None:
        """Forget the previous frame (the next frame starts a new trajectory, with status "first")."""
        self._previous_world_from_camera: np.ndarray | None = None
        self._previous_time_s: float | None = None

    def check_frames(self, frame_indices: np.ndarray) -> None:
        """Every frame a run will give has a pose here, or the `DatasetError` `pose_of` would raise at the
        first that has none (a replay built for another dataset or range)."""
        for frame in np.asarray(frame_indices).reshape(-1):
            self.pose_of(int(frame))

    def pose_of(self, frame_index: int) -> np.ndarray:
        """The file's `world_from_camera` of a processed frame (by its sequence frame number)."""
        row = self._row_of_frame.get(int(frame_index))
        if row is None:
            raise DatasetError(
                f"frame {frame_index} has no pose in the replay of {self.pose_file.path}: it was aligned for "
                f"frames {int(self.frame_indices[0])}..{int(self.frame_indices[-1])} "
                f"({len(self.frame_indices)} frames) of another dataset or range; build the replay for the "
                "dataset being run"
            )
        return self.world_from_camera[row]

    def process(self, frame: Any) -> VoStep:
        """The step from the previous processed frame to `frame` (identity, status "first", on the first)."""
        world_from_cur = self.pose_of(frame.index)
        stamp = float(frame.timestamp_s)
        if self._previous_world_from_camera is None:
            step, status, dt_s = np.eye(4), "first", 0.0
        else:
            assert self._previous_time_s is not None
            step = np.linalg.solve(self._previous_world_from_camera, world_from_cur)  # inv(P_prev) @ P_cur
            step[3] = (0.0, 0.0, 0.0, 1.0)  # exact bottom row despite round-off
            status, dt_s = "ok", stamp - self._previous_time_s
        self._previous_world_from_camera, self._previous_time_s = world_from_cur, stamp
        return VoStep(step, status, dt_s, 0, 0, 0, float("nan"))

    def __repr__(self) -> str:
        return (
            f"ReplayOdometry({str(self.pose_file.path)!r}, format={self.pose_file.file_format!r}, "
            f"align={self.align!r}, frames={len(self.frame_indices)})"
        )


def replay_odometry(
    path: str | Path, *, file_format: str | None = None, align: str = "exact"
) -> Callable[[Any], ReplayOdometry]:
    """What `hippo_nav.pipeline.run(..., odometry=)` takes: reads and checks the file now (so a malformed
    file fails before the dataset is opened), and aligns it with the dataset when called with it."""
    _check_alignment(align)  # before reading a long file
    pose_file = read_pose_file(path, file_format)
    _check_alignment(align, pose_file.file_format)

    def build(dataset: StereoDataset) -> ReplayOdometry:
        return ReplayOdometry(pose_file, dataset, align=align)

    return build
