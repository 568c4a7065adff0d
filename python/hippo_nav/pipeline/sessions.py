"""Every session's frames, re-corrected by the latest: the path a memory keeps, and the merged trajectory.

A run's corrected trajectory places each frame at its vertex's corrected pose ∘ the frame's offset from that
vertex (`assemble.corrected_track`). A memory keeps that anchoring for every frame of every session it holds
(`memory/path.npz`: `session`, `frame`, `timestamp_s`, `vertex`, `vertex_from_agent` (x, y, yaw)), so a later
session, whose closures move the loaded map's vertices, places the earlier sessions' frames again on the map as
it ends: `trajectory_sessions.tum.txt` holds every frame of every session (earlier sessions first, this run's
last; planar, at height 0), and `metrics.json` `sessions` says how many of each and, when the memory's
ground truth is of the same sequence (`truth.py`), the ATE (2-D) of all of them against it — the map of
several days as one map. A memory written before `path.npz` existed places only the new session's frames.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.geometry import lift_planar, se2_compose
from hippo_nav.memory import SavedMemory
from hippo_nav.metrics import ate_errors
from hippo_nav.pipeline.records import RunRecord
from hippo_nav.pipeline.truth import LoadedTruth

log = logging.getLogger("hippo_nav.pipeline")

__all__ = ["SessionsTrack", "path_to_save", "sessions_metrics", "sessions_track"]

_COLUMNS = {"session": 1, "frame": 1, "timestamp_s": 1, "vertex": 1, "vertex_from_agent": 3}


@dataclass(frozen=True)
class SessionsTrack:
    """Every frame of every session, placed on this run's corrected map (module doc)."""

    session: np.ndarray  # (n,) int: 0 the first session
    timestamp_s: np.ndarray  # (n,)
    planar: np.ndarray  # (n, 3) x, y, yaw in the map frame
    earlier_frames: int  # how many come from the loaded memory (they come first)

    def world_from_camera(self) -> np.ndarray:
        """(n, 4, 4) poses at height 0, level (the earlier sessions' heights are not kept)."""
        return lift_planar(self.planar, np.eye(4))


def _loaded_path(memory: SavedMemory | None) -> dict[str, np.ndarray] | None:
    """The loaded memory's path arrays, or None (no memory, one written before paths were kept, or a
    damaged one: it costs the earlier sessions' trajectory, never the run)."""
    if memory is None or not memory.path:
        return None
    path = memory.path
    try:
        n = len(path["session"])
        for name, columns in _COLUMNS.items():
            array = np.asarray(path[name])
            shape_ok = array.shape == ((n,) if columns == 1 else (n, columns))
            if not shape_ok or not (np.issubdtype(array.dtype, np.number) and array.dtype != np.complex128):
                raise ValueError(f"{name}: {array.dtype} {array.shape}")
            if not np.isfinite(array).all():
                raise ValueError(f"{name} holds NaN or infinity")
    except (KeyError, ValueError, IndexError, TypeError) as err:
        log.warning(
            "the loaded memory's path.npz is not usable (%s); earlier sessions are not re-placed", err
        )
        return None
    return {name: np.asarray(path[name]) for name in _COLUMNS}


def path_to_save(memory: SavedMemory | None, record: RunRecord, resumed: bool) -> dict[str, np.ndarray]:
    """What `path.npz` holds after this run: the loaded memory's path, then this run's frames as the next
    session (`resumed`: the same session, continued)."""
    earlier = _loaded_path(memory)
    session = 0
    if earlier is not None and len(earlier["session"]):
        session = int(earlier["session"].max()) + (0 if resumed else 1)
    here: dict[str, np.ndarray] = {
        "session": np.full(len(record), session, np.int32),
        "frame": np.asarray(record.column("frame_index"), np.int64),
        "timestamp_s": np.asarray(record.column("timestamp_s"), np.float64),
        "vertex": np.asarray(record.column("vertex"), np.int64),
        "vertex_from_agent": np.asarray(record.column("vertex_from_agent"), np.float64).reshape(-1, 3),
    }
    if earlier is None:
        return here
    return {name: np.concatenate([earlier[name].astype(here[name].dtype), here[name]]) for name in _COLUMNS}


def sessions_track(
    memory: SavedMemory | None, record: RunRecord, vertex_poses: np.ndarray, corrected: np.ndarray
) -> SessionsTrack | None:
    """The earlier sessions' frames placed on the corrected map (`vertex_poses`), then this run's
    (`corrected`, planar); None when no memory with a path was loaded."""
    earlier = _loaded_path(memory)
    if earlier is None:
        return None
    vertex, offset = earlier["vertex"], earlier["vertex_from_agent"]
    placed = np.full((len(vertex), 3), np.nan)
    ok = (vertex >= 0) & (vertex < len(vertex_poses)) & np.isfinite(offset).all(axis=1)
    if ok.any():
        placed[ok] = se2_compose(vertex_poses[vertex[ok]], offset[ok])
    this_session = int(earlier["session"].max()) + 1 if len(vertex) else 0
    return SessionsTrack(
        session=np.concatenate([earlier["session"], np.full(len(record), this_session)]).astype(np.int32),
        timestamp_s=np.concatenate([earlier["timestamp_s"], np.asarray(record.column("timestamp_s"))]),
        planar=np.concatenate([placed, corrected]),
        earlier_frames=len(vertex),
    )


def sessions_metrics(
    track: SessionsTrack,
    loaded: LoadedTruth | None,
    ground_truth: np.ndarray | None,
    why_unscored: str | None,
) -> dict[str, Any]:
    """`metrics.json` `sessions`: frames per session and, with a comparable truth, the ATE (2-D) of every
    frame of every session (`ground_truth`: this run's, rebased; `loaded`: the memory's, in the same frame)."""
    sessions, counts = np.unique(track.session, return_counts=True)
    out: dict[str, Any] = {"frames": dict(zip(map(str, sessions.tolist()), counts.tolist()))}
    placed = np.isfinite(track.planar).all(axis=1)
    out["unplaced_frames"] = int((~placed).sum())
    if loaded is None or ground_truth is None:
        out["unscored"] = why_unscored or "this run has no ground truth"
        return out
    truth = np.concatenate([loaded.path_position_m, np.asarray(ground_truth)[:, :3, 3]])
    if len(truth) != len(track.planar):
        out["unscored"] = (
            f"the memory's truth holds {len(loaded.path_position_m)} earlier frames, its path "
            f"{track.earlier_frames}: an earlier session had no ground truth of this sequence"
        )
        return out
    truth_poses = np.tile(np.eye(4), (len(truth), 1, 1))
    truth_poses[:, :3, 3] = truth
    try:
        errors = ate_errors(truth_poses[placed], track.world_from_camera()[placed], planar=True, align="se3")
    except HippoNavError as err:
        # No alignment (e.g. no frame placed, or every one at the same point: a session that never moved):
        # unscored, as a trajectory's errors are — never a run's results lost over a score.
        log.warning("the sessions' errors are unavailable: %s", err)
        out["unscored"] = str(err)
        return out
    out["ate_2d_m"] = float(np.sqrt(np.mean(errors**2)))
    # The earlier sessions' frames alone, in the alignment of all of them.
    earlier = (np.arange(len(truth)) < track.earlier_frames)[placed]
    if earlier.any():
        out["ate_2d_m_earlier_sessions"] = float(np.sqrt(np.mean(errors[earlier] ** 2)))
    return out
