"""The memory folder: what a run learnt, saved so that a later run can start inside it (docs/memory.md).

`<results>/memory/` holds:

| file | what |
|---|---|
| `map.bin` | the experience map (the map crate's versioned, checksummed format) |
| `views.npz` | the view cells (word features or templates) and what each recalls: its stored network state (`CompactView` codes), the vertex it was made at and its offset from it, the odometer when made |
| `keyframes.npz` | the closure proposer's stereo keyframes, one per vertex |
| `state.npz` | where the run stopped: the networks' full state, the active view cell, the last odometry pose — what a session continuing with the next frames needs (`SlamSystem(..., memory=..., resume=True)`) |
| `path.npz` | every frame of every session: its vertex and offset from it (and session, frame index, time), so a later session places the earlier sessions' frames again on the map it corrected (`hippo_nav.pipeline.sessions`); absent from memories written before it existed |
| `truth.npz` | only when the run had a ground truth: where each vertex was made and every frame's position, in the dataset's own ground-truth frame, so a later session on the same sequence scores its closures onto this map against the truth; never read by the system |
| `memory.json` | format and version, the config that made the memory, the camera, the VO's disparity offset as the run ended and the estimates behind it, and every file's size and SHA-256 |

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
from hippo_nav.io.errors import os_error_words, read_bytes

__all__ = [
    "FORMAT",
    "MEMORY_FOLDER",
    "PATH_FILE",
    "TRUTH_FILE",
    "VERSION",
    "SavedMemory",
    "SavedMemoryError",
    "check_compatible",
    "check_parts_agree",
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
TRUTH_FILE = "truth.npz"  # optional: a run without ground truth has none
PATH_FILE = "path.npz"  # optional: memories written before it existed have none
_OPTIONAL_FILES = (PATH_FILE, TRUTH_FILE)


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
    # For scoring only (`truth.npz`, `hippo_nav.pipeline.truth`): empty when the run had no ground truth.
    truth: dict[str, np.ndarray] = field(default_factory=dict)
    # Every session's frames as vertex + offset (`path.npz`, `hippo_nav.pipeline.sessions`); empty: none kept.
    path: dict[str, np.ndarray] = field(default_factory=dict)


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
    """Write `memory` as `folder`: filled beside it and swapped in whole (`atomic.atomic_folder`), so an
    earlier memory there stays intact until the new one is complete, and a link at `folder` (another run's
    memory) is replaced, never written through. The manifest is written last."""
    folder = Path(folder)
    payloads = {
        "map.bin": memory.map_bytes,
        "views.npz": _npz_bytes(memory.views),
        "keyframes.npz": _npz_bytes(memory.keyframes),
        # The networks' full state: each grid module's activity is tiled k² times over the torus (8 MB at the
        # defaults); compressed it is a small fraction of that.
        "state.npz": _npz_bytes(memory.state, compressed=True),
    }
    if memory.path:
        payloads[PATH_FILE] = _npz_bytes(memory.path, compressed=True)
    if memory.truth:
        payloads[TRUTH_FILE] = _npz_bytes(memory.truth, compressed=True)
    with atomic.atomic_folder(folder) as staging:
        files = {}
        for name, data in payloads.items():
            atomic.write_bytes(staging / name, data)
            files[name] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
        manifest = {"format": FORMAT, "version": VERSION, "files": files, **memory.info}
        atomic.write_text(staging / MANIFEST, json.dumps(manifest, indent=1, allow_nan=False) + "\n")
    return folder


def _fail(folder: Path, what: str) -> SavedMemoryError:
    return SavedMemoryError(f"the saved memory in {folder}: {what}")


def read_memory(path: str | Path) -> SavedMemory:
    """Read and check a memory folder (or a results folder holding one); every problem is one
    `SavedMemoryError` naming the file, raised before anything is built."""
    folder = memory_folder(path)
    manifest_path = folder / MANIFEST
    if not manifest_path.is_file():
        aside = folder.parent / ".hippo_nav_previous"  # `--overwrite`'s (pipeline.results.PREVIOUS_RESULTS)
        if folder.name == MEMORY_FOLDER and (aside / MEMORY_FOLDER / MANIFEST).is_file():
            raise _fail(
                folder,
                f"there is no memory.json: an --overwrite run into {folder.parent} never finished, and the "
                f"earlier run it replaced, memory included, is in {aside}; give --map {aside}",
            )
        raise _fail(
            folder,
            "there is no memory.json: give the results folder of a finished `hippo-nav run` (it holds "
            "memory/), or the memory folder itself",
        )
    try:
        manifest = json.loads(read_bytes(manifest_path, "memory manifest", _MAX_MANIFEST_BYTES))
    except RecursionError:  # nested deeper than any manifest this package writes (a few levels)
        raise _fail(folder, "memory.json is nested too deeply to be a manifest; it is corrupted") from None
    except OSError as err:
        raise _fail(folder, f"memory.json cannot be read ({os_error_words(err)})") from None
    except ValueError as err:
        raise _fail(folder, f"memory.json cannot be read ({err}); it is truncated or corrupted") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise _fail(folder, f"memory.json is not a {FORMAT} manifest")
    if manifest.get("version") != VERSION:
        raise _fail(
            folder,
            f"format version {manifest.get('version')!r}, this hippo_nav reads version {VERSION}; use the "
            "hippo_nav that wrote it",
        )
    files = manifest.get("files")
    if not isinstance(files, dict) or set(files) - set(_OPTIONAL_FILES) != {"map.bin", *_ARRAY_FILES}:
        raise _fail(folder, "memory.json does not list the memory's files; it is corrupted")
    _check_manifest(folder, manifest)
    data: dict[str, bytes] = {}
    for name, expected in files.items():
        path_ = folder / name
        try:
            blob = read_bytes(path_, f"memory file {name}", _MAX_FILE_BYTES)
        except OSError as err:
            raise _fail(folder, f"{name} cannot be read ({os_error_words(err)})") from None
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
    arrays: dict[str, dict[str, np.ndarray]] = {name: {} for name in _OPTIONAL_FILES}
    for name in (*_ARRAY_FILES, *(name for name in _OPTIONAL_FILES if name in data)):
        try:
            with np.load(io.BytesIO(data[name]), allow_pickle=False) as npz:
                arrays[name] = {k: npz[k] for k in npz.files}
        except (ValueError, OSError, EOFError) as err:  # numpy's words for bytes that are not an .npz
            why = err.args[0] if err.args else type(err).__name__
            raise _fail(folder, f"{name} is not a readable array file ({why})") from None
    info = {k: v for k, v in manifest.items() if k not in ("format", "version", "files")}
    return SavedMemory(
        data["map.bin"],
        arrays["views.npz"],
        arrays["keyframes.npz"],
        arrays["state.npz"],
        info,
        folder,
        arrays[TRUTH_FILE],
        arrays[PATH_FILE],
    )


_SHA256_HEX = frozenset("0123456789abcdef")
_INFO_OBJECTS = ("depends_on", "config", "counts", "odometry", "truth")


def _check_manifest(folder: Path, manifest: dict[str, Any]) -> None:
    """Every field of memory.json a later step reads has the type it needs, so a hand-edited or foreign
    manifest is one error naming the field, not a traceback where it is used."""
    for name, entry in manifest["files"].items():
        if not (
            isinstance(entry, dict)
            and type(entry.get("bytes")) is int
            and entry["bytes"] >= 0
            and isinstance(entry.get("sha256"), str)
            and len(entry["sha256"]) == 64
            and set(entry["sha256"]) <= _SHA256_HEX
        ):
            raise _fail(
                folder,
                f"memory.json's files.{name} is not a size and a SHA-256 ({json.dumps(entry)[:80]}); the "
                "manifest is corrupted: restore the folder from a backup",
            )
    for key in _INFO_OBJECTS:
        if key in manifest and not isinstance(manifest[key], dict):
            raise _fail(
                folder,
                f"memory.json's {key} is {type(manifest[key]).__name__}, not an object; it is corrupted",
            )
    for key, value in (manifest.get("counts") or {}).items():
        if type(value) is not int or value < 0:
            raise _fail(folder, f"memory.json's counts.{key} is {value!r}, not a count; it is corrupted")


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
    differ = [
        n
        for n in sorted(set(saved) | set(current))
        if not _same(saved.get(n, "<absent>"), current.get(n, "<absent>"))
    ]
    if any(name.startswith("camera.") for name in differ):
        raise _fail(
            memory.folder or Path("."),
            f"it was made with another camera ({_camera(saved)}; this run's: {_camera(current)}): its view "
            "cells and keyframes are images of that camera. Run on the images of the camera that made it, "
            "or start a new map.",
        )
    for name in differ:
        a, b = saved.get(name, "<absent>"), current.get(name, "<absent>")
        if not _same(a, b):
            raise _fail(
                memory.folder or Path("."),
                f"it was made with {_shown(name, a, 'it was made without the part')}, this run has "
                f"{_shown(name, b, 'no such part', named=False)}: what it stores "
                "(view cells, network states, map) depends on that setting. Run with the saved value (its "
                "config.json is in the results folder) or start a new map.",
            )


def _shown(name: str, value: Any, absent: str, named: bool = True) -> str:
    """`name = value` (`value` alone unless `named`), or, where one side lacks the setting (a part that run
    did not have, e.g. a preset without keyframes), what that means rather than a placeholder value."""
    if value == "<absent>":
        return f"no {name} ({absent} that sets it)"
    return f"{name} = {json.dumps(value)}" if named else json.dumps(value)


def _camera(flat: dict[str, Any]) -> str:
    """A camera as a person compares two: image size, focal length, baseline."""
    size = flat.get("camera.image_size_px")
    fx, baseline = flat.get("camera.fx_px"), flat.get("camera.baseline_m")
    parts = [
        f"{size[0]}×{size[1]} px images" if isinstance(size, list) and len(size) == 2 else f"images {size!r}",
        f"fx {fx:.2f} px" if isinstance(fx, (int, float)) else f"fx {fx!r}",
        f"baseline {baseline:.4f} m" if isinstance(baseline, (int, float)) else f"baseline {baseline!r}",
    ]
    return ", ".join(parts)


def check_parts_agree(memory: SavedMemory, *, vertices: int, view_cells: int) -> None:
    """The restored parts of `memory` refer to each other only within what was restored (`vertices` map
    vertices, `view_cells` cells): view cells anchored to vertices the map has, keyframes of its vertices,
    the counts the manifest promises. A memory that fails this (files mixed from several runs) would load and
    never relocalise, so it is refused, naming what disagrees."""
    folder = memory.folder or Path(".")
    views, keyframes = memory.views, memory.keyframes
    checks = [
        ("views.npz recall.anchor_vertex", views.get("recall.anchor_vertex"), vertices, "map vertices"),
        ("keyframes.npz vertex", keyframes.get("vertex"), vertices, "map vertices"),
        ("views.npz recall.anchor_cell", views.get("recall.anchor_cell"), view_cells, "view cells"),
        ("views.npz recall.stored_cell", views.get("recall.stored_cell"), view_cells, "view cells"),
        ("views.npz recall.offset_cell", views.get("recall.offset_cell"), view_cells, "view cells"),
    ]
    for what, ids, size, of in checks:
        if ids is None or np.size(ids) == 0:
            continue
        ids = np.asarray(ids).reshape(-1)
        if not np.issubdtype(ids.dtype, np.integer):
            found = f"holds {ids.dtype} values, not ids"
        elif ids.min() < 0 or ids.max() >= size:
            found = f"refers to ids {int(ids.min())} to {int(ids.max())}, the memory holds {size} {of}"
        else:
            continue
        raise _fail(
            folder,
            f"its parts disagree: {what} {found}; it is not one run's memory (files mixed from several?): "
            "start a new map or restore the folder",
        )
    counts = memory.info.get("counts") or {}
    for name, restored in (("vertices", vertices), ("view_cells", view_cells)):
        promised = counts.get(name)
        if promised is not None and promised != restored:
            raise _fail(
                folder,
                f"memory.json promises {promised} {name}, its files hold {restored}; the files are mixed "
                "from several runs: restore the folder",
            )
