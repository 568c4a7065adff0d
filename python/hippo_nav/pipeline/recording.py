"""A run's networks as a neuroscientist records them: `recording.npz` (a `hippo_nav.recording.Recording`) and
`module_phase.npz` (`ModulePhases`, each grid module's decoded bump per frame), written into the results
folder, so the measures and figures (`hippo-nav figures --run DIR`, `hippo_nav.report.neural`) need no
second run.

Frame: the networks' own (torus) frame. The map frame (x along the first camera's heading, y to its
left, origin at the first processed frame; `hippo_nav.geometry`) turned by the heading code the networks
started with, `h0` (`RunRecord.initial_heading_rad`): `x_torus = R(h0) x_map`. In it the grid lattices'
axes are the torus axes, so a module's unit fires where `2πk·x_torus/P` (modulo 2π, per axis, from the
phase it started at) reaches its phase, and the place code's unwrapped position is comparable with the
true position without any alignment. The true position is the ground truth's; with none, the corrected
map's trajectory (`metadata["position_source"]` says which). Time is uniform (`Recording` requires it):
frame position × the median frame interval; the frames' own timestamps are in `module_phase.npz`.

Size: every population keeps at most `records.UNITS_PER_AXIS`² = 64 units (the sub-grid of
`records.RunRecorder`), float32, compressed: about 1 KB a frame (docs/pipeline.md gives the numbers).
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav.engine import EngineConfig
from hippo_nav.geometry import planar_from_pose, wrap_angle
from hippo_nav.io.atomic import open_atomic
from hippo_nav.io.errors import os_error_words
from hippo_nav.pipeline.records import RunResult
from hippo_nav.recording import Recording, RecordingError

__all__ = ["MODULE_PHASE_FILE", "RECORDING_FILE", "ModulePhases", "run_recording", "write_recording"]

RECORDING_FILE = "recording.npz"
MODULE_PHASE_FILE = "module_phase.npz"
_PHASE_FORMAT = "hippo_nav.module_phase/1"
_FALLBACK_FRAME_INTERVAL_S = 0.1  # KITTI's rate, for a run without usable timestamps


@dataclass
class ModulePhases:
    """Each grid module's decoded bump at every frame of a run, in the torus frame (module doc).

    `tracked_rad` (T, modules, 2): the followed bump's centre (θx, θy) on the torus; `start_tracked_rad`
    (modules, 2): the same before the first frame; `position_m` (T, modules, 2): the followed bump's
    unwrapped displacement since the start (m). NaN for a lesioned module. A module's decoded phase is
    `k·(tracked_rad − start_tracked_rad)` modulo 2π; the true one `2πk·x/P` with x the recording's
    `position_m`."""

    frame_index: np.ndarray
    timestamp_s: np.ndarray
    tracked_rad: np.ndarray
    start_tracked_rad: np.ndarray
    position_m: np.ndarray
    module_k: tuple[int, ...]
    torus_period_m: float

    def save(self, path: str | Path) -> Path:
        """Write one compressed `.npz`, atomically."""
        arrays: dict[str, Any] = {
            "frame_index": self.frame_index,
            "timestamp_s": self.timestamp_s,
            "tracked_rad": self.tracked_rad,
            "start_tracked_rad": self.start_tracked_rad,
            "position_m": self.position_m,
            "module_k": np.asarray(self.module_k, np.int64),
            "torus_period_m": np.array(self.torus_period_m),
            "format": np.array(_PHASE_FORMAT),
        }
        with open_atomic(path, "wb") as f:
            np.savez_compressed(f, **arrays)
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> ModulePhases:
        """Read `save`'s file; a missing or foreign one is a `RecordingError` naming it."""
        path = Path(path)
        try:
            # np.load given a name leaves the file open when it is not a zip archive: open it here.
            with path.open("rb") as f, np.load(f, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            if str(arrays["format"]) != _PHASE_FORMAT:
                raise ValueError(f"format {str(arrays['format'])!r}, expected {_PHASE_FORMAT!r}")
            _check_phase_shapes(arrays)
        except FileNotFoundError:
            raise RecordingError(f"{path}: no such file") from None
        except OSError as err:
            raise RecordingError(f"{path}: not readable ({os_error_words(err)})") from None
        except (ValueError, KeyError, EOFError, zipfile.BadZipFile) as err:
            raise RecordingError(f"{path}: not a readable module-phase file ({err})") from None
        return cls(
            frame_index=arrays["frame_index"],
            timestamp_s=arrays["timestamp_s"],
            tracked_rad=arrays["tracked_rad"],
            start_tracked_rad=arrays["start_tracked_rad"],
            position_m=arrays["position_m"],
            module_k=tuple(int(k) for k in arrays["module_k"]),
            torus_period_m=float(arrays["torus_period_m"]),
        )


def _check_phase_shapes(arrays: dict[str, np.ndarray]) -> None:
    """A ValueError naming the first array whose shape disagrees with a file of frames × modules."""
    frames, modules = arrays["frame_index"].shape[:1], arrays["module_k"].shape
    wanted = {
        "frame_index": frames,
        "timestamp_s": frames,
        "tracked_rad": (*frames, *modules, 2),
        "start_tracked_rad": (*modules, 2),
        "position_m": (*frames, *modules, 2),
        "module_k": modules,
        "torus_period_m": (),
    }
    for name, shape in wanted.items():
        if arrays[name].shape != shape:
            raise ValueError(f"{name} has shape {arrays[name].shape}, expected {shape}")


def _rotation(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s], [s, c]])


def _true_track(result: RunResult) -> tuple[np.ndarray, str]:
    """(n, 3) planar poses (map frame) of the animal's true track, and where they come from."""
    n = len(result.record)
    if result.ground_truth is not None:
        return planar_from_pose(result.ground_truth)[:n], "ground truth"
    return planar_from_pose(result.corrected_world_from_camera)[:n], "corrected map (no ground truth)"


def _frame_interval_s(timestamps_s: np.ndarray) -> float:
    steps = np.diff(timestamps_s)
    steps = steps[np.isfinite(steps) & (steps > 0)]
    return float(np.median(steps)) if len(steps) else _FALLBACK_FRAME_INTERVAL_S


def run_recording(result: RunResult, engine: EngineConfig, seed: int | None = None) -> Recording:
    """The run's `Recording` (module doc): `engine` is the engine config the run used (lesions applied)."""
    record = result.record
    n = len(record)
    turn = float(record.initial_heading_rad)
    track, source = _true_track(result)
    position_m = track[:, :2] @ _rotation(turn).T
    timestamps_s = np.asarray(record.column("timestamp_s"), np.float64)
    dt_s = _frame_interval_s(timestamps_s)
    # Speed from the true track over the frames' own times (a skipped frame is a longer interval).
    times_s = timestamps_s if np.all(np.diff(timestamps_s) > 0) else np.arange(n) * dt_s
    speed_m_s = np.linalg.norm(np.gradient(position_m, times_s, axis=0), axis=1) if n > 1 else np.zeros(n)
    populations = {name: np.stack(rows).astype(np.float32) for name, rows in record.unit_activity.items()}
    for name, phases in record.unit_phase_rad.items():  # a lesioned module: silent units (as a recording's)
        populations.setdefault(name, np.zeros((n, len(phases)), np.float32))
    metadata = {
        "source": "hippo-nav run",
        "sequence": result.name,
        "frames": n,
        "interrupted": bool(result.interrupted),
        "position_source": source,
        "frame": "torus: the first camera's ground plane (x forward, y left) turned by initial_heading_rad; "
        "origin at the first processed frame",
        "initial_heading_rad": turn,
        "time": "uniform, frame position × the median frame interval; timestamps in " + MODULE_PHASE_FILE,
        "module_phase_file": MODULE_PHASE_FILE,
        "seed": seed,
        "engine": json.loads(engine.to_json()),
    }
    return Recording(
        time_s=np.arange(n) * dt_s,
        position_m=position_m,
        heading_rad=np.asarray(wrap_angle(track[:, 2] + turn)),
        speed_m_s=speed_m_s,
        decoded_position_m=np.asarray(record.column("place_position_m"), np.float64).reshape(n, 2),
        decoded_heading_rad=np.asarray(record.column("heading_rad"), np.float64),
        populations=populations,
        unit_phase_rad=dict(record.unit_phase_rad),
        torus_period_m=float(engine.torus_period_m),
        module_k=tuple(grid.k for grid in engine.grid),
        lesioned=tuple(bool(b) for b in engine.lesioned),
        metadata=metadata,
    )


def run_module_phases(result: RunResult, engine: EngineConfig) -> ModulePhases:
    """Each grid module's decoded bump per frame (`ModulePhases`), from the run's record."""
    record = result.record
    k = len(engine.grid)
    start = record.start_tracked_rad
    return ModulePhases(
        frame_index=np.asarray(record.column("frame_index"), np.int64),
        timestamp_s=np.asarray(record.column("timestamp_s"), np.float64),
        tracked_rad=np.asarray(record.module_tracked_rad, np.float64).reshape(-1, k, 2),
        start_tracked_rad=np.full((k, 2), np.nan) if start is None else np.asarray(start, np.float64),
        position_m=np.asarray(record.module_position_m, np.float64).reshape(-1, k, 2),
        module_k=tuple(grid.k for grid in engine.grid),
        torus_period_m=float(engine.torus_period_m),
    )


def write_recording(
    result: RunResult, out: Path, engine: EngineConfig, seed: int | None = None
) -> list[Path]:
    """Write `recording.npz` and `module_phase.npz` into the results folder `out`; returns their paths
    (none for a run without frames)."""
    if len(result.record) == 0:
        return []
    return [
        run_recording(result, engine, seed).save(out / RECORDING_FILE),
        run_module_phases(result, engine).save(out / MODULE_PHASE_FILE),
    ]
