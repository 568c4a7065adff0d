"""The ground truth a memory keeps so that a later session's closures onto it are scored like any other.

A run with a ground truth saves, in `memory/truth.npz` (`hippo_nav.memory`, for scoring only: the system never
reads it):
- `vertex_position_m` (vertices, 3): where each vertex of the map was made, in the dataset's own ground-truth
  frame (NaN where unknown: a vertex of an earlier session without a truth, or with one in another frame);
- `path_position_m` (frames, 3): the true position of every frame of every session the memory holds;
and in `memory.json` `truth.source`: the dataset's name (`kitti_00`).

Ground truths are comparable only in one frame. A later session on a dataset of the same name (the same
sequence: two slices of one KITTI sequence, or a render along its ground truth) takes them back, moved into its
own results' frame (rebased to its first frame): a closure onto a loaded vertex is true when the two places lie
within 5 m (`results.closure_quality`), and a frame within 5 m of where an earlier session went is a revisit.
Another name: the loaded map's closures are left unscored and `metrics.json` says why.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from hippo_nav.memory import SavedMemory
from hippo_nav.pipeline.records import RunRecord

log = logging.getLogger("hippo_nav.pipeline")

__all__ = ["LoadedTruth", "loaded_truth", "truth_to_save"]


@dataclass(frozen=True)
class LoadedTruth:
    """A loaded memory's truth in this run's results frame (the ground truth rebased to the first frame)."""

    vertex_position_m: np.ndarray  # (loaded vertices, 3), NaN where unknown
    path_position_m: np.ndarray  # (frames of the earlier sessions, 3)


def _saved_arrays(memory: SavedMemory | None, source: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The loaded memory's truth arrays in the dataset's frame when they are of `source`, else None."""
    if memory is None or not memory.truth:
        return None
    if (memory.info.get("truth") or {}).get("source") != source:
        return None
    vertex, path = memory.truth.get("vertex_position_m"), memory.truth.get("path_position_m")
    for array in (vertex, path):
        if (
            array is None
            or array.ndim != 2
            or array.shape[1] != 3
            or not np.issubdtype(array.dtype, np.floating)
        ):
            # Scoring only: a damaged truth costs the scores, never the run.
            log.warning("the loaded memory's truth.npz holds no usable positions; its closures go unscored")
            return None
    assert vertex is not None and path is not None
    return vertex.astype(np.float64), path.astype(np.float64)


def loaded_truth(
    memory: SavedMemory | None, source: str, ground_truth: np.ndarray | None
) -> tuple[LoadedTruth | None, str | None]:
    """The loaded memory's truth moved into this run's results frame, or None and why (None: nothing
    loaded). `ground_truth`: this run's, in the dataset's frame (n, 4, 4)."""
    if memory is None:
        return None, None
    if ground_truth is None or len(ground_truth) == 0:
        return None, "this run has no ground truth"
    saved = _saved_arrays(memory, source)
    if saved is None:
        was = (memory.info.get("truth") or {}).get("source")
        why = (
            "the loaded map was saved without a ground truth"
            if was is None
            else (f"the loaded map's ground truth is of {was!r}, this run's of {source!r} (another frame)")
        )
        return None, why
    first_from_world = np.linalg.inv(np.asarray(ground_truth[0], dtype=np.float64))

    def moved(points: np.ndarray) -> np.ndarray:
        return points @ first_from_world[:3, :3].T + first_from_world[:3, 3]

    return LoadedTruth(moved(saved[0]), moved(saved[1])), None


def truth_to_save(
    memory: SavedMemory | None,
    source: str,
    ground_truth: np.ndarray | None,
    record: RunRecord,
    vertices: int,
) -> tuple[dict[str, np.ndarray], dict[str, Any]] | None:
    """What `truth.npz` and the manifest's `truth` hold for a memory of `vertices` vertices after this run
    (`memory`: the one it started inside, or None), or None when this run has no ground truth."""
    if ground_truth is None or len(ground_truth) < len(record) or len(record) == 0:
        return None
    here = np.asarray(ground_truth, dtype=np.float64)[: len(record), :3, 3]
    vertex = np.full((vertices, 3), np.nan)
    path = here
    saved = _saved_arrays(memory, source)
    if saved is not None:
        earlier = min(len(saved[0]), vertices)
        vertex[:earlier] = saved[0][:earlier]
        path = np.concatenate([saved[1], here])
    for made, position in record.vertex_position.items():
        if 0 <= made < vertices:
            vertex[made] = here[position]
    return {"vertex_position_m": vertex, "path_position_m": path}, {"source": source}
