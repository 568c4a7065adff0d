"""The keyframe store: what each map vertex keeps so that a later visit can measure its pose, shared by every
proposer of the chain.

A new vertex keeps its frame's stereo keyframe (`keyframes.py`): the one a proposer already extracted
for this frame (`current()`, once a frame whoever asks), or one extracted on the slow-work `Worker` beside the
next frame's odometry (it is first needed when the agent comes back, at least `min_loop_separation_m` later).
With `keyframe_spacing_m` > 0, a vertex made less than that far (odometer) after the last kept keyframe keeps
none unless a proposer extracted it anyway: a SIFT keyframe costs about a quarter of a real KITTI frame's CPU, and
a revisit measures the keyframed vertices near it (`keyframed`; the confirmation takes the nearest keyframed
neighbour on each side).
`measure` measures a vertex's keyframe from the current frame (`measure.py`, stereo PnP) and remembers which
vertices were measured this frame, so a later proposer of the chain does not measure one again;
`confirmed` is the neighbour confirmation that view-cell and proximity proposals below their own bar need.
The store is what a memory folder saves of the closure (`export_state`, `restore_state`; docs/memory.md).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from concurrent.futures import Future

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.closure.config import ClosureConfig
from hippo_nav.closure.keyframes import DESCRIPTOR_BYTES, Keyframe, KeyframeExtractor
from hippo_nav.closure.measure import LoopMeasurement, LoopMeasurer
from hippo_nav.datasets.base import StereoCalibration, StereoFrame
from hippo_nav.geometry import se2_between, se2_compose
from hippo_nav.map import ExperienceMap, MapFrameOutcome
from hippo_nav.memory import split_ragged, stack_ragged
from hippo_nav.workers import Worker

log = logging.getLogger("hippo_nav.pipeline")

__all__ = ["KeyframeStore"]

_NEIGHBOUR_REACH = 4  # vertex ids the confirmation looks along the path for a keyframed neighbour


class KeyframeStore:
    """Vertex → stereo keyframe, this frame's keyframe, and the measurements against them (module doc)."""

    def __init__(
        self,
        calibration: StereoCalibration,
        config: ClosureConfig | None = None,
        *,
        disparity_offset_px: float = 0.0,
    ) -> None:
        self.config = config if config is not None else ClosureConfig()
        self.extract = KeyframeExtractor(calibration, self.config, disparity_offset_px)
        self.measurer = LoopMeasurer(calibration, self.config)
        # The confirming neighbour: measured at its own bar, with any inlier share and farther (a neighbour is
        # up to a vertex spacing beyond the target, and with `keyframe_spacing_m` the nearest keyframed one up to
        # that much farther: at 5 m without the extra reach, 12 of 26 proposals on the 06 render at `strong` went
        # unconfirmed); its pose is checked against the first measurement's.
        confirm = self.config.confirm
        self.confirmer = LoopMeasurer(
            calibration,
            self.config.model_copy(
                update={
                    "min_inliers": confirm.min_inliers,
                    "min_inlier_ratio": 0.0,
                    "max_distance_m": confirm.max_distance_m + self.config.keyframe_spacing_m,
                }
            ),
        )
        self.keyframes: dict[int, Keyframe] = {}
        self._pending: dict[int, Future[Keyframe]] = {}  # keyframes still being extracted
        self._frame: StereoFrame | None = None
        self._offset_px: float | None = None  # this frame's stereo correction (None: the configured one)
        self._current: Keyframe | None = None
        self._current_why = ""  # why this frame has no keyframe, once extraction failed
        self.measured: set[int] = set()  # vertices measured from this frame
        # Where the last kept keyframe was made (`keyframe_spacing_m`).
        self._last_keyframe_odometer_m = -np.inf
        # Keyframes extracted this run (`extractions`): where a closure's CPU goes.
        self._extracted_by_proposers = 0
        self._kept_from_proposers = 0
        self._extracted_for_vertices = 0

    # -- this frame -----------------------------------------------------------------------------------
    def begin_frame(self, frame: StereoFrame, disparity_offset_px: float | None) -> None:
        """A new frame: its keyframe is extracted when a proposer first asks (`current`)."""
        self._frame, self._offset_px = frame, disparity_offset_px
        self._current, self._current_why = None, ""
        self.measured = set()

    def current(self) -> tuple[Keyframe | None, str]:
        """(this frame's keyframe, "ok"), or (None, "no_current_keyframe") when it cannot be extracted."""
        if self._current is not None:
            return self._current, "ok"
        if self._current_why or self._frame is None:
            return None, self._current_why or "no_current_keyframe"
        frame = self._frame
        self._extracted_by_proposers += 1
        try:
            self._current = self.extract(frame.left, frame.right, self._offset_px)
        except Exception as err:  # noqa: BLE001 - a frame without a keyframe closes no loop; the run goes on
            log.warning("frame %s: no stereo keyframe (%s); no loop closure attempted", frame.index, err)
            self._current_why = "no_current_keyframe"
            return None, self._current_why
        return self._current, "ok"

    def measure(
        self, vertex: int, current: Keyframe, min_inliers: int | None = None
    ) -> tuple[LoopMeasurement | None, str]:
        """The pose of `vertex`'s keyframe seen from `current` (`LoopMeasurer.measure`, at `min_inliers` or the
        config's bar), or (None, why not: "no_keyframe" when the vertex has none)."""
        keyframe = self.keyframe(vertex)
        if keyframe is None:
            return None, "no_keyframe"
        self.measured.add(vertex)
        return self.measurer.measure(keyframe, current, min_inliers)

    def measure_confirmed(
        self,
        experience_map: ExperienceMap,
        vertex: int,
        current: Keyframe,
        min_inliers: int,
        confirm: bool,
        via: str,
    ) -> tuple[LoopMeasurement | None, str]:
        """`measure` at `min_inliers`, then, when `confirm`, `confirmed` by a path neighbour: the measurement
        a proposer may propose, or (None, why not)."""
        measurement, why = self.measure(vertex, current, min_inliers)
        if measurement is None or not confirm:
            return measurement, why
        confirmed, why = self.confirmed(experience_map, vertex, measurement, current, via)
        return (measurement, why) if confirmed else (None, why)

    def confirmed(
        self,
        experience_map: ExperienceMap,
        vertex: int,
        measurement: LoopMeasurement,
        current: Keyframe,
        via: str,
    ) -> tuple[bool, str]:
        """(whether a neighbour of `vertex` along the path, measured from the same frame, lies where
        `measurement` and the map put it, why not: `<via>_no_neighbour`, `<via>_unconfirmed` (no neighbour
        measured) or `<via>_disagrees`). The neighbour nearer the agent is tried first.

        A wrong PnP pose from a few matches can be metres off and still inside its own covariance's gate (on
        the 00 render at `strong`: 3.5 m, χ² 42 against the truth); a second keyframe, measured
        independently, does not repeat the same error: it must put the neighbour within
        `confirm.agreement_m` and `confirm.agreement_rad` of where the first measurement and the map's short
        path between the two vertices put it."""
        cfg = self.config.confirm
        world_from_target = np.array(experience_map.vertex_pose(vertex))
        agent_from_target = np.array(measurement.agent_from_target)
        world_from_agent = se2_compose(world_from_target, se2_between(agent_from_target, np.zeros(3)))
        neighbours = self._keyframed_neighbours(vertex, len(experience_map))
        poses = {n: np.array(experience_map.vertex_pose(n)) for n in neighbours}
        neighbours.sort(key=lambda n: float(np.hypot(*(poses[n][:2] - world_from_agent[:2]))))
        why = f"{via}_no_neighbour"
        for neighbour in neighbours:
            keyframe = self.keyframe(neighbour)
            if keyframe is None:
                continue
            second, _ = self.confirmer.measure(keyframe, current)
            if second is None:
                why = why if why == f"{via}_disagrees" else f"{via}_unconfirmed"
                continue
            predicted = se2_compose(agent_from_target, se2_between(world_from_target, poses[neighbour]))
            off = se2_between(predicted, np.array(second.agent_from_target))
            off_m, off_rad = float(np.hypot(off[0], off[1])), abs(float(off[2]))
            log.debug(
                "vertex %d: %s measurement checked against neighbour %d: %.2f m, %.3f rad apart",
                vertex,
                via,
                neighbour,
                off_m,
                off_rad,
            )
            if off_m <= cfg.agreement_m and off_rad <= cfg.agreement_rad:
                return True, "ok"
            why = f"{via}_disagrees"
        return False, why

    def _keyframed_neighbours(self, vertex: int, vertices: int) -> list[int]:
        """The nearest vertex keeping a keyframe on each side of `vertex` along the path (ids next to it;
        with `keyframe_spacing_m` the next few), within `_NEIGHBOUR_REACH` ids."""
        found = []
        for side in (-1, 1):
            for n in range(vertex + side, vertex + side * (_NEIGHBOUR_REACH + 1), side):
                if not 0 <= n < vertices:
                    break
                if self.has_keyframe(n):
                    found.append(n)
                    break
                if self.config.keyframe_spacing_m <= 0:
                    break  # every vertex keeps one: a gap is a failed extraction, not a spacing
        return found

    # -- what vertices keep ---------------------------------------------------------------------------
    def after_map(
        self, frame: StereoFrame, outcome: MapFrameOutcome, worker: Worker, odometer_m: float
    ) -> None:
        """A new vertex keeps this frame's keyframe: the one a proposer made, or one extracted on `worker`
        (with `keyframe_spacing_m`, only when the last kept one was made that far back; `odometer_m`: the
        map's odometer now)."""
        if not outcome.created or outcome.vertex is None:
            return
        vertex = int(outcome.vertex)
        if self._current is not None:
            self.keyframes[vertex] = self._current
            self._kept_from_proposers += 1
            self._last_keyframe_odometer_m = odometer_m
            return
        # (An odometer behind the last keyframe's is a new session's, started at 0 over a loaded memory.)
        if 0.0 <= odometer_m - self._last_keyframe_odometer_m < self.config.keyframe_spacing_m:
            return
        self._last_keyframe_odometer_m = odometer_m
        self._extracted_for_vertices += 1
        self._pending[vertex] = worker.submit(self.extract, frame.left, frame.right, self._offset_px)
        if self._pending[vertex].done():  # done at once (inline): take it (or report its failure) now
            self.keyframe(vertex)

    def finish(self) -> None:
        """Take every keyframe still being extracted."""
        for vertex in list(self._pending):
            self.keyframe(vertex)

    def keyframe(self, vertex: int) -> Keyframe | None:
        """The keyframe of `vertex` (waiting for it if it is still being extracted), or None."""
        pending = self._pending.pop(vertex, None)
        if pending is not None:
            try:
                self.keyframes[vertex] = pending.result()
            except Exception as err:  # noqa: BLE001 - a keyframe costs closures to one vertex, never the run
                log.warning("vertex %d: no stereo keyframe (%s); no loop can close onto it", vertex, err)
        return self.keyframes.get(vertex)

    def has_keyframe(self, vertex: int) -> bool:
        """Whether `vertex` keeps a keyframe (or one is being extracted for it); does not wait."""
        return vertex in self.keyframes or vertex in self._pending

    def keyframed(self, vertices: Iterable[int]) -> list[int]:
        """The `vertices` (in order) that keep a keyframe: where a proposer looks for a place to measure."""
        if self.config.keyframe_spacing_m <= 0:
            return list(vertices)
        return [v for v in vertices if self.has_keyframe(int(v))]

    def __len__(self) -> int:
        return len(self.keyframes)

    @property
    def extractions(self) -> dict[str, int]:
        """Keyframes extracted this run: `by_proposers` for this frame's measurements (on the closure's thread,
        in the frame's time), `kept_by_a_vertex` of those, and `for_new_vertices` on the slow-work thread. A
        proposer's extractions that no vertex kept are its own cost (docs/results.md, "Lost loops")."""
        return {
            "by_proposers": self._extracted_by_proposers,
            "kept_by_a_vertex": self._kept_from_proposers,
            "for_new_vertices": self._extracted_for_vertices,
        }

    @property
    def stored_bytes(self) -> int:
        return int(sum(k.nbytes for k in self.keyframes.values()))

    # -- Persistent -----------------------------------------------------------------------------------
    def depends_on(self) -> dict[str, object]:
        # The keyframes' descriptors: SIFT's and ORB's cannot be matched with each other.
        return {"descriptor": self.config.descriptor}

    def export_state(self) -> dict[str, np.ndarray]:
        """Every vertex's keyframe (waits for those still being extracted)."""
        self.finish()
        vertices = sorted(self.keyframes)
        frames = [self.keyframes[v] for v in vertices]
        return {
            "vertex": np.array(vertices, np.int64),
            "count": np.array([len(k) for k in frames], np.int64),
            "pixels_px": stack_ragged([k.pixels_px for k in frames], 2, np.float32),
            "descriptors": stack_ragged(
                [k.descriptors for k in frames], DESCRIPTOR_BYTES[self.config.descriptor], np.uint8
            ),
            "points_m": stack_ragged([k.points_m for k in frames], 3, np.float32),
            "last_keyframe_odometer_m": np.array(self._last_keyframe_odometer_m),
        }

    def restore_state(self, saved: dict[str, np.ndarray]) -> None:
        """The keyframes of `export_state`, kept as this store's (replacing any)."""
        parts = split_ragged(saved["count"], saved["pixels_px"], saved["descriptors"], saved["points_m"])
        width = int(saved["descriptors"].shape[1]) if saved["descriptors"].ndim == 2 else -1
        if width != DESCRIPTOR_BYTES[self.config.descriptor]:
            raise HippoNavError(
                f"the saved keyframes hold {width}-byte descriptors, closure.descriptor = "
                f"{self.config.descriptor!r} needs {DESCRIPTOR_BYTES[self.config.descriptor]}: continue a map "
                "with the descriptor it was made with"
            )
        if len(parts) != len(saved["vertex"]):
            raise HippoNavError("saved keyframes are inconsistent: one count per vertex is needed")
        for name in ("pixels_px", "points_m"):
            if not np.isfinite(np.asarray(saved[name], np.float64)).all():
                # Every keyframe this package saves is finite: a NaN would become a NaN closure later on.
                raise HippoNavError(
                    f"the saved keyframes' {name} holds NaN or infinity; the memory is damaged"
                )
        self.keyframes = {
            int(vertex): Keyframe(
                np.ascontiguousarray(px, np.float32),
                np.ascontiguousarray(desc, np.uint8),
                np.ascontiguousarray(points, np.float32),
            )
            for vertex, (px, desc, points) in zip(saved["vertex"].tolist(), parts)
        }
        self._pending = {}
        # Memories saved before `keyframe_spacing_m` existed kept a keyframe at every vertex.
        self._last_keyframe_odometer_m = float(saved.get("last_keyframe_odometer_m", -np.inf))
