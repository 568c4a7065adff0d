"""What a run records: one `FrameRecord` per processed frame, and the `RunResult` it ends with.

Frames: everything the system decided for one camera frame, in the units its name says. Planar poses are
`(x_m, y_m, yaw_rad)` in the map frame (`hippo_nav.geometry`); `vo_world_from_camera` is the 3-D
odometry (the built-in VO or a replayed trajectory) chained from the first processed frame.
`RunRecord.column(name)` (or the attribute of the same name) gives one field over all frames.

The runner keeps the `RunRecord` (`RunRecorder`: the frames, and the neural data the figures need, read
from the engine after each frame) and times every stage of a frame (`StageTimer`); the per-frame system
only reports where one stage ends and the next begins.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav.engine import N_MODULES, SpatialMemory, SpatialReadout

STAGES = ("load", "vo", "views", "engine", "closure", "map", "record")
"""Per-frame stages whose wall time is measured (seconds per frame in `RunRecord.stage_s`)."""


@dataclass(frozen=True)
class FrameRecord:
    """One processed frame."""

    frame_index: int  # frame number in the sequence
    timestamp_s: float
    vo_world_from_camera: np.ndarray  # (4, 4) odometry pose
    vo_status: str  # the odometry's status ("ok", "first", "low_texture", "failed", …)
    motion_flag: str  # "ok", "clamped", "engine_skipped" or "vo:<status>"
    yaw_rate_rad_s: float  # what the engine integrated
    speed_m_s: float
    view_cell: int  # NO_VIEW_CELL (-1): no informative view
    view_status: str  # "new", "familiar", "uninformative", "none"
    view_difference: float
    injection_strength: float
    heading_rad: float  # HD ring's heading
    place_code_rad: tuple[float, float]  # place bump on the torus
    place_position_m: tuple[float, float]  # unwrapped place code
    vertex: int  # current map vertex (-1 while lost)
    vertex_created: bool
    loop_closure: tuple[int, int] | None  # (from, to) of the loop link added this frame
    closure_note: str  # "" (no attempt), "accepted" ("accepted_proximity": proposed by proximity), or why not
    data_flags: str  # "" or ";"-joined: "skipped_frames:N" (sequence frames missing before), "time_gap:Ts"
    online_pose: np.ndarray  # (3,) the map's agent pose as the run went
    vertex_from_agent: np.ndarray  # (3,) offset from the current vertex (NaN while lost)


_COLUMNS = {f.name for f in fields(FrameRecord)}


@dataclass
class RunRecord:
    """Every processed frame, per-stage wall times, and the neural data the figures need."""

    frames: list[FrameRecord] = field(default_factory=list)
    stage_s: dict[str, list[float]] = field(default_factory=lambda: {s: [] for s in STAGES})
    # Sub-sampled unit activities for the firing-rate maps: name -> list of (units,) float32 arrays.
    unit_activity: dict[str, list[np.ndarray]] = field(default_factory=dict)
    # Full network snapshots at chosen frames: frame position -> dict of arrays and the readout.
    snapshots: dict[int, dict[str, Any]] = field(default_factory=dict)
    # The run position (index into `frames`) at which each map vertex was made.
    vertex_position: dict[int, int] = field(default_factory=dict)
    # Wall time of the frame loop (s): with the front end frames ahead, less than the stages' sum.
    wall_s: float = 0.0

    def __len__(self) -> int:
        return len(self.frames)

    def append(self, frame: FrameRecord) -> None:
        if frame.vertex_created and frame.vertex >= 0:
            self.vertex_position[frame.vertex] = len(self.frames)
        self.frames.append(frame)

    def column(self, name: str) -> list[Any]:
        """One field of every frame, in order."""
        if name not in _COLUMNS:
            raise AttributeError(f"FrameRecord has no field {name!r}")
        return [getattr(f, name) for f in self.frames]

    def __getattr__(self, name: str) -> list[Any]:
        # Only called for names that are not attributes: the per-frame columns.
        if name in _COLUMNS:
            return self.column(name)
        raise AttributeError(f"{type(self).__name__!s} has no attribute {name!r}")


@dataclass
class RunResult:
    """What `Pipeline.run` produced; `out_dir` holds the written files (None when not writing).

    3-D trajectories are (n, 4, 4) `world_from_camera` in the camera frame of the first processed frame.
    The map's and the networks' estimates are planar; their 3-D poses carry the odometry's height,
    pitch and roll (`hippo_nav.geometry.lift_planar`), so 3-D metrics compare like with like."""

    name: str
    record: RunRecord
    metrics: dict[str, Any]
    vo_world_from_camera: np.ndarray
    online_world_from_camera: np.ndarray
    corrected_world_from_camera: np.ndarray
    neural_world_from_camera: np.ndarray
    ground_truth: np.ndarray | None  # rebased to the first processed frame
    map_export: dict[str, np.ndarray]
    interrupted: bool
    out_dir: Path | None = None

    @property
    def estimates(self) -> dict[str, np.ndarray]:
        """The four trajectories by name."""
        return {
            "vo": self.vo_world_from_camera,
            "online": self.online_world_from_camera,
            "corrected": self.corrected_world_from_camera,
            "neural": self.neural_world_from_camera,
        }


class StageTimer:
    """Wall time per stage of a frame, appended to `stage_s` (a `RunRecord.stage_s`): `lap(stage)` closes
    the stage that began at the previous lap (or at `restart`). Without `stage_s`, it measures nothing."""

    def __init__(self, stage_s: dict[str, list[float]] | None = None) -> None:
        self._stage_s = stage_s
        self._since = time.perf_counter()

    def restart(self) -> None:
        self._since = time.perf_counter()

    def lap(self, stage: str) -> None:
        if self._stage_s is None:
            return
        now = time.perf_counter()
        self._stage_s[stage].append(now - self._since)
        self._since = now


class RunRecorder:
    """Keeps a run's `RunRecord`: each frame's record, a regular sub-grid of every network's units (for the
    rate maps; every `unit_stride`-th unit per axis) and full network snapshots at `state_frames` (run
    positions; the last frame's is added by `final_snapshot`)."""

    def __init__(self, state_frames: Sequence[int], unit_stride: int) -> None:
        self.record = RunRecord()
        self._state_frames = set(state_frames)
        self._unit_stride = max(int(unit_stride), 1)

    def add(self, frame: FrameRecord, engine: SpatialMemory, readout: SpatialReadout) -> None:
        """Record a processed frame, with the engine's state after it."""
        self.record.append(frame)
        self._record_units(engine)
        self._snapshot(len(self.record) - 1, engine, readout=readout)

    def final_snapshot(self, engine: SpatialMemory) -> None:
        """The network at the last processed frame (figures always show it)."""
        self._snapshot(len(self.record) - 1, engine, final=True)

    def _record_units(self, engine: SpatialMemory) -> None:
        s = self._unit_stride
        acts = self.record.unit_activity
        for m, grid in enumerate(engine.config.grid):
            if engine.config.lesioned[m]:
                continue
            name = f"grid k={grid.k}"
            acts.setdefault(name, []).append(
                np.asarray(engine.grid_layer2(m)[::s, ::s], dtype=np.float32).ravel()
            )
        acts.setdefault("place", []).append(
            np.asarray(engine.place_activity()[::s, ::s], dtype=np.float32).ravel()
        )

    def _snapshot(
        self,
        position: int,
        engine: SpatialMemory,
        final: bool = False,
        readout: SpatialReadout | None = None,
    ) -> None:
        record = self.record
        if not (final or position in self._state_frames) or position in record.snapshots:
            return
        sm = engine
        record.snapshots[position] = {
            "frame_index": record.frames[position].frame_index,
            "hd": sm.hd_activity(),
            "grid": [None if sm.config.lesioned[m] else sm.grid_activity(m) for m in range(N_MODULES)],
            "layer2": [None if sm.config.lesioned[m] else sm.grid_layer2(m) for m in range(N_MODULES)],
            "place": sm.place_activity(),
            "k": [g.k for g in sm.config.grid],
            "nu_max": [g.nu_max for g in sm.config.grid],
            "hd_nu_max": sm.config.hd.nu_max,
            "readout": readout if readout is not None else sm.readout(),
        }
