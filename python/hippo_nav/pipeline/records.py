"""What a run records: the system's `FrameRecord` of every processed frame (`hippo_nav.system.records`), and
the `RunResult` it ends with. `RunRecord.column(name)` (or the attribute of the same name) gives one field
over all frames. The runner keeps the `RunRecord` (`RunRecorder`: the frames, and the neural data the
figures and the recording need, read from the engine after each frame) and the time of every stage of a
frame (`hippo_nav.system.records.StageTimer`).

Recorded units (`RunRecord.unit_activity`, named as `hippo_nav.recording`'s populations): of every network
a regular sub-grid of at most `units_per_axis` units per torus axis (the HD ring: `units_per_axis²` units
around it). A grid module's layer II is k² identical copies of one `(N/k)²` unit cell (docs/model.md), so
the sub-grid is taken in the unit cell: every sampled unit is a different one. Unit `(i, j)` (row-major,
θy then θx) has phase `(2πj/N, 2πi/N)` (`RunRecord.unit_phase_rad`); an HD unit i, `2πi/Nθ`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hippo_nav.engine import N_MODULES, SpatialMemory, SpatialReadout
from hippo_nav.recording.session import GRID_POPULATIONS
from hippo_nav.system.records import STAGES, FrameRecord

if TYPE_CHECKING:
    from hippo_nav.pipeline.sessions import SessionsTrack

UNITS_PER_AXIS = 8
"""Units kept per torus axis of every network (`RunRecorder`): 64 per population, a few MB over a
4 500-frame drive (docs/pipeline.md, `recording.npz`)."""

_COLUMNS = {f.name for f in fields(FrameRecord)}


@dataclass
class RunRecord:
    """Every processed frame, per-stage wall times, and the neural data the figures need."""

    frames: list[FrameRecord] = field(default_factory=list)
    stage_s: dict[str, list[float]] = field(default_factory=lambda: {s: [] for s in STAGES})
    # Sub-sampled unit activities (module doc): population name -> list of (units,) float32 arrays.
    unit_activity: dict[str, list[np.ndarray]] = field(default_factory=dict)
    # Each population's sampled units' phases: (units,) rad for "hd", (units, 2) (θx, θy) rad otherwise.
    unit_phase_rad: dict[str, np.ndarray] = field(default_factory=dict)
    # Per frame, each grid module's followed bump (θx, θy, rad) and its unwrapped displacement (m), in the
    # engine's frame: (N_MODULES, 2) arrays, NaN for a lesioned module.
    module_tracked_rad: list[np.ndarray] = field(default_factory=list)
    module_position_m: list[np.ndarray] = field(default_factory=list)
    # Before the first frame: the followed bumps' phases (N_MODULES, 2) and the heading code the networks
    # started with (rad; the engine's frame is the map frame turned by it).
    start_tracked_rad: np.ndarray | None = None
    initial_heading_rad: float = 0.0
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
    # A session inside a loaded map: every session's frames on this run's corrected map (`pipeline.sessions`).
    sessions: SessionsTrack | None = None

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
    """Keeps a run's `RunRecord`: each frame's record, a regular sub-grid of every network's units and each
    grid module's decoded bump (module doc), and full network snapshots at `state_frames` (run positions;
    the last frame's is added by `final_snapshot`). `start`: the engine before the first frame, with the
    heading code it started with (`initial_heading_rad`): the origin of the recorded phases."""

    def __init__(
        self,
        state_frames: Sequence[int],
        units_per_axis: int = UNITS_PER_AXIS,
        start: SpatialMemory | None = None,
        initial_heading_rad: float = 0.0,
    ) -> None:
        self.record = RunRecord(initial_heading_rad=float(initial_heading_rad))
        self._state_frames = set(state_frames)
        self._units_per_axis = max(int(units_per_axis), 1)
        if start is not None:
            tracked, _ = _module_readout(start.readout(), start.config.lesioned)
            self.record.start_tracked_rad = tracked

    def add(self, frame: FrameRecord, engine: SpatialMemory, readout: SpatialReadout) -> None:
        """Record a processed frame, with the engine's state after it."""
        self.record.append(frame)
        self._record_units(engine)
        tracked, position = _module_readout(readout, engine.config.lesioned)
        self.record.module_tracked_rad.append(tracked)
        self.record.module_position_m.append(position)
        self._snapshot(len(self.record) - 1, engine, readout=readout)

    def final_snapshot(self, engine: SpatialMemory) -> None:
        """The network at the last processed frame (figures always show it)."""
        self._snapshot(len(self.record) - 1, engine, final=True)

    def _record_units(self, engine: SpatialMemory) -> None:
        n = self._units_per_axis
        acts, phases = self.record.unit_activity, self.record.unit_phase_rad
        # name -> (unit cell side, units per torus axis, the cell's pattern; None when lesioned)
        patterns: dict[str, tuple[int, int, np.ndarray | None]] = {}
        for m, grid in enumerate(engine.config.grid):
            cell = grid.n_theta // grid.k
            live = not engine.config.lesioned[m]
            patterns[GRID_POPULATIONS[m]] = (
                cell,
                grid.n_theta,
                engine.grid_layer2(m)[:cell, :cell] if live else None,
            )
        place_n = engine.config.place.n_theta
        patterns["place"] = (place_n, place_n, engine.place_activity())
        for name, (side, n_theta, pattern) in patterns.items():
            index = sampled_units(side, n)
            if pattern is not None:  # a lesioned module is silent: no activity, but its units' phases
                acts.setdefault(name, []).append(
                    np.asarray(pattern[np.ix_(index, index)], np.float32).ravel()
                )
            if name not in phases:
                theta_y, theta_x = np.meshgrid(index, index, indexing="ij")
                phases[name] = 2 * np.pi / n_theta * np.column_stack([theta_x.ravel(), theta_y.ravel()])
        profile = engine.hd_profile()
        index = sampled_units(len(profile), n * n)
        acts.setdefault("hd", []).append(np.asarray(profile[index], np.float32))
        phases.setdefault("hd", 2 * np.pi / len(profile) * index)

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


def sampled_units(side: int, at_most: int) -> np.ndarray:
    """Indices of a regular sample of at most `at_most` of `side` units along one axis (every
    `ceil(side / at_most)`-th, from 0)."""
    stride = max(-(-side // max(at_most, 1)), 1)
    return np.arange(0, side, stride)


def _module_readout(readout: SpatialReadout, lesioned: Sequence[bool]) -> tuple[np.ndarray, np.ndarray]:
    """Each grid module's followed bump (rad) and unwrapped displacement (m), (N_MODULES, 2) each; NaN
    for a lesioned module (its readout is the last one before the lesion)."""
    tracked = np.full((N_MODULES, 2), np.nan)
    position = np.full((N_MODULES, 2), np.nan)
    for m, module in enumerate(readout.modules):
        if not lesioned[m]:
            tracked[m], position[m] = module.tracked_rad, module.position_m
    return tracked, position
