"""`manifest.json`: the provenance of one run of a sweep, beside its results folder's files.

| field | what |
|---|---|
| `run_id`, `sweep_session`, `attempt` | the run's id; the sweep invocation that made it; 2 or more when Ray restarted it after its worker died |
| `status`, `exit_status`, `error` | `running`, `done`, `interrupted` or `failed`; the code `hippo-nav run` would exit with (0; 2 bad input; 1 an error that is a bug; 130/143/129 interrupted; null: the worker died); the error, one line |
| `axes`, `overrides`, `lesion`, `seed`, `sequence`, `odometry` | what the run varies (`axes`: all of them, flat, as the report's columns) |
| `dataset` | the dataset flags and `checksum`: SHA-256 of the frame numbers, timestamps and ground-truth poses of the frames the run processed (images are not hashed; null when it stopped before the first frame) |
| `config`, `config_sha256` | the fully resolved config and the SHA-256 of its canonical JSON |
| `package`, `python`, `host`, `pid`, `cpus` | hippo_nav's version and git revision (when it runs from a git checkout; `git_dirty`: uncommitted changes), Python, the machine, the worker process, the CPUs the run was given |
| `started_utc`, `ended_utc`, `wall_s`, `peak_rss_mb` | ISO 8601 times, the run's wall time and the worker's peak resident memory during the run |

Written atomically (a temporary file, then a rename): a reader never sees half a manifest, and a worker killed
while writing leaves the previous one.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import platform
import resource
import socket
import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav.io import read_text
from hippo_nav.io.atomic import write_text

MANIFEST = "manifest.json"
RUN_LOG = "run.log"
RUNS_DIR = "runs"
STATUSES = ("running", "done", "interrupted", "failed")
MANIFEST_VERSION = 1


def write_json_atomic(path: Path, data: dict[str, Any]) -> Path:
    """Write `data` as JSON to `path` atomically (`hippo_nav.io.atomic`: a temporary file, then a rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_text(path, json.dumps(data, indent=2, default=_json_default) + "\n")


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON")


MAX_MANIFEST_BYTES = 16 * 2**20
"""A manifest is a few kB; a bigger file at its name is not one (and is not read)."""


def read_manifest(run_dir: Path) -> dict[str, Any] | None:
    """The manifest of a run folder, or None when there is none or it is not one: unreadable, too big, not
    UTF-8, not JSON, nested too deeply for the parser, or not a JSON object. A run without a readable manifest
    is a run to do (again); the reader never raises for what a file holds."""
    try:
        data = json.loads(read_text(run_dir / MANIFEST, "manifest", MAX_MANIFEST_BYTES))
    except (OSError, ValueError, RecursionError):  # ValueError: DatasetError (size, UTF-8) and JSON errors
        return None
    return data if isinstance(data, dict) else None


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


@functools.cache
def package_provenance() -> dict[str, Any]:
    """hippo_nav's version and, when it runs from a git checkout, the revision and whether it has changes."""
    from hippo_nav._core import __version__

    source = Path(__file__).resolve().parent
    revision: str | None = None
    dirty: bool | None = None
    try:
        revision = _git(source, "rev-parse", "HEAD")
        dirty = bool(_git(source, "status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        pass  # not a git checkout (an installed wheel) or no git: the version alone identifies it
    return {"version": __version__, "git_revision": revision, "git_dirty": dirty}


def _git(where: Path, *args: str) -> str:
    done = subprocess.run(
        ["git", "-C", str(where), *args], capture_output=True, text=True, timeout=10, check=True
    )
    return done.stdout.strip()


def machine() -> dict[str, Any]:
    return {"host": socket.gethostname(), "pid": os.getpid(), "python": platform.python_version()}


def dataset_checksum(result: Any) -> dict[str, Any]:
    """SHA-256 of what a run read of its dataset besides the images (a `RunResult`): the frame numbers, the
    timestamps and the ground-truth poses of the frames processed (float64; the poses as the results folder
    writes them, rebased to the first frame), so runs on changed data are told apart."""
    record = result.record
    digest = hashlib.sha256()
    digest.update(np.asarray(record.column("frame_index"), dtype=np.int64).tobytes())
    digest.update(np.asarray(record.column("timestamp_s"), dtype=np.float64).tobytes())
    if result.ground_truth is not None:
        digest.update(np.ascontiguousarray(np.asarray(result.ground_truth, dtype=np.float64)).tobytes())
    return {
        "sha256": digest.hexdigest(),
        "frames": len(record),
        "ground_truth": result.ground_truth is not None,
    }


class PeakMemory:
    """The process's peak resident memory during one run. On Linux the kernel's high-water mark (`VmHWM`)
    is reset at the start (`/proc/self/clear_refs`), so a worker that ran other runs before reports this
    run's peak; elsewhere the process's peak since it started (`ru_maxrss`), an upper bound."""

    def __init__(self) -> None:
        self.per_run = False
        try:
            Path("/proc/self/clear_refs").write_text("5")
            self.per_run = True
        except OSError:
            pass

    def peak_mb(self) -> float:
        if self.per_run:
            try:
                for line in Path("/proc/self/status").read_text().splitlines():
                    if line.startswith("VmHWM:"):
                        return int(line.split()[1]) / 1024.0
            except (OSError, ValueError, IndexError):
                pass
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return peak / 1024.0 if sys.platform != "darwin" else peak / 2**20
