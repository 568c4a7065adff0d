"""The end of a run as a pure function: the record and the corrected map become the four trajectories.

- `vo`: the odometry's `vo_world_from_camera`, chained from the first processed frame.
- `online`: the map's agent pose at each frame as the run went.
- `corrected`: every frame's pose after the final correction, its vertex's corrected pose ∘ the frame's
  offset from that vertex (`corrected_track`).
- `neural`: the networks' own estimate in the map frame, the unwrapped place-code displacement and the
  HD heading, relative to the heading code they started with (`neural_track`).

The planar ones are lifted to 3-D with the odometry's height, pitch and roll (`geometry.lift_planar`), so
3-D metrics compare like with like. The ground truth is rebased to the first processed frame.
"""

from __future__ import annotations

import numpy as np

from hippo_nav.geometry import lift_planar, se2_compose
from hippo_nav.pipeline.records import RunRecord, RunResult

__all__ = ["assemble_result", "corrected_track", "neural_track"]


def corrected_track(record: RunRecord, vertex_poses: np.ndarray) -> np.ndarray:
    """(n, 3) planar pose of every frame after correction: its vertex's corrected pose ∘ its offset.
    Frames without a vertex (never, unless relocalising) keep their online pose."""
    vertex = np.asarray(record.column("vertex"))
    offset = np.stack(record.column("vertex_from_agent"))
    online = np.stack(record.column("online_pose"))
    track = online.copy()
    ok = (vertex >= 0) & np.isfinite(offset).all(axis=1)
    if ok.any():
        track[ok] = se2_compose(vertex_poses[vertex[ok]], offset[ok])
    return track


def neural_track(record: RunRecord, initial_heading_rad: float) -> np.ndarray:
    """(n, 3) planar poses of the networks' estimate: their displacement and heading code relative to the
    heading code they started with (`initial_heading_rad`)."""
    h0 = initial_heading_rad
    displacement = np.asarray(record.column("place_position_m"))
    c, s = np.cos(h0), np.sin(h0)
    return np.column_stack(
        [
            c * displacement[:, 0] + s * displacement[:, 1],
            -s * displacement[:, 0] + c * displacement[:, 1],
            np.asarray(record.column("heading_rad")) - h0,
        ]
    )


def assemble_result(
    name: str,
    record: RunRecord,
    map_export: dict[str, np.ndarray],
    initial_heading_rad: float,
    ground_truth: np.ndarray | None,
    interrupted: bool,
) -> RunResult:
    """The `RunResult` of a run (metrics still empty): `map_export` is the corrected map's
    `ExperienceMap.export()`, `ground_truth` the dataset's (len ≥ frames processed, or None)."""
    vo = np.stack(record.column("vo_world_from_camera"))
    online = np.stack(record.column("online_pose"))
    corrected = corrected_track(record, map_export["poses"])
    neural = neural_track(record, initial_heading_rad)
    gt = None
    if ground_truth is not None:
        gt = np.asarray(ground_truth)[: len(record)]
        gt = np.linalg.inv(gt[0]) @ gt
    return RunResult(
        name=name,
        record=record,
        metrics={},
        vo_world_from_camera=vo,
        online_world_from_camera=lift_planar(online, vo),
        corrected_world_from_camera=lift_planar(corrected, vo),
        neural_world_from_camera=lift_planar(neural, vo),
        ground_truth=gt,
        map_export=map_export,
        interrupted=interrupted,
    )
