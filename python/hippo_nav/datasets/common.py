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
import struct
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from hippo_nav._core import decode_png
from hippo_nav.datasets.base import MAX_IMAGE_PIXELS, StereoCalibration, check_calibration
from hippo_nav.io.errors import MAX_SETTINGS_FILE_BYTES, DatasetError, file_error, read_bytes, read_text
from hippo_nav.io.poses import check_regular_file, matrix_from_quaternion, quaternion_from_matrix

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".ppm", ".bmp", ".tif", ".tiff")

# Rectified pairs share K; files print it with 6–9 significant digits.
INTRINSICS_TOLERANCE = 1e-6


MAX_YAML_VALUES = 10_000
"""Numbers one calibration key may hold at most (a 4x4 matrix has 16): YAML aliases can make a 1 kB file
stand for billions of values, which must not reach NumPy."""


def strict_yaml_loader() -> type:
    """PyYAML's safe loader, stricter where a settings file (a calibration, a sweep) is concerned: a key given
    twice in one mapping is an error (YAML would keep the last silently), and a scalar its constructor cannot
    take (a date 2001-13-45, an integer of thousands of digits) is a YAML error at its line, not a ValueError."""
    import yaml

    class Loader(yaml.SafeLoader):
        def construct_object(self, node: yaml.Node, deep: bool = False) -> Any:
            try:
                return super().construct_object(node, deep)
            except (ValueError, OverflowError) as err:
                problem = str(err).split(":")[0][:80] if str(err) else type(err).__name__
                raise yaml.constructor.ConstructorError(
                    None,
                    None,
                    f"cannot read this {node.tag.rsplit(':', 1)[-1]}: {problem}",
                    node.start_mark,
                ) from None

        def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
            seen: set[str] = set()
            for key, _ in node.value:
                if isinstance(key, yaml.ScalarNode) and key.tag != "tag:yaml.org,2002:merge":
                    if key.value in seen:
                        raise yaml.constructor.ConstructorError(
                            None, None, f"key {key.value[:40]!r} appears twice; keep one", key.start_mark
                        )
                    seen.add(key.value)
            return super().construct_mapping(node, deep)

    return Loader


def read_yaml(path: Path, what: str) -> dict[str, Any]:
    """A YAML mapping; OpenCV's `%YAML:1.0` first line (EuRoC's sensor.yaml files have it) is skipped."""
    import yaml

    check_regular_file(path, what, f"the dataset needs its {path.name}")
    text = read_text(path, what, MAX_SETTINGS_FILE_BYTES)
    skipped = 0
    if text.startswith("%YAML:"):
        text, skipped = (text.split("\n", 1)[1] if "\n" in text else ""), 1
    try:
        data = yaml.load(text, Loader=strict_yaml_loader())  # a SafeLoader subclass: no arbitrary objects
    except RecursionError:  # PyYAML composes nested collections recursively
        raise file_error(path, f"nested too deeply to be a {what}") from None
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
    if isinstance(value, bool):  # YAML's true/yes/on: float() would read 1.0
        raise file_error(path, f"'{key}: {value}' is not a number")
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):  # OverflowError: an integer beyond float's range
        raise file_error(path, f"'{key}: {_shown(value)}' is not a number (or not a finite one)") from None
    if not np.isfinite(number) or (positive and number <= 0):
        raise file_error(
            path, f"'{key}: {_shown(value)}' must be a {'positive ' if positive else ''}finite number"
        )
    return number


def _shown(value: object) -> str:
    """`value` as quoted in a message: at most 40 characters (an integer of 5 000 digits has no str)."""
    if isinstance(value, int) and abs(value) >= 10**40:
        return f"<an integer of about {value.bit_length() * 0.30103:.0f} digits>"
    # A value with a line break or another control character would break the message's one line: escaped.
    text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(value))
    return text if len(text) <= 40 else text[:40] + "…"


def _flat_numbers(value: Any, limit: int) -> list[float] | None:
    """The numbers of a number, or of a (nested) list of them, in order; None when anything else is there
    (other text, a mapping, a boolean). Iterative, and more than `limit` values give `limit` + 1 (of which only the
    count matters) at once: an alias bomb costs nothing."""
    numbers: list[float] = []
    stack = [value]
    while stack:
        if len(numbers) + len(stack) > limit:
            return [0.0] * (limit + 1)
        item = stack.pop()
        if isinstance(item, (list, tuple)):
            stack.extend(reversed(item))
        elif isinstance(item, (int, float, str)) and not isinstance(item, bool):
            # Text too: PyYAML reads 1e-5 (no dot) as a string, and such files have always been read.
            try:
                numbers.append(float(item))
            except OverflowError:  # an integer beyond float's range
                numbers.append(float("inf"))
            except ValueError:
                return None
        else:
            return None
    return numbers


def yaml_numbers(data: dict[str, Any], key: str, path: Path, count: int | None, what: str) -> np.ndarray:
    """`data[key]` as a flat float64 array of `count` finite numbers (any length when None)."""
    if key not in data:
        raise file_error(path, f"no '{key}' key ({what})")
    value = data[key]
    if isinstance(value, dict) and "data" in value:  # OpenCV/Kalibr matrices: {rows, cols, data}
        value = value["data"]
    limit = MAX_YAML_VALUES if count is None else count
    numbers = _flat_numbers(value, limit)
    if numbers is None:
        raise file_error(path, f"'{key}' must be a list of numbers ({what})")
    if len(numbers) > limit:
        raise file_error(path, f"'{key}' holds more than {limit} numbers ({what})")
    array = np.array(numbers, dtype=np.float64)
    if count is not None and array.size != count:
        raise file_error(path, f"'{key}' needs {count} numbers ({what}), found {array.size}")
    if not np.all(np.isfinite(array)):
        raise file_error(path, f"'{key}' contains NaN or infinity")
    return array


def rectified_calibration(
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    baseline_m: float,
    image_size_px: tuple[int, int],
    where: str,
) -> StereoCalibration:
    """The calibration of an already rectified pair: P0 = K[I|0], P1 = K[I|(−b, 0, 0)], checked for
    plausibility (`check_calibration`; `where` names the file it came from)."""
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    p0 = np.hstack([K, np.zeros((3, 1))])
    p1 = p0.copy()
    p1[0, 3] = -fx * baseline_m
    return check_calibration(StereoCalibration(p0, p1, None, None, image_size_px), where)


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


MAX_IMAGE_FILE_BYTES = 512 * 2**20
"""An image file larger than this is refused before it is read (an uncompressed 8192 × 8192 RGBA has 256 MiB)."""

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JPEG_STANDALONE = {0x01, *range(0xD0, 0xDA)}
_JPEG_SOF = set(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def image_size_in_header(data: bytes) -> tuple[int, int] | None:
    """(width, height) an encoded image declares (PNG, JPEG, BMP, PNM, TIFF, WebP), read from its header
    without decoding anything; None for another format or a header too broken to tell."""
    try:
        if data[:8] == _PNG_SIGNATURE and data[12:16] == b"IHDR":
            return struct.unpack(">II", data[16:24])
        if data[:2] == b"BM":
            if struct.unpack("<I", data[14:18])[0] == 12:  # OS/2 header: 16-bit sides
                return struct.unpack("<HH", data[18:22])
            width, height = struct.unpack("<ii", data[18:26])
            return abs(width), abs(height)
        if data[:1] == b"P" and data[1:2] in (b"1", b"2", b"3", b"4", b"5", b"6"):
            head = re.sub(rb"#[^\n]*", b" ", data[2:4096]).split()
            return int(head[0]), int(head[1])
        if data[:4] in (b"II*\x00", b"MM\x00*"):
            return _tiff_size(data)
        if data[:2] == b"\xff\xd8":
            return _jpeg_size(data)
        if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
            return _webp_size(data)
    except (struct.error, ValueError, IndexError):
        return None
    return None


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    at = 2
    while at + 4 <= len(data):
        if data[at] != 0xFF:
            return None
        marker = data[at + 1]
        if marker == 0xFF:  # fill byte
            at += 1
        elif marker in _JPEG_STANDALONE:
            at += 2
        elif marker in _JPEG_SOF:
            height, width = struct.unpack(">HH", data[at + 5 : at + 9])
            return width, height
        else:
            at += 2 + struct.unpack(">H", data[at + 2 : at + 4])[0]
    return None


def _tiff_size(data: bytes) -> tuple[int, int] | None:
    order = "<" if data[:2] == b"II" else ">"
    ifd = struct.unpack(order + "I", data[4:8])[0]
    (count,) = struct.unpack(order + "H", data[ifd : ifd + 2])
    sides: dict[int, int] = {}
    for k in range(count):
        entry = ifd + 2 + 12 * k
        tag, kind = struct.unpack(order + "HH", data[entry : entry + 4])
        if tag in (256, 257):
            value = data[entry + 8 : entry + 12]
            sides[tag] = struct.unpack(order + ("H" if kind == 3 else "I"), value[: 2 if kind == 3 else 4])[0]
    return (sides[256], sides[257]) if len(sides) == 2 else None


def _webp_size(data: bytes) -> tuple[int, int] | None:
    chunk = data[12:16]
    if chunk == b"VP8X":
        return 1 + int.from_bytes(data[24:27], "little"), 1 + int.from_bytes(data[27:30], "little")
    if chunk == b"VP8L":
        bits = int.from_bytes(data[21:25], "little")
        return 1 + (bits & 0x3FFF), 1 + ((bits >> 14) & 0x3FFF)
    if chunk == b"VP8 ":
        width, height = struct.unpack("<HH", data[26:30])
        return width & 0x3FFF, height & 0x3FFF
    return None


def decode_image_bytes(data: bytes, where: str, flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray | None:
    """An encoded image decoded by OpenCV (None when OpenCV cannot decode it). An image that declares more
    than `MAX_IMAGE_PIXELS` pixels is refused from its header, before a buffer is allocated (a 100 kB PNG
    can declare 100 000 × 100 000 px); OpenCV's own errors are a `DatasetError` naming `where`.

    8-bit gray and colour PNGs read as they are stored (`IMREAD_UNCHANGED`) are decoded by the `png` crate
    (`_core.decode_png`): the pixels OpenCV gives, in a quarter of its time (loading the pair was about a tenth
    of a real KITTI frame's CPU); every other image, and every PNG that decoder refuses, goes to OpenCV."""
    size = image_size_in_header(data)
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise DatasetError(
            f"{where}: the image declares {size[0]}x{size[1]} px ({size[0] * size[1]:,} pixels); images of "
            f"at most {MAX_IMAGE_PIXELS:,} pixels are read: is it the right file?"
        )
    if flags == cv2.IMREAD_UNCHANGED and data[:8] == _PNG_SIGNATURE:
        image = decode_png(data)
        if image is not None:
            return image
    try:
        return cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    except cv2.error as err:  # OpenCV's own limits (CV_IO_MAX_IMAGE_PIXELS …) raise
        reason = str(err).strip().splitlines()[-1] if str(err).strip() else "unknown error"
        raise DatasetError(f"{where}: OpenCV cannot decode the image ({reason})") from None


def read_image_file(path: Path, flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray:
    """An image file decoded as it is stored (`decode_image_bytes`: sizes checked before decoding; any file
    name works, the bytes are read here); a missing, oversized or undecodable file is a `DatasetError`."""
    if not path.is_file():
        raise DatasetError(f"{path}: image not found")
    try:
        data = read_bytes(path, "image file", MAX_IMAGE_FILE_BYTES)
    except OSError as err:
        raise DatasetError(f"{path}: cannot read the image ({err.strerror})") from None
    image = decode_image_bytes(data, str(path), flags) if data else None
    if image is None:
        raise DatasetError(f"{path}: image is corrupt or not a format OpenCV can read; replace the file")
    return image


def read_image(path: Path) -> np.ndarray:
    """Load an 8-bit image file as (H, W) uint8 gray."""
    return to_gray(read_image_file(path), str(path))


def frame_interval_s(frame_indices: np.ndarray, frame_timestamps_s: np.ndarray) -> float | None:
    """The median time between consecutive frames of the *sequence* (a stride or a gap in the yielded
    frames divides out), or None when the timestamps do not advance."""
    frames = np.asarray(frame_indices, dtype=np.float64)
    times = np.asarray(frame_timestamps_s, dtype=np.float64)
    d_frames, d_times = np.diff(frames), np.diff(times)
    usable = (d_frames > 0) & (d_times > 0)
    if not usable.any():
        return None
    return float(np.median(d_times[usable] / d_frames[usable]))


SLOWEST_FRAME_INTERVAL_S = 20.0
# No stereo camera a SLAM system is given takes more than 1 000 images a second; timestamps closer than
# that are in a unit the reader does not expect (EuRoC's integer milliseconds read as its nanoseconds put
# frames 100 ns apart, and the VO then rejects every step as impossibly fast: a trajectory of zeros).
FASTEST_FRAME_INTERVAL_S = 1e-3
_TIME_UNITS = (("milliseconds", 1e3), ("microseconds", 1e6), ("nanoseconds", 1e9))


def check_time_unit(name: str, frame_indices: np.ndarray, timestamps_s: np.ndarray) -> None:
    """Refuse frame timestamps that are not seconds: milliseconds or nanoseconds would make every frame a
    time gap (flagged, one warning per frame, and the networks would lose the motion across it), a unit
    read as a smaller one every step impossibly fast. A reader calls it on all its selected frames before
    trimming them to a ground truth, which a wrong unit would trim to nothing."""
    interval_s = frame_interval_s(frame_indices, np.asarray(timestamps_s, dtype=np.float64))
    if interval_s is not None and interval_s < FASTEST_FRAME_INTERVAL_S:
        raise DatasetError(
            f"{name}: the timestamps advance by a median {interval_s:.3g} s per sequence frame, a camera "
            f"taking {1.0 / interval_s:.3g} images a second; they are in another unit than the dataset's "
            "reader expects (KITTI times.txt, a folder's times.txt and TUM files: seconds; EuRoC data.csv: "
            "integer nanoseconds): fix the timestamps the dataset gives"
        )
    if interval_s is None or interval_s < SLOWEST_FRAME_INTERVAL_S:
        return
    guess = next(
        (
            f"{unit} (divide them by {factor:,.0f})"
            for unit, factor in _TIME_UNITS
            if interval_s / factor < 2.0
        ),
        "another unit",
    )
    raise DatasetError(
        f"{name}: the timestamps advance by a median {interval_s:.4g} per sequence frame, which as "
        f"seconds would be a camera taking one image every {interval_s:.3g} s; timestamps must be in seconds, "
        f"and these look like {guess}: fix the timestamps the dataset gives (KITTI: times.txt)"
    )


def check_increasing(stamps_s: np.ndarray, what: str) -> None:
    """Timestamps must increase strictly (the pipeline's dt, and TUM files paired by time)."""
    steps = np.diff(stamps_s)
    if steps.size and not np.all(steps > 0):
        k = int(np.flatnonzero(steps <= 0)[0])
        how = "repeats" if steps[k] == 0 else "goes back from"
        raise DatasetError(
            f"{what}: timestamp {float(stamps_s[k + 1])!r} (entry {k + 2}) {how} the previous one; "
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


def check_frame_range(start: object, stop: object, stride: object) -> None:
    """`start`, `stop` (or None) and `stride` must be whole numbers: 1.5 or True would be cut to 1 silently,
    a run over other frames than asked for."""
    for name, value in (("start", start), ("stop", stop), ("stride", stride)):
        if value is None and name != "stride":
            continue
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise TypeError(f"{name} must be a whole frame number, got {value!r} ({type(value).__name__})")


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
        check_frame_range(start, stop, stride)
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


GROUND_TRUTH_SLOWER_AT_MOST = 50.0
"""A ground truth sampled more slowly than a second and than this many camera frames is in the wrong unit."""


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
    gt_interval_s = float(np.median(np.diff(stamps_s))) if len(stamps_s) > 1 else None
    frames_interval_s = frame_interval_s(np.arange(len(frame_times_s)), frame_times_s)
    if (
        gt_interval_s is not None
        and frames_interval_s is not None
        and gt_interval_s > max(1.0, GROUND_TRUTH_SLOWER_AT_MOST * frames_interval_s)
    ):
        # A ground truth in milliseconds or nanoseconds beside images in seconds: every frame would fall
        # between its first two samples and be given a pose interpolated between them, a drive that never moves.
        raise DatasetError(
            f"{where}: its samples are a median {gt_interval_s:.4g} apart, the images {frames_interval_s:.3g} s: "
            f"a ground truth sampled more than {GROUND_TRUTH_SLOWER_AT_MOST:g}× more slowly than the camera is in "
            "another unit; its timestamps must be seconds, as the images' are"
        )
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
