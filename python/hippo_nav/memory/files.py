"""The memory folder: what a run learnt, saved so that a later run can start inside it (docs/memory.md).

`<results>/memory/` holds:

| file | what |
|---|---|
| `map.bin` | the experience map (the map crate's versioned, checksummed format) |
| `views.npz` | the view cells (word features or templates) and what each recalls: its stored network state (`CompactView` codes), the vertex it was made at and its offset from it, the odometer when made |
| `keyframes.npz` | the closure proposer's stereo keyframes, one per vertex |
| `state.npz` | where the run stopped: the networks' full state, the active view cell, the last odometry pose — what a session continuing with the next frames needs (`SlamSystem(..., memory=..., resume=True)`) |
| `memory.json` | format and version, the config that made the memory, the camera, the VO's disparity offset as the run ended, and every file's size and SHA-256 |

The manifest is written last, so a folder with a manifest is complete; loading checks the manifest, then every
file's size and checksum, before anything is built, so a truncated or corrupted folder is one error naming the
file and nothing is half-loaded. Arrays are read without pickle.

`check_compatible` refuses a memory made with settings that change what is stored (the view descriptor and its
feature settings, the network's sizes, lesions, the map's parameters, the camera's image size and focal length),
naming the setting; the rest (thresholds of the closure check, injection, the odometry, outputs) may differ.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav._defaults import dotted
from hippo_nav.io import atomic
from hippo_nav.io.errors import read_bytes

__all__ = [
    "FORMAT",
    "MEMORY_FOLDER",
    "VERSION",
    "SavedMemory",
    "SavedMemoryError",
    "check_compatible",
    "memory_folder",
    "read_memory",
    "split_ragged",
    "stack_ragged",
    "write_memory",
]

FORMAT = "hippo_nav memory"
VERSION = 1
MEMORY_FOLDER = "memory"
MANIFEST = "memory.json"  # not manifest.json: a sweep's run folder has one of those, and tools look for it
_MAX_FILE_BYTES = 8 * 2**30  # a memory of a very long run; more is not a memory this package wrote
_MAX_MANIFEST_BYTES = 4 * 2**20
_ARRAY_FILES = ("views.npz", "keyframes.npz", "state.npz")


class SavedMemoryError(HippoNavError):
    """A saved memory that cannot be used: missing, truncated, corrupted, of another version, or made with
    incompatible settings. The message names the folder, the file or setting, and what to do."""


@dataclass
class SavedMemory:
    """The parts of a memory folder, checked (`read_memory`) or about to be written (`write_memory`).

    `map_bytes`: the map file's bytes; `views`, `keyframes`, `state`: named arrays; `info`: JSON-able facts
    (config, camera, counts, the descriptor and its settings) kept in the manifest."""

    map_bytes: bytes
    views: dict[str, np.ndarray]
    keyframes: dict[str, np.ndarray]
    state: dict[str, np.ndarray]
    info: dict[str, Any] = field(default_factory=dict)
    folder: Path | None = None


def stack_ragged(parts: list[np.ndarray], columns: int, dtype: Any) -> np.ndarray:
    """Every part's rows, one part after another, as one (Σ rows, columns) array (the parts' row counts,
    saved beside it, split it again: `split_ragged`)."""
    if not parts:
        return np.zeros((0, columns), dtype)
    return np.ascontiguousarray(np.concatenate(parts), dtype=dtype)


def split_ragged(counts: np.ndarray, *stacked: np.ndarray) -> list[tuple[np.ndarray, ...]]:
    """The parts of `stack_ragged` arrays again, one tuple (a slice of each array) per count; counts that
    do not add up to the arrays' rows are a `SavedMemoryError`."""
    counts = np.asarray(counts, np.int64).reshape(-1)
    ends = np.cumsum(counts)
    total = int(ends[-1]) if len(ends) else 0
    if (counts < 0).any() or any(len(a) != total for a in stacked):
        raise SavedMemoryError(
            f"saved parts are inconsistent: their counts add up to {total} rows, the arrays hold "
            f"{[len(a) for a in stacked]}; the memory is corrupted"
        )
    return [tuple(a[end - n : end] for a in stacked) for end, n in zip(ends.tolist(), counts.tolist())]


def memory_folder(path: str | Path) -> Path:
    """The memory folder of a results folder (or the folder itself when it is one)."""
    path = Path(path)
    if (path / MANIFEST).is_file() and not (path / MEMORY_FOLDER).is_dir():
        return path
    return path / MEMORY_FOLDER


def _npz_bytes(arrays: dict[str, np.ndarray], compressed: bool = False) -> bytes:
    buffer = io.BytesIO()
    named: dict[str, Any] = {k: np.asarray(v) for k, v in arrays.items()}
    (np.savez_compressed if compressed else np.savez)(buffer, allow_pickle=False, **named)
    return buffer.getvalue()


def write_memory(memory: SavedMemory, folder: str | Path) -> Path:
    """Write `memory` into `folder` (made if needed): each file atomically, the manifest last."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    payloads = {
        "map.bin": memory.map_bytes,
        "views.npz": _npz_bytes(memory.views),
        "keyframes.npz": _npz_bytes(memory.keyframes),
        # The networks' full state: each grid module's activity is tiled k² times over the torus (8 MB at the
        # defaults); compressed it is a small fraction of that.
        "state.npz": _npz_bytes(memory.state, compressed=True),
    }
    files = {}
    for name, data in payloads.items():
        atomic.write_bytes(folder / name, data)
        files[name] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    manifest = {"format": FORMAT, "version": VERSION, "files": files, **memory.info}
    atomic.write_text(folder / MANIFEST, json.dumps(manifest, indent=1, allow_nan=False) + "\n")
    return folder


def _fail(folder: Path, what: str) -> SavedMemoryError:
    return SavedMemoryError(f"the saved memory in {folder}: {what}")


def read_memory(path: str | Path) -> SavedMemory:
    """Read and check a memory folder (or a results folder holding one); every problem is one
    `SavedMemoryError` naming the file, raised before anything is built."""
    folder = memory_folder(path)
    manifest_path = folder / MANIFEST
    if not manifest_path.is_file():
        raise _fail(
            folder,
            "there is no memory.json: give the results folder of a finished `hippo-nav run` (it holds "
            "memory/), or the memory folder itself",
        )
    try:
        manifest = json.loads(read_bytes(manifest_path, "memory manifest", _MAX_MANIFEST_BYTES))
    except (ValueError, OSError) as err:
        raise _fail(folder, f"memory.json cannot be read ({err}); it is truncated or corrupted") from err
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise _fail(folder, f"memory.json is not a {FORMAT} manifest")
    if manifest.get("version") != VERSION:
        raise _fail(
            folder,
            f"format version {manifest.get('version')!r}, this hippo_nav reads version {VERSION}; use the "
            "hippo_nav that wrote it",
        )
    files = manifest.get("files")
    if not isinstance(files, dict) or set(files) != {"map.bin", *_ARRAY_FILES}:
        raise _fail(folder, "memory.json does not list the memory's files; it is corrupted")
    data: dict[str, bytes] = {}
    for name, expected in files.items():
        path_ = folder / name
        try:
            blob = read_bytes(path_, f"memory file {name}", _MAX_FILE_BYTES)
        except OSError as err:
            raise _fail(folder, f"{name} cannot be read ({err})") from err
        if len(blob) != expected.get("bytes"):
            raise _fail(
                folder,
                f"{name} holds {len(blob)} bytes, the manifest promises {expected.get('bytes')}: it is "
                "truncated or was changed after the run; restore the folder from a backup",
            )
        if hashlib.sha256(blob).hexdigest() != expected.get("sha256"):
            raise _fail(
                folder, f"{name} does not match its checksum: it is corrupted; restore it from a backup"
            )
        data[name] = blob
    arrays = {}
    for name in _ARRAY_FILES:
        try:
            with np.load(io.BytesIO(data[name]), allow_pickle=False) as npz:
                arrays[name] = {k: npz[k] for k in npz.files}
        except (ValueError, OSError, EOFError) as err:
            raise _fail(folder, f"{name} is not a readable array file ({err})") from err
    info = {k: v for k, v in manifest.items() if k not in ("format", "version", "files")}
    return SavedMemory(
        data["map.bin"], arrays["views.npz"], arrays["keyframes.npz"], arrays["state.npz"], info, folder
    )


# Settings a memory records only since a later version, with the value every memory saved before had.
_RECORDED_LATER: dict[str, Any] = {"closure.descriptor": "orb"}
# Settings memories once recorded that what they store does not depend on: the closure's proposers (their
# chain is `parts.closure`; the keyframes depend only on `closure.descriptor`).
_NO_LONGER_RECORDED = ("parts.closure",)


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        try:
            return math.isclose(float(a), float(b), rel_tol=1e-6, abs_tol=0.0)
        except (TypeError, ValueError):
            return False
    return bool(a == b)


def check_compatible(memory: SavedMemory, now: dict[str, Any]) -> None:
    """Refuse a memory whose stored parts this run could not use: `now` holds this run's values of the
    settings in `memory.info["depends_on"]` (same flattened names) and its camera; the first difference is
    an error naming the setting, both values and the fix."""
    saved = {**_RECORDED_LATER, **dotted(memory.info.get("depends_on", {}))}
    for name in _NO_LONGER_RECORDED:
        saved.pop(name, None)
    current = dotted(now)
    for name in sorted(set(saved) | set(current)):
        a, b = saved.get(name, "<absent>"), current.get(name, "<absent>")
        if not _same(a, b):
            raise _fail(
                memory.folder or Path("."),
                f"it was made with {name} = {json.dumps(a)}, this run has {json.dumps(b)}: what it stores "
                "(view cells, network states, map) depends on that setting. Run with the saved value (its "
                "config.json is in the results folder) or start a new map.",
            )
