"""The package's error for bad data files (datasets, calibration, pose files).

`DatasetError` subclasses `hippo_nav.HippoNavError` (itself a `ValueError`), so callers can catch every
problem of this package with one `except HippoNavError`. Messages name the file (and the 1-based line
where one is at fault) and say what to fix.
"""

from __future__ import annotations

import os
from pathlib import Path

from hippo_nav._core import HippoNavError


class DatasetError(HippoNavError):
    """A data file or folder is missing, malformed or inconsistent; the message names it."""


def file_error(path: str | Path, problem: str, line: int | None = None) -> DatasetError:
    """Build a `DatasetError` that starts with `path[:line]` so the culprit is visible at a glance."""
    where = f"{path}:{line}" if line is not None else f"{path}"
    return DatasetError(f"{where}: {problem}")


def os_error_words(err: OSError) -> str:
    """An operating-system error as one plain line naming the file(s): "no such file or directory:
    runs/x/metrics.json", not Python's `[Errno 2] No such file or directory: '…'`."""
    what = (err.strerror or type(err).__name__).rstrip(".")
    what = what[:1].lower() + what[1:]
    names = [str(n) for n in (err.filename, err.filename2) if n is not None]
    return f"{what}: {' → '.join(names)}" if names else what


MAX_DATA_FILE_BYTES = 256 * 2**20
"""The largest text data file read (poses, timestamps, image lists; a KITTI pose file has 0.5 MB, EuRoC's
200 Hz ground truth 2–5 MB a sequence): a bigger one is refused before it is read."""
MAX_SETTINGS_FILE_BYTES = 16 * 2**20
"""The largest settings file read (a config, a calibration, a topics YAML: each a few kB)."""


def _size(n_bytes: int) -> str:
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n_bytes >= scale:
            return f"{n_bytes / scale:.1f} {unit}"
    return f"{n_bytes} bytes"


def read_bytes(path: str | Path, what: str = "file", max_bytes: int = MAX_DATA_FILE_BYTES) -> bytes:
    """The bytes of a file of at most `max_bytes`; a larger one is a `DatasetError` naming the file and its
    size, raised before anything is read (a pipe or device is read up to the limit, never further). Other
    read errors (`OSError`) pass through."""
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        data = f.read(max_bytes + 1) if size <= max_bytes else b""
    if size > max_bytes or len(data) > max_bytes:
        how_big = (
            f"is {_size(size)} ({size} bytes)" if size > max_bytes else f"holds more than {_size(max_bytes)}"
        )
        raise file_error(
            path, f"the {what} {how_big}; one may have {_size(max_bytes)} at most: is it the right file?"
        )
    return data


def read_text(path: str | Path, what: str = "file", max_bytes: int = MAX_DATA_FILE_BYTES) -> str:
    """The text of a UTF-8 file of at most `max_bytes` (`read_bytes`); a byte that is not UTF-8 is a
    `DatasetError` naming the file, the line and the byte (not a `UnicodeDecodeError` traceback). Other
    read errors (`OSError`) pass through."""
    data = read_bytes(path, what, max_bytes)
    # A byte-order mark (editors on Windows write one) is not text: without this, calib.txt's "P0:" read
    # as "\ufeffP0:" and the file had "no P0 line".
    data = data.removeprefix(b"\xef\xbb\xbf")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        line = data.count(b"\n", 0, err.start) + 1
        raise file_error(
            path,
            f"the {what} is not UTF-8 text (byte 0x{data[err.start]:02x} at offset {err.start}); "
            "save it as UTF-8 (or plain ASCII)",
            line,
        ) from None
