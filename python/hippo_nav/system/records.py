"""What the per-frame system reports: one `FrameRecord` per frame, and where each stage of a frame ends
(`StageTimer`; the runner keeps the times).

Frames: everything the system decided for one camera frame, in the units its name says. Planar poses are
`(x_m, y_m, yaw_rad)` in the map frame (`hippo_nav.geometry`); `vo_world_from_camera` is the 3-D
odometry (the built-in VO or a replayed trajectory) chained from the first processed frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

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
