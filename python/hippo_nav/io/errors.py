"""The package's error for bad data files (datasets, calibration, pose files).

`DatasetError` subclasses `hippo_nav.HippoNavError` (itself a `ValueError`), so callers can catch every
problem of this package with one `except HippoNavError`. Messages name the file (and the 1-based line
where one is at fault) and say what to fix.
"""

from __future__ import annotations

from pathlib import Path

from hippo_nav._core import HippoNavError


class DatasetError(HippoNavError):
    """A data file or folder is missing, malformed or inconsistent; the message names it."""


def file_error(path: str | Path, problem: str, line: int | None = None) -> DatasetError:
    """Build a `DatasetError` that starts with `path[:line]` so the culprit is visible at a glance."""
    where = f"{path}:{line}" if line is not None else f"{path}"
    return DatasetError(f"{where}: {problem}")


def read_text(path: str | Path, what: str = "file") -> str:
    """The text of a UTF-8 file; a byte that is not UTF-8 is a `DatasetError` naming the file, the line and
    the byte (not a `UnicodeDecodeError` traceback). Other read errors (`OSError`) pass through."""
    data = Path(path).read_bytes()
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
