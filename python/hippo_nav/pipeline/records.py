"""What a run records: the system's `FrameRecord` of every processed frame (`hippo_nav.system.records`), and
the `RunResult` it ends with. `RunRecord.column(name)` (or the attribute of the same name) gives one field
over all frames. The runner keeps the `RunRecord` (`RunRecorder`: the frames, and the neural data the
figures need, read from the engine after each frame) and the time of every stage of a frame
(`hippo_nav.system.records.StageTimer`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav.engine import N_MODULES, SpatialMemory, SpatialReadout
from hippo_nav.system.records import STAGES, FrameRecord

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
    # CPU time of the whole process over the frame loop (s), every thread: what a frame costs the machine.
    cpu_s: float = 0.0

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
