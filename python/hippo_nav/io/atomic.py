"""Writing files so that none is ever half-written, written through a link, or lost to a full disk.

Every file a run or `render` writes goes through here. The content goes to a fresh temporary file in the
target's folder, created exclusively (`O_EXCL` never opens an existing name, so a link planted under a
predictable name is not followed), is closed, and is then renamed over the target (a rename replaces a
link at the target itself, never the file it points to). A reader sees the old file or the whole new
one, never a truncated one, whenever the process stops. (No fsync: it guards against a power cut, not a
stopped process, and would cost a render of thousands of images seconds per thousand.) A failure (a read-only or full disk, a folder removed) removes the
temporary file and raises `WriteError`, which names the file and the reason.

OpenCV takes file names as C strings and crashes on a name that is not valid UTF-8 (a byte-named folder
on Linux), so images are encoded in memory (`write_image`) and written here (the loaders decode the bytes
they read: `hippo_nav.datasets.common.read_image_file`).
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import cv2
import numpy as np

from hippo_nav._core import HippoNavError

__all__ = [
    "RESULTS_MARK",
    "WriteError",
    "atomic_folder",
    "atomic_path",
    "open_atomic",
    "open_lock",
    "output_folder",
    "write_bytes",
    "write_image",
    "write_text",
]


class WriteError(HippoNavError):
    """A file could not be written; `path` is the file, `reason` the operating system's words."""

    def __init__(self, path: Path, reason: str) -> None:
        self.path = Path(path)
        self.reason = reason
        super().__init__(f"cannot write {path}: {reason}")


def _reason(err: OSError) -> str:
    if err.errno == errno.ENOSPC:
        return "the disk is full"
    if err.errno == errno.EROFS:
        return "the file system is read-only"
    if err.errno in (errno.EACCES, errno.EPERM):
        return "permission denied"
    if err.errno == errno.EDQUOT:
        return "the disk quota is exceeded"
    return err.strerror or str(err)


def _temporary(path: Path, suffix: str) -> tuple[int, Path]:
    """A new file beside `path`, created exclusively (`O_EXCL`: an existing name or link is never opened),
    with the permissions a plain `open` would give (0666 less the umask; `mkstemp`'s are private)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}{suffix}")
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:
            continue
        except OSError as err:
            raise WriteError(path, _reason(err)) from None
    raise WriteError(path, "no free temporary name beside it")


def fresh_file_beside(path: str | Path, suffix: str) -> Path:
    """A new empty file beside `path` (a hidden name from it, `suffix` at the end), created exclusively, with
    the permissions of a plain `open`: for a writer that fills it and renames it to `path` when it is whole."""
    fd, tmp = _temporary(Path(path), suffix)
    os.close(fd)
    return tmp


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A fresh temporary path next to `path` (same suffix, so writers that choose the format by it still
    do), for writers that want a path (matplotlib); renamed over `path` when the block ends without an
    error, removed otherwise. The temporary file exists (empty, created exclusively) when the block starts."""
    path = Path(path)
    tmp = fresh_file_beside(path, path.suffix)
    try:
        try:
            yield tmp
        except OSError as err:
            raise WriteError(path, _reason(err)) from None
        if tmp.stat().st_size == 0:
            raise WriteError(path, "nothing was written (the writer failed silently)")
        _replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def open_atomic(path: str | Path, mode: str = "w", newline: str | None = None) -> Iterator[IO]:
    """`open(path, mode)` for writing, atomically (module doc): `mode` is "w" (UTF-8 text) or "wb"."""
    if mode not in ("w", "wb"):
        raise ValueError(f"open_atomic writes only ('w' or 'wb'), not {mode!r}")
    path = Path(path)
    fd, tmp = _temporary(path, ".tmp")
    try:
        if mode == "w":
            f: IO = os.fdopen(fd, "w", encoding="utf-8", newline=newline)
        else:
            f = os.fdopen(fd, "wb")
    except BaseException:
        os.close(fd)
        tmp.unlink(missing_ok=True)
        raise
    try:
        try:
            with f:
                yield f
        except OSError as err:  # a write or the close (where some file systems report a full disk)
            raise WriteError(path, _reason(err)) from None
        _replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write `data` to `path` atomically; returns the path."""
    with open_atomic(path, "wb") as f:
        f.write(data)
    return Path(path)


def write_text(path: str | Path, text: str) -> Path:
    """Write `text` (UTF-8) to `path` atomically; returns the path."""
    with open_atomic(path, "w") as f:
        f.write(text)
    return Path(path)


def write_image(path: str | Path, image: np.ndarray, params: list[int] | None = None) -> Path:
    """Encode `image` in the format of `path`'s suffix (OpenCV, in memory) and write it atomically."""
    path = Path(path)
    ok, encoded = cv2.imencode(path.suffix or ".png", image, params or [])
    if not ok:
        raise WriteError(
            path, f"OpenCV could not encode a {image.shape} {image.dtype} image as {path.suffix}"
        )
    return write_bytes(path, encoded.tobytes())


@contextlib.contextmanager
def atomic_folder(path: str | Path) -> Iterator[Path]:
    """A fresh, empty folder beside `path` to fill (with this module's writers); when the block ends without
    an error it takes `path`'s place whole, else it is removed and `path` is untouched. Whatever was at
    `path` is replaced, never written into: a folder is moved aside and removed after the swap, a link is
    removed (its target, perhaps another run's folder, is left as it was). Between the two renames a
    reader finds no folder for an instant, never a mixed one."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise WriteError(path.parent, _reason(err)) from None
    staging = _fresh_folder(path, "new")
    try:
        try:
            yield staging
        except OSError as err:
            raise WriteError(path, _reason(err)) from None
        old = None
        try:
            if path.is_symlink() or path.is_file():
                path.unlink()
            elif path.is_dir():
                old = _fresh_name(path, "old")
                os.rename(path, old)
            os.rename(staging, path)
        except OSError as err:
            if old is not None and not path.exists():
                os.rename(old, path)  # the earlier folder back where it was
            raise WriteError(path, _reason(err)) from None
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def _fresh_name(path: Path, tag: str) -> Path:
    return path.with_name(f".{path.name}.{tag}-{secrets.token_hex(4)}")


def _fresh_folder(path: Path, tag: str) -> Path:
    """A new folder beside `path` (`mkdir` never opens an existing name), with a plain folder's permissions."""
    for _ in range(100):
        folder = _fresh_name(path, tag)
        try:
            folder.mkdir(0o777)
            return folder
        except FileExistsError:
            continue
        except OSError as err:
            raise WriteError(path, _reason(err)) from None
    raise WriteError(path, "no free temporary name beside it")


RESULTS_MARK = ".hippo_nav_results"
"""Written into a results folder before the first frame: `--overwrite` replaces only a folder that has it, so
a folder that was never a results folder (a user's own config.json, frames.csv) is never touched."""


def output_folder(out: str | Path, holds: str) -> Path:
    """`out` (a command's `--out`), created when missing, before any work; a file there, or a folder that
    cannot be made, is one `HippoNavError` naming it and what it is for (`holds`), not `[Errno 17] …`."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise HippoNavError(f"--out {out}: not a folder (a file is there); give a folder for {holds}")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise HippoNavError(f"--out {out}: cannot create the folder ({_reason(err)})") from None
    return out


def open_lock(path: str | Path) -> IO[str]:
    """A lock or mark file opened for reading and writing (created when missing) without following a link
    at its name (`O_NOFOLLOW`: a link planted there is refused, not written through); for files that are
    held open and `flock`ed for a whole run rather than written once. A link or another failure is a
    `WriteError` naming the file."""
    path = Path(path)
    flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags, 0o666)
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise WriteError(
                path, "it is a symbolic link; remove the link (a lock file must be a plain file)"
            ) from None
        raise WriteError(path, _reason(err)) from None
    return os.fdopen(fd, "r+", encoding="utf-8")


def _replace(tmp: Path, path: Path) -> None:
    try:
        os.replace(tmp, path)
    except OSError as err:
        raise WriteError(path, _reason(err)) from None
