"""Trajectory files in the KITTI odometry and TUM RGB-D formats, as (N, 4, 4) `world_from_camera` arrays.

KITTI (`poses/XX.txt`): one pose per line, 12 numbers = the row-major 3×4 matrix [R | t] of
`world_from_camera`, where "world" is the camera-0 frame of the sequence's first frame (x right, y down,
z forward). Line N is frame N; there are no timestamps (they live in `sequences/XX/times.txt`).

TUM: one pose per line, `timestamp_s x y z qx qy qz qw` (Hamilton unit quaternion, scalar last),
`#` starts a comment line. Both formats are what evo and the KITTI devkit read.

Readers check every line (field count, numbers, finiteness, a proper rotation) and raise `DatasetError`
naming the file and the 1-based line at fault. Writers accept any array layout and write with enough
digits (%.9e) that a write/read round trip is exact to ~1e-9.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hippo_nav.io.atomic import open_atomic
from hippo_nav.io.errors import DatasetError, file_error, read_text

# A 3×3 block read from a file counts as a rotation when RᵀR = I and det R = 1 within this tolerance.
# Files are often written with 6–9 significant digits, so exactness cannot be asked for; a corrupt or
# transposed-with-translation line is off by far more.
ROTATION_TOLERANCE = 1e-3
MAX_COORDINATE_M = 1e9
"""Largest |x|, |y|, |z| of a position read (a million km: far beyond any trajectory, metres or millimetres).
A larger number is a corrupt or mis-scaled file, and would overflow the error metrics' squares."""
MAX_TIMESTAMP_S = 1e11
"""Largest |timestamp| in seconds read (3 000 years; Unix time is 1.7e9 s): a larger one is in another unit
(milli- or nanoseconds), and differences of two would overflow."""


def check_regular_file(path: Path, what: str, hint: str) -> None:
    """A `DatasetError` unless `path` is a regular file: missing (`hint` says what is expected there), a folder,
    or a FIFO or device (opening a FIFO with no writer would wait for ever)."""
    if path.is_file():
        return
    if path.is_dir():
        raise DatasetError(f"{path}: is a folder, not a {what}; {hint}")
    if path.exists():
        raise DatasetError(f"{path}: is not a regular file (a FIFO, socket or device); give a {what}")
    raise DatasetError(f"{path}: {what} not found; {hint}")


def _improper_rotations(rotations: np.ndarray) -> np.ndarray:
    """(n,) True where an (n, 3, 3) block is not a proper rotation within `ROTATION_TOLERANCE` (RᵀR = I,
    det R = 1): what the readers refuse and the writers will not write."""
    # An entry beyond 1 is checked first: RᵀR of 1e200s overflows.
    improper = np.abs(rotations).max(axis=(1, 2)) > 1.0 + ROTATION_TOLERANCE
    bounded = np.where(improper[:, None, None], np.eye(3), rotations)
    gram_error = np.abs(np.einsum("nji,njk->nik", bounded, bounded) - np.eye(3)).max(axis=(1, 2))
    return (
        improper
        | (gram_error > ROTATION_TOLERANCE)
        | (np.abs(np.linalg.det(bounded) - 1.0) > ROTATION_TOLERANCE)
    )


def _check_rotation(rotation: np.ndarray, path: Path, line: int) -> None:
    if not _improper_rotations(rotation[None])[0]:
        return
    if np.abs(rotation).max() > 1.0 + ROTATION_TOLERANCE:
        raise file_error(
            path,
            f"the 3x3 block is not a rotation (it holds {np.abs(rotation).max():.4g}; a rotation's entries lie "
            "in [-1, 1]); each line must hold a proper rotation [R | t], row-major",
            line,
        )
    gram_error = np.abs(rotation.T @ rotation - np.eye(3)).max()
    raise file_error(
        path,
        f"the 3x3 block is not a rotation (|RᵀR − I| = {gram_error:.2g}, det = {np.linalg.det(rotation):.4g}); "
        "each line must hold a proper rotation [R | t]",
        line,
    )


def _numbers(text: str, path: Path, line: int, expected: int, what: str) -> np.ndarray:
    fields = text.split()
    if len(fields) != expected:
        why = ""
        if text.lstrip().startswith("#"):
            why = "; this is a comment line, which the format has none of: remove it"
        elif "," in text:
            why = "; the numbers are separated by commas, where the format separates them by spaces"
        raise file_error(path, f"expected {expected} numbers ({what}), found {len(fields)}{why}", line)
    try:
        values = np.array([float(f) for f in fields], dtype=np.float64)
    except ValueError as err:
        raise file_error(path, f"not a number: {err}", line) from None
    if not np.all(np.isfinite(values)):
        raise file_error(path, "contains NaN or infinity", line)
    return values


def _check_position(position: np.ndarray, path: Path, line: int) -> None:
    if np.abs(position).max() > MAX_COORDINATE_M:
        raise file_error(
            path,
            f"position {np.abs(position).max():.4g} m from the origin along an axis; positions are metres, at "
            f"most {MAX_COORDINATE_M:g} (a corrupt or mis-scaled file?)",
            line,
        )


def _lines(path: str | Path) -> tuple[Path, list[str]]:
    path = Path(path)
    check_regular_file(path, "pose file", "check the path (a KITTI or TUM trajectory, one pose a line)")
    try:
        text = read_text(path, "pose file")  # bounded in size, one line for a byte that is not UTF-8
    except OSError as err:
        raise file_error(path, f"cannot be read ({err.strerror or err})") from None
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()  # a trailing newline or blank tail is not a pose
    return path, lines


def read_kitti_poses(path: str | Path) -> np.ndarray:
    """Read a KITTI pose file into an (N, 4, 4) float64 array of `world_from_camera` matrices."""
    path, lines = _lines(path)
    if not lines:
        raise file_error(path, "is empty; a KITTI pose file has one 12-number line per frame")
    poses = np.tile(np.eye(4), (len(lines), 1, 1))
    for i, text in enumerate(lines):
        if not text.strip():
            raise file_error(path, "blank line inside the file (line N must be frame N)", i + 1)
        poses[i, :3, :4] = _numbers(text, path, i + 1, 12, "a row-major 3x4 pose").reshape(3, 4)
        _check_rotation(poses[i, :3, :3], path, i + 1)
        _check_position(poses[i, :3, 3], path, i + 1)
    return poses


def _validated_poses(world_from_camera: np.ndarray) -> np.ndarray:
    """The poses to write, checked as the readers check them: a file written is a file that reads back (before,
    a reflection or a zero block was written as something else, e.g. TUM's identity)."""
    poses = np.asarray(world_from_camera, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] not in ((4, 4), (3, 4)):
        raise DatasetError(f"poses must have shape (N, 4, 4) or (N, 3, 4), got {poses.shape}")
    if len(poses) == 0:
        raise DatasetError("no poses to write: a trajectory file holds at least one")
    if not np.all(np.isfinite(poses)):
        raise DatasetError("poses contain NaN or infinity; refusing to write them")
    far = np.abs(poses[:, :3, 3]).max(axis=1) > MAX_COORDINATE_M
    bad = _improper_rotations(poses[:, :3, :3])
    if bad.any():
        raise DatasetError(
            f"pose #{int(np.argmax(bad))} is not [R | t] with R a proper rotation (RᵀR = I, det R = 1); "
            "refusing to write it"
        )
    if far.any():
        raise DatasetError(
            f"pose #{int(np.argmax(far))} lies more than {MAX_COORDINATE_M:g} m from the origin along an axis; "
            "positions are metres (refusing to write it)"
        )
    return poses


def write_kitti_poses(path: str | Path, world_from_camera: np.ndarray) -> Path:
    """Write (N, 4, 4) or (N, 3, 4) poses as a KITTI pose file; returns the path."""
    poses = _validated_poses(world_from_camera)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open_atomic(path, "wb") as f:
        np.savetxt(f, poses[:, :3, :4].reshape(len(poses), 12), fmt="%.9e")
    return path


def quaternion_from_matrix(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (qx, qy, qz, qw), qw ≥ 0, of a 3×3 rotation (Shepperd's numerically stable branch)."""
    r = np.asarray(rotation, dtype=np.float64)
    trace = np.trace(r)
    # Pick the largest of 4·qw², 4·qx², 4·qy², 4·qz² as the divisor so no branch divides by a tiny number.
    candidates = np.array([trace, r[0, 0], r[1, 1], r[2, 2]])
    k = int(np.argmax(candidates))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        q = np.array([(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, s / 4])
    elif k == 1:
        s = 2.0 * np.sqrt(max(1.0 + r[0, 0] - r[1, 1] - r[2, 2], 0.0))
        q = np.array([s / 4, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s, (r[2, 1] - r[1, 2]) / s])
    elif k == 2:
        s = 2.0 * np.sqrt(max(1.0 + r[1, 1] - r[0, 0] - r[2, 2], 0.0))
        q = np.array([(r[0, 1] + r[1, 0]) / s, s / 4, (r[1, 2] + r[2, 1]) / s, (r[0, 2] - r[2, 0]) / s])
    else:
        s = 2.0 * np.sqrt(max(1.0 + r[2, 2] - r[0, 0] - r[1, 1], 0.0))
        q = np.array([(r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, s / 4, (r[1, 0] - r[0, 1]) / s])
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def matrix_from_quaternion(quaternion_xyzw: np.ndarray) -> np.ndarray:
    """3×3 rotation of a (qx, qy, qz, qw) quaternion; the quaternion is normalised first."""
    x, y, z, w = np.asarray(quaternion_xyzw, dtype=np.float64) / np.linalg.norm(quaternion_xyzw)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory: (timestamps_s (N,), world_from_camera (N, 4, 4))."""
    path, lines = _lines(path)
    stamps: list[float] = []
    poses: list[np.ndarray] = []
    for i, text in enumerate(lines):
        stripped = text.strip()
        if not stripped or stripped.startswith("#"):
            continue
        values = _numbers(stripped.replace(",", " "), path, i + 1, 8, "timestamp x y z qx qy qz qw")
        if abs(values[0]) > MAX_TIMESTAMP_S:
            raise file_error(
                path,
                f"timestamp {values[0]:.6g} s is beyond ±{MAX_TIMESTAMP_S:g} s; TUM timestamps are seconds "
                "(milli- or nanoseconds?)",
                i + 1,
            )
        _check_position(values[1:4], path, i + 1)
        quaternion = values[4:]
        # A component beyond 1 is no unit quaternion; checked first, as the norm of 1e200s overflows.
        if np.abs(quaternion).max() > 2.0:
            biggest = np.abs(quaternion).max()
            raise file_error(
                path, f"quaternion norm is over {biggest:.6g}, expected 1 (qx qy qz qw order)", i + 1
            )
        norm = np.linalg.norm(quaternion)
        if abs(norm - 1.0) > ROTATION_TOLERANCE:
            raise file_error(path, f"quaternion norm is {norm:.6g}, expected 1 (qx qy qz qw order)", i + 1)
        pose = np.eye(4)
        pose[:3, :3] = matrix_from_quaternion(quaternion)
        pose[:3, 3] = values[1:4]
        stamps.append(values[0])
        poses.append(pose)
    if not poses:
        raise file_error(path, "holds no poses; a TUM line is 'timestamp x y z qx qy qz qw'")
    timestamps_s = np.array(stamps)
    if np.any(np.diff(timestamps_s) <= 0):
        bad = int(np.argmax(np.diff(timestamps_s) <= 0)) + 1
        raise file_error(path, f"timestamps must increase strictly; pose #{bad + 1} does not")
    return timestamps_s, np.stack(poses)


def write_tum(path: str | Path, timestamps_s: np.ndarray, world_from_camera: np.ndarray) -> Path:
    """Write poses with their timestamps as a TUM trajectory file; returns the path."""
    poses = _validated_poses(world_from_camera)
    stamps = np.asarray(timestamps_s, dtype=np.float64).reshape(-1)
    if stamps.shape[0] != poses.shape[0]:
        raise DatasetError(f"{stamps.shape[0]} timestamps for {poses.shape[0]} poses; give one per pose")
    if not np.all(np.isfinite(stamps)):
        raise DatasetError("timestamps contain NaN or infinity")
    rows = np.empty((len(poses), 8))
    rows[:, 0] = stamps
    rows[:, 1:4] = poses[:, :3, 3]
    rows[:, 4:] = [quaternion_from_matrix(p[:3, :3]) for p in poses]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open_atomic(path, "wb") as f:
        np.savetxt(f, rows, fmt="%.9f %.9e %.9e %.9e %.12f %.12f %.12f %.12f")
    return path
