"""Closure proposers: the plug point that proposes measured loop closures for the experience map.

Python proposes and measures; the map decides. Once per frame (in the map's geometric closure mode) the
system asks its proposer for a closure (`propose`): a target vertex, the target's pose seen from the agent
(`agent_from_target`, planar `(forward_m, left_m, yaw_rad)`, `hippo_nav.geometry`) and its information
(3 × 3, inverse covariance). The experience map (Rust, `hippo_map`, docs/map.md) then accepts it as a loop
link or rejects it (too recent, outside the loop gate around the odometry's prediction, inconsistent with
the graph: `MapFrameOutcome.rejected_closure`). After the map has taken the frame, `after_map` lets the
proposer keep what a later closure onto a new vertex needs (a keyframe, a submap) — slow work goes to the
`Worker` it is given, so it may run beside the next frame's odometry — and note an accepted closure.
`finish` waits for work still pending at the end of a run. What a proposer keeps (`stored`,
`stored_bytes`) is reported in `metrics.json` (`keyframes`, `keyframe_bytes`).

The built-in proposer, `ViewCellPnpClosure`: a familiar view suggests a place the map knows; the
candidates are the vertex where that view cell was first seen and its `anchor_neighbours` odometry
neighbours on either side, kept by the map
when far enough back along the path and inside its loop gate (`ExperienceMap.loop_candidates`); the current
stereo frame measures the nearest `candidates_per_frame` against their stored keyframes (SIFT + PnP,
`LoopMeasurer`) and the first verified one is proposed, at most one accepted closure per
`closure_spacing_m` of travel. Every new vertex keeps its frame's keyframe.

A familiar view's candidate measured with fewer inliers than `min_inliers`, but at least
`view_cell_confirmed_min_inliers`, is proposed only when a path neighbour of its vertex confirms it, as a
proximity measurement is (below); it is noted `accepted_view_cell_confirmed`, a refused one
`view_cell_unconfirmed` or `view_cell_disagrees`.

Proximity (`closure.proximity`, on by default): a frame whose familiar view gives no closure, or that has no
familiar view, also measures the vertex nearest to where the odometry puts the agent among those the loop
gate admits, when it is within `proximity_radius_m`, at the lower bar of `proximity_min_inliers` PnP inliers.
An odometry drifts: after kilometres without a closure a revisit lies tens of metres from where it puts the
agent (`proximity_radius_per_m` of the travel since the last closure, at most `proximity_max_radius_m`), so
each frame also measures one gated vertex of the ring out to that reach, the next one in turn each frame.
The view cells recognise a place by its look; a revisit under another sun, in another lane, is not recognised
(the `strong` renders), but its stereo geometry still measures it. The bar may be lower because the gate has
already put the vertex where the odometry says the agent is: unrelated places gave at most 9 inliers (1 352
pairs of real KITTI 06 and 01 frames; 266 pairs of the 06 render at `strong`, docs/views.md), true revisits at
`strong` up to 30. A bar does not catch the right place measured at a wrong pose, so the measurement is
proposed only when a path neighbour of its vertex confirms it (`proximity_confirm`, `_confirmed`). The map's
gate and consistency check then decide as for any closure. A proximity closure recalls no network state by
itself (no view is familiar); it is noted `accepted_proximity` in `frames.csv`, a refused one
`proximity_unconfirmed` or `proximity_disagrees`.

Relocalisation (a session started inside a loaded map, `ExperienceMap.start_session`, docs/memory.md): until
the session is joined the map offers no candidates (the odometry says nothing about where in the old map the
agent is), so a familiar view of the loaded map is measured directly against the keyframes of its anchor vertex
and neighbours, with the stricter `relocalisation_min_inliers`. Each such measurement is a hypothesis of where
the session lies in the old map; the closure is proposed (and the map joins the session with it, without a
gate) only once `relocalisation_confirmations` hypotheses from different frames within
`relocalisation_window_m` of travel put the agent at the same place (`relocalisation_agreement_m`, `_rad`).
"""

from __future__ import annotations

import logging
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.closure.birdseye import BirdsEyeSearch
from hippo_nav.closure.keyframes import DESCRIPTOR_BYTES, ClosureConfig, Keyframe, KeyframeExtractor
from hippo_nav.closure.measure import LoopMeasurement, LoopMeasurer
from hippo_nav.datasets.base import StereoCalibration, StereoFrame
from hippo_nav.geometry import se2_between, se2_compose
from hippo_nav.map import ExperienceMap, MapFrameOutcome
from hippo_nav.memory import split_ragged, stack_ragged
from hippo_nav.workers import Worker

log = logging.getLogger("hippo_nav.pipeline")

# The proximity ring measures only vertices whose heading the odometry puts within this of the agent's.
_RING_MAX_HEADING_RAD = np.radians(30.0)

__all__ = ["ClosureAttempt", "ClosureContext", "ClosureProposer", "ProposedClosure", "ViewCellPnpClosure"]


@dataclass(frozen=True)
class ClosureContext:
    """What a proposer sees of one frame, before the map takes it."""

    frame: StereoFrame
    planar_step: tuple[float, float, float]  # the map's odometry step to this frame (forward, left, yaw)
    anchor_vertex: (
        int | None
    )  # the vertex where this frame's familiar view was first seen (None: not familiar)
    experience_map: ExperienceMap
    # The stereo correction the odometry applies now (its self-calibration moves it): a keyframe's depths
    # come from the same pair. None: the proposer's own (the configured `vo.disparity_offset_px`).
    disparity_offset_px: float | None = None


@dataclass(frozen=True)
class ProposedClosure:
    """A measured loop closure, as the map takes it."""

    target_vertex: int
    agent_from_target: tuple[float, float, float]  # planar (forward m, left m, yaw rad)
    information: np.ndarray  # (3, 3) inverse covariance of agent_from_target
    # What proposed it: "view_cell" (a familiar view), "view_cell_confirmed" (a familiar view below the
    # view cells' bar, confirmed by a neighbour), "proximity" (a vertex near where the odometry puts the
    # agent, inside the loop gate) or "birdseye"; an accepted one is noted "accepted" or "accepted_<via>".
    via: str = "view_cell"

    def map_input(self) -> tuple[int, tuple[float, float, float], np.ndarray]:
        """The `loop_closure` argument of `ExperienceMap.on_frame`."""
        return self.target_vertex, self.agent_from_target, self.information


@dataclass(frozen=True)
class ClosureAttempt:
    """A proposer's answer for one frame: a closure or None, and a note for `frames.csv`'s `closure_note`
    ("" when nothing was tried, "measured" when a closure is proposed, otherwise why not)."""

    closure: ProposedClosure | None = None
    note: str = ""


NO_ATTEMPT = ClosureAttempt()


class ClosureProposer(Protocol):
    """Proposes measured loop closures (module doc)."""

    def propose(self, context: ClosureContext) -> ClosureAttempt: ...

    def after_map(
        self, frame: StereoFrame, outcome: MapFrameOutcome, experience_map: ExperienceMap, worker: Worker
    ) -> None: ...

    def finish(self) -> None: ...

    @property
    def stored(self) -> int:
        """How many places the proposer keeps (keyframes, submaps)."""
        ...

    @property
    def stored_bytes(self) -> int: ...


class ViewCellPnpClosure:
    """Closures proposed by familiar view cells, measured by stereo PnP against the keyframe of the vertex
    where the view was first seen (module doc). `keyframes`: vertex → its stereo keyframe."""

    def __init__(
        self,
        calibration: StereoCalibration,
        config: ClosureConfig | None = None,
        *,
        disparity_offset_px: float = 0.0,
    ) -> None:
        self.config = config or ClosureConfig()
        self.extract = KeyframeExtractor(calibration, self.config, disparity_offset_px)
        self.measurer = LoopMeasurer(calibration, self.config)
        # A proximity closure's confirming neighbour: measured at its own bar, with any inlier share and
        # farther (a neighbour is up to a vertex spacing beyond the target); its pose is checked against the
        # first measurement's (`_confirmed`), which a chance pose does not pass.
        self.confirmer = LoopMeasurer(
            calibration,
            self.config.model_copy(
                update={
                    "min_inliers": self.config.proximity_confirm_min_inliers,
                    "min_inlier_ratio": 0.0,
                    "max_distance_m": self.config.proximity_confirm_max_distance_m,
                }
            ),
        )
        self.keyframes: dict[int, Keyframe] = {}
        self.birdseye = BirdsEyeSearch(self.config)
        # Keyframes still being extracted (vertex → future); see `after_map`.
        self._pending: dict[int, Future[Keyframe]] = {}
        self._made: Keyframe | None = None  # the current frame's keyframe, when a closure attempt made one
        self._proposed = False  # whether the current frame proposed a closure
        self._offset_px: float | None = None  # the current frame's stereo correction (ClosureContext)
        self._closure_odometer_m = -np.inf
        self._ring_turn = 0  # which vertex of the proximity ring the next frame measures
        # Relocalisation hypotheses: (odometer m, the session's pose in the loaded map (x, y, yaw)).
        self._hypotheses: list[tuple[float, np.ndarray]] = []

    @property
    def stored(self) -> int:
        return len(self.keyframes)

    @property
    def stored_bytes(self) -> int:
        return int(sum(k.nbytes for k in self.keyframes.values())) + self.birdseye.stored_bytes

    def propose(self, context: ClosureContext) -> ClosureAttempt:
        """The first candidate vertex whose keyframe the current frame measures (module doc)."""
        self._made, self._proposed = None, False
        self._offset_px = context.disparity_offset_px
        cfg = self.config
        experience_map, frame = context.experience_map, context.frame
        if experience_map.unjoined_from is not None:
            return self._relocalise(context, int(experience_map.unjoined_from))
        if experience_map.odometer_m - self._closure_odometer_m < cfg.closure_spacing_m:
            return NO_ATTEMPT
        # (vertex, PnP inlier bar (None: the config's), what proposed it), measured in this order.
        candidates: list[tuple[int, int | None, str]] = []
        anchor = context.anchor_vertex
        if anchor is not None:
            reach = cfg.anchor_neighbours
            nearby = [v for v in range(anchor - reach, anchor + reach + 1) if 0 <= v < len(experience_map)]
            gated = experience_map.loop_candidates(nearby, context.planar_step)
            candidates = [(c[0], None, "view_cell") for c in gated[: cfg.candidates_per_frame]]
        if cfg.proximity:
            for vertex in self._proximity_candidates(context):
                # Already a view cell's candidate: measured once, at the proximity bar.
                candidates = [c for c in candidates if c[0] != vertex]
                candidates.append((vertex, cfg.proximity_min_inliers, "proximity"))
        if not candidates:
            attempt = NO_ATTEMPT if anchor is None else ClosureAttempt(None, "no_candidate")
            return self._or_birdseye(context, attempt)
        try:
            current = self.extract(frame.left, frame.right, self._offset_px)
        except Exception as err:  # noqa: BLE001 - a frame without a keyframe closes no loop; the run goes on
            log.warning("frame %s: no stereo keyframe (%s); no loop closure attempted", frame.index, err)
            return ClosureAttempt(None, "no_current_keyframe")
        self._made = current
        why = "no_keyframe"
        for vertex, bar, via in candidates:
            keyframe = self._keyframe(vertex)
            if keyframe is None:
                continue
            if via == "view_cell":
                bar = min(cfg.view_cell_confirmed_min_inliers, cfg.min_inliers)
            measurement, why = self.measurer.measure(keyframe, current, bar)
            if measurement is not None and via == "view_cell" and measurement.inliers < cfg.min_inliers:
                # Below the view cells' own bar: proposed only if a path neighbour confirms it.
                via = "view_cell_confirmed"
                confirmed, why = self._confirmed(experience_map, vertex, measurement, current, "view_cell")
                if not confirmed:
                    continue
            if measurement is not None and via == "proximity" and cfg.proximity_confirm:
                confirmed, why = self._confirmed(experience_map, vertex, measurement, current, "proximity")
                if not confirmed:
                    continue
            if measurement is not None:
                closure = ProposedClosure(vertex, measurement.agent_from_target, measurement.information, via)
                self._proposed = True
                return ClosureAttempt(closure, "measured")
        return self._or_birdseye(context, ClosureAttempt(None, why))

    def _or_birdseye(self, context: ClosureContext, attempt: ClosureAttempt) -> ClosureAttempt:
        """`attempt` (no closure), or a bird's-eye closure when `closure.birdseye` proposes one
        (`birdseye.py`). A bird's-eye closure recalls no network state: no view is familiar, and on a street
        driven the other way the stored state holds the opposite heading."""
        if not self.config.birdseye:
            return attempt
        try:
            vertex, agent_from_target, information, why = self.birdseye.propose(
                context.experience_map, context.planar_step, self._keyframe
            )
        except Exception as err:  # noqa: BLE001 - a failed registration closes no loop; the run goes on
            log.warning("frame %s: bird's-eye attempt failed (%s); no closure", context.frame.index, err)
            return attempt
        if vertex is None:
            # The bird's-eye note when it tried (it says more than the view's), else the view's.
            return ClosureAttempt(None, why) if why else attempt
        self._proposed = True
        return ClosureAttempt(ProposedClosure(vertex, agent_from_target, information, "birdseye"), "measured")

    def _proximity_candidates(self, context: ClosureContext) -> list[int]:
        """The vertices a proximity measurement tries, among those the map's loop gate admits (far enough
        back along the path, inside the gate): the one nearest to where the odometry puts the agent, when it
        is within `proximity_radius_m`, then one vertex of the ring beyond it, out to the odometry's likely
        drift since the last closure (`proximity_radius_per_m`, at most `proximity_max_radius_m`), taken in
        turn from frame to frame, among those passed in about the agent's direction (within 30°) (module
        doc)."""
        cfg = self.config
        experience_map, step = context.experience_map, context.planar_step
        since_m = experience_map.odometer_m - max(self._closure_odometer_m, 0.0)
        reach_m = min(
            cfg.proximity_radius_m + cfg.proximity_radius_per_m * since_m, cfg.proximity_max_radius_m
        )
        near = experience_map.vertices_near(max(reach_m, cfg.proximity_radius_m), step)
        gated = experience_map.loop_candidates(near, step) if near else []
        chosen = [int(gated[0][0])] if gated and gated[0][2] <= cfg.proximity_radius_m else []
        # Only vertices passed in about the agent's direction: a forward camera measures nothing else.
        ring = [
            int(c[0])
            for c in gated
            if c[2] > cfg.proximity_radius_m and abs(c[1][2]) <= _RING_MAX_HEADING_RAD
        ]
        if ring:
            # The drift's direction is unknown: each frame measures the next vertex of the ring, so that a
            # revisit tens of metres from where the odometry puts it is met within a few frames of driving.
            chosen.append(ring[self._ring_turn % len(ring)])
            self._ring_turn += 1
        return chosen

    def _confirmed(
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
        `proximity_agreement_m` and `proximity_agreement_rad` of where the first measurement and the map's
        short path between the two vertices put it."""
        cfg = self.config
        world_from_target = np.array(experience_map.vertex_pose(vertex))
        agent_from_target = np.array(measurement.agent_from_target)
        world_from_agent = se2_compose(world_from_target, se2_between(agent_from_target, np.zeros(3)))
        neighbours = [n for n in (vertex - 1, vertex + 1) if 0 <= n < len(experience_map)]
        poses = {n: np.array(experience_map.vertex_pose(n)) for n in neighbours}
        neighbours.sort(key=lambda n: float(np.hypot(*(poses[n][:2] - world_from_agent[:2]))))
        why = f"{via}_no_neighbour"
        for neighbour in neighbours:
            keyframe = self._keyframe(neighbour)
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
            if off_m <= cfg.proximity_agreement_m and off_rad <= cfg.proximity_agreement_rad:
                return True, "ok"
            why = f"{via}_disagrees"
        return False, why

    def _relocalise(self, context: ClosureContext, first_session_vertex: int) -> ClosureAttempt:
        """A familiar view of the loaded map, measured against its anchor's keyframes (module doc)."""
        cfg = self.config
        anchor = context.anchor_vertex
        if anchor is None or anchor >= first_session_vertex:
            return NO_ATTEMPT
        experience_map = context.experience_map
        here = experience_map.world_from_agent
        if here is None:  # the session's first frame: nothing to place yet
            return NO_ATTEMPT
        # Where the session's odometry puts the agent after this frame's step (in the session's frame).
        agent_in_session = se2_compose(np.array(here), np.array(context.planar_step))
        reach = cfg.anchor_neighbours
        nearby = [v for v in range(anchor - reach, anchor + reach + 1) if 0 <= v < first_session_vertex]
        try:
            current = self.extract(context.frame.left, context.frame.right, self._offset_px)
        except Exception as err:  # noqa: BLE001 - a frame without a keyframe relocalises nothing
            log.warning(
                "frame %s: no stereo keyframe (%s); no relocalisation attempted", context.frame.index, err
            )
            return ClosureAttempt(None, "no_current_keyframe")
        self._made = current
        odometer = experience_map.odometer_m + float(np.hypot(*context.planar_step[:2]))
        self._hypotheses = [h for h in self._hypotheses if odometer - h[0] <= cfg.relocalisation_window_m]
        why = "no_keyframe"
        for vertex in sorted(nearby, key=lambda v: abs(v - anchor)):
            keyframe = self._keyframe(vertex)
            if keyframe is None:
                continue
            measurement, why = self.measurer.measure(keyframe, current)
            if measurement is None:
                continue
            if measurement.inliers < cfg.relocalisation_min_inliers:
                why = "relocalisation_too_few_inliers"
                continue
            # The session's pose in the loaded map that this measurement implies.
            agent_in_map = se2_compose(
                np.array(experience_map.vertex_pose(vertex)),
                se2_between(np.array(measurement.agent_from_target), np.zeros(3)),
            )
            map_from_session = se2_compose(agent_in_map, se2_between(agent_in_session, np.zeros(3)))
            agreeing = sum(
                self._agree(map_from_session, earlier, agent_in_session) for _, earlier in self._hypotheses
            )
            self._hypotheses.append((odometer, map_from_session))
            if agreeing + 1 < cfg.relocalisation_confirmations:
                return ClosureAttempt(None, "relocalisation_unconfirmed")
            self._proposed = True
            closure = ProposedClosure(vertex, measurement.agent_from_target, measurement.information)
            return ClosureAttempt(closure, "measured")
        return ClosureAttempt(None, why)

    def _agree(self, a: np.ndarray, b: np.ndarray, agent_in_session: np.ndarray) -> bool:
        """Whether two placements of the session put the agent at the same place and heading."""
        pa, pb = se2_compose(a, agent_in_session), se2_compose(b, agent_in_session)
        off = se2_between(pa, pb)
        return bool(
            np.hypot(off[0], off[1]) <= self.config.relocalisation_agreement_m
            and abs(off[2]) <= self.config.relocalisation_agreement_rad
        )

    def export_keyframes(self) -> dict[str, np.ndarray]:
        """Every vertex's keyframe, for a memory folder (waits for those still being extracted)."""
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
            "closure_odometer_m": np.array(self._closure_odometer_m),
            "ring_turn": np.array(self._ring_turn, np.int64),
            # Relocalisation hypotheses not yet confirmed (odometer m, x, y, yaw).
            "hypotheses": np.array([[o, *h] for o, h in self._hypotheses], np.float64).reshape(-1, 4),
        }

    def restore_keyframes(self, saved: dict[str, np.ndarray]) -> None:
        """The keyframes of `export_keyframes`, kept as this proposer's (replacing any)."""
        parts = split_ragged(saved["count"], saved["pixels_px"], saved["descriptors"], saved["points_m"])
        width = int(saved["descriptors"].shape[1]) if saved["descriptors"].ndim == 2 else -1
        if width != DESCRIPTOR_BYTES[self.config.descriptor]:
            raise HippoNavError(
                f"the saved keyframes hold {width}-byte descriptors, closure.descriptor = "
                f"{self.config.descriptor!r} needs {DESCRIPTOR_BYTES[self.config.descriptor]}: continue a map with the "
                "descriptor it was made with"
            )
        if len(parts) != len(saved["vertex"]):
            raise HippoNavError("saved keyframes are inconsistent: one count per vertex is needed")
        self.keyframes = {
            int(vertex): Keyframe(
                np.ascontiguousarray(px, np.float32),
                np.ascontiguousarray(desc, np.uint8),
                np.ascontiguousarray(points, np.float32),
            )
            for vertex, (px, desc, points) in zip(saved["vertex"].tolist(), parts)
        }
        self._pending = {}
        self.birdseye = BirdsEyeSearch(self.config)  # its caches derive from the keyframes
        self._closure_odometer_m = float(saved["closure_odometer_m"])
        # A memory saved before the proximity ring has no turn: it starts again at the first vertex.
        self._ring_turn = int(saved["ring_turn"]) if "ring_turn" in saved else 0
        self._hypotheses = [(float(h[0]), np.array(h[1:], np.float64)) for h in saved["hypotheses"]]

    def after_map(
        self, frame: StereoFrame, outcome: MapFrameOutcome, experience_map: ExperienceMap, worker: Worker
    ) -> None:
        """A new vertex keeps this frame's keyframe: the one a closure attempt made, or one extracted on
        `worker` (beside the next frame's odometry: it is first needed when the agent comes back, at least
        `min_loop_separation_m` later). An accepted closure restarts the spacing."""
        if outcome.loop_closure is not None:
            self.birdseye.forget()
        if self._proposed and outcome.loop_closure is not None:
            self._closure_odometer_m = experience_map.odometer_m
        if not outcome.created or outcome.vertex is None:
            return
        vertex = int(outcome.vertex)
        if self._made is not None:
            self.keyframes[vertex] = self._made
            return
        self._pending[vertex] = worker.submit(self.extract, frame.left, frame.right, self._offset_px)
        if self._pending[vertex].done():  # done at once (inline): take it (or report its failure) now
            self._keyframe(vertex)

    def finish(self) -> None:
        """Take every keyframe still being extracted."""
        for vertex in list(self._pending):
            self._keyframe(vertex)

    def _keyframe(self, vertex: int) -> Keyframe | None:
        """The keyframe of `vertex` (waiting for it if it is still being extracted), or None."""
        pending = self._pending.pop(vertex, None)
        if pending is not None:
            try:
                self.keyframes[vertex] = pending.result()
            except Exception as err:  # noqa: BLE001 - a keyframe costs closures to one vertex, never the run
                log.warning("vertex %d: no stereo keyframe (%s); no loop can close onto it", vertex, err)
        return self.keyframes.get(vertex)
