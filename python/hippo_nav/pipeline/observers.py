"""Watching a run: observers receive data, never the system.

After every processed frame the runner calls `observer.on_frame(event)` with a frozen `FrameEvent` — the
frame, its `FrameRecord`, the networks' readout, the odometry's tracked features, the map's size and the
run's facts — and after the run `observer.on_finish(result)` with the `RunResult`. What costs time to read
(the networks' activity, the map's arrays) is read only when an observer asks for it, once per event; it
describes the system right after that frame, so it must be read during `on_frame` (or, for the last
frame, up to `on_finish`): reading it later raises. Observers must not change what they are given.

```python
from hippo_nav.pipeline import FrameEvent, run

class VertexCounter:
    def __init__(self) -> None:
        self.vertices: list[int] = []

    def on_frame(self, event: FrameEvent) -> None:
        self.vertices.append(len(event.vertex_poses))          # read now, only because it is asked for

    def on_finish(self, result) -> None:
        print(f"{len(self.vertices)} frames, {self.vertices[-1]} vertices")

run(None, stop=10, progress=False, observers=[VertexCounter()])   # 10 frames, … vertices
```
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Protocol

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.datasets.base import StereoFrame
from hippo_nav.engine import SpatialMemory, SpatialReadout
from hippo_nav.geometry import planar_xy
from hippo_nav.system.records import FrameRecord

if TYPE_CHECKING:
    from hippo_nav.pipeline.records import RunResult
    from hippo_nav.system.slam import SlamSystem

__all__ = ["FrameEvent", "NetworkActivity", "Observer", "ObserverError", "RunInfo"]


class ObserverError(HippoNavError):
    """An observer could not finish (a video or recording on a full disk) after the run's results were
    written; `result` holds the run's `RunResult`."""


class Observer(Protocol):
    """Watches a run (module doc). Live viewers and video writers are observers."""

    def on_frame(self, event: FrameEvent) -> None: ...

    def on_finish(self, result: RunResult) -> None: ...


@dataclass(frozen=True)
class NetworkActivity:
    """Every network's activity at one moment: the HD-by-velocity ring (Nν, Nθ), each grid module's
    layer-II pattern (N, N) = (θy, θx) (None when lesioned), the CA3 place torus (N, N), and the modules'
    wave numbers k."""

    hd: np.ndarray
    layer2: tuple[np.ndarray | None, ...]
    place: np.ndarray
    ks: tuple[int, ...]

    @classmethod
    def of(cls, engine: SpatialMemory) -> NetworkActivity:
        config = engine.config
        layer2 = tuple(None if off else engine.grid_layer2(m) for m, off in enumerate(config.lesioned))
        return cls(engine.hd_activity(), layer2, engine.place_activity(), tuple(g.k for g in config.grid))


@dataclass(frozen=True)
class RunInfo:
    """What observers know of the run as a whole: its name, its length in frames, and the dataset's
    ground truth in the map frame (read when first asked for)."""

    name: str
    frames: int
    _ground_truth: Callable[[], np.ndarray | None] = field(repr=False, compare=False)

    @cached_property
    def ground_truth_xy(self) -> np.ndarray | None:
        """(frames, 2) map-frame positions of the ground truth, rebased on the first frame like the results'
        `ground_truth`; None without one."""
        gt = self._ground_truth()
        if gt is None:
            return None
        gt = np.asarray(gt, dtype=np.float64)
        if gt.ndim != 3 or len(gt) == 0:
            return None
        return planar_xy(np.linalg.inv(gt[0]) @ gt)


@dataclass(frozen=True)
class FrameEvent:
    """One processed frame, as observers see it (module doc)."""

    position: int  # run position (0 for the first processed frame)
    frame: StereoFrame
    record: FrameRecord
    readout: SpatialReadout
    features_px: np.ndarray | None  # (n, 2) left-image features the odometry tracked in this frame
    view_cells: int  # view cells so far
    vertices: int  # map vertices so far
    view_rows: tuple[int, int] | None  # image rows the view descriptor looks at (None: all)
    previous_stage_s: Mapping[str, float] | None  # every stage's wall time of the previous frame (s)
    run: RunInfo
    _system: SlamSystem = field(repr=False, compare=False)
    _map_revision: int = field(repr=False, compare=False)  # the system's `map_revision` after this frame

    def _live(self, part: str) -> SlamSystem:
        system = self._system
        moved = system.frames != self.position + 1
        if moved or (part == "map" and system.map_revision != self._map_revision):
            raise HippoNavError(
                f"frame {self.record.frame_index}'s {part} was read after the system moved on; read what an "
                "observer needs of the networks and the map during on_frame"
            )
        return system

    @cached_property
    def network(self) -> NetworkActivity:
        """The networks' activity after this frame."""
        return NetworkActivity.of(self._live("network").engine)

    @cached_property
    def vertex_poses(self) -> np.ndarray:
        """(N, 3) map vertex poses `(x_m, y_m, yaw_rad)` after this frame."""
        return np.asarray(self._live("map").map.poses(), dtype=np.float64).reshape(-1, 3)

    @cached_property
    def map_export(self) -> dict[str, np.ndarray]:
        """The whole map as arrays after this frame (`ExperienceMap.export`)."""
        return {k: np.asarray(v) for k, v in self._live("map").map.export().items()}
