"""Closures by proximity (`"proximity"`): a frame whose familiar view gives no closure, or that has no familiar
view, measures the vertex nearest to where the odometry puts the agent among those the loop gate admits, when
it is within `radius_m`, at the lower bar of `min_inliers` PnP inliers.

An odometry drifts: a revisit lies tens of metres from where it puts the agent after kilometres of odometry
between the two (`radius_per_m` of the shortest path through the map's links from the agent to the vertex, at
most `max_radius_m`; a closure shortens the paths to the places near it only), so each frame also measures one
gated vertex of the ring out to that reach, the next one in turn each frame. The view cells
recognise a place by its look; a revisit under another sun, in another lane, is not recognised (the `strong`
renders), but its stereo geometry still measures it. The bar may be lower because the gate has already put the
vertex where the odometry says the agent is: unrelated places gave at most 9 inliers (1 352 pairs of real
KITTI 06 and 01 frames; 266 pairs of the 06 render at `strong`, docs/views.md), true revisits at `strong` up
to 30. A bar does not catch the right place measured at a wrong pose, so the measurement is proposed only when
a path neighbour of its vertex confirms it (`confirm`, `KeyframeStore.confirmed`). A vertex an earlier
proposer of the chain measured this frame is not measured again. A proximity closure recalls no network
state by itself (no view is familiar); it is noted `accepted_proximity` in `frames.csv`, a refused one
`proximity_unconfirmed` or `proximity_disagrees`.
"""

from __future__ import annotations

import numpy as np
from pydantic import ConfigDict, Field

from hippo_nav._defaults import ConfigSection
from hippo_nav.closure.base import NO_ATTEMPT, ClosureAttempt, ClosureContext, ProposedClosure
from hippo_nav.map import MapFrameOutcome

__all__ = ["ProximityConfig", "ProximityProposer"]

# The ring measures only vertices whose heading the odometry puts within this of the agent's.
_RING_MAX_HEADING_RAD = np.radians(30.0)


class ProximityConfig(ConfigSection):
    """`closure.proximity`: where a proximity measurement looks, and its bar."""

    model_config = ConfigDict(frozen=True)

    min_inliers: int = Field(
        15,
        ge=6,
        le=20000,
        description="PnP inliers a proximity measurement needs (the gate has already placed the vertex; "
        "unrelated real and rendered places give at most 9, docs/views.md)",
    )
    radius_m: float = Field(
        8.0,
        gt=0.0,
        description="a proximity measurement is tried only when the odometry puts the nearest gated vertex "
        "this close: `max_distance_m` plus the odometry's likely error (farther ones were 90 % of the failed "
        "tries on the 06 render, and their cost)",
    )
    radius_per_m: float = Field(
        0.01,
        ge=0.0,
        description="beyond `radius_m`, the proximity search also reaches a vertex this share of the path "
        "through the map from the agent to it (an odometry drifts about 1 % of its path: on the 02 render at "
        "`strong` the two passes of a street were 27-31 m apart after 2.9-3.4 km), measuring one vertex of "
        "that ring a frame, in turn; 0: only `radius_m`",
    )
    max_radius_m: float = Field(50.0, gt=0.0, description="the proximity search reaches at most this far (m)")
    confirm: bool = Field(
        True,
        description="a proximity measurement is proposed only when a neighbour of its vertex along the path, "
        "measured from the same frame, puts that neighbour where the first measurement and the map do "
        "(`closure.confirm`): a wrong PnP pose from few matches is not repeated by a second keyframe",
    )


class ProximityProposer:
    """Closures onto the gated vertex nearest to where the odometry puts the agent (module doc)."""

    def __init__(self, config: ProximityConfig | None = None) -> None:
        self.config = config if config is not None else ProximityConfig()
        self._ring_turn = 0  # which vertex of the ring the next frame measures

    def propose(self, context: ClosureContext) -> ClosureAttempt:
        if context.lost or not context.spaced:
            return NO_ATTEMPT
        store = context.keyframes
        candidates = [v for v in self._candidates(context) if v not in store.measured]
        if not candidates:
            return NO_ATTEMPT
        current, why = store.current()
        if current is None:
            return ClosureAttempt(None, why)
        why = "no_keyframe"
        for vertex in candidates:
            if store.keyframe(vertex) is None:
                continue
            measurement, why = store.measure_confirmed(
                context.experience_map,
                vertex,
                current,
                self.config.min_inliers,
                self.config.confirm,
                "proximity",
            )
            if measurement is None:
                continue
            closure = ProposedClosure(
                vertex, measurement.agent_from_target, measurement.information, "proximity"
            )
            return ClosureAttempt(closure, "measured")
        return ClosureAttempt(None, why)

    def _candidates(self, context: ClosureContext) -> list[int]:
        """Among the vertices the map's loop gate admits (far enough back along the path, inside the gate):
        the one nearest to where the odometry puts the agent, when it is within `radius_m`, then one vertex of
        the ring beyond it, each vertex out to the odometry's likely drift between the agent and it, taken in
        turn from frame to frame, among those passed in about the agent's direction (within 30°)."""
        cfg = self.config
        experience_map, step = context.experience_map, context.planar_step
        widest_m = max(cfg.max_radius_m, cfg.radius_m) if cfg.radius_per_m > 0 else cfg.radius_m
        near = context.keyframes.keyframed(experience_map.vertices_near(widest_m, step))
        gated = experience_map.loop_candidates(near, step) if near else []
        chosen = [int(gated[0][0])] if gated and gated[0][2] <= cfg.radius_m else []
        # Only vertices passed in about the agent's direction (a forward camera measures nothing else), each
        # within the drift of the odometry that relates it to the agent (`c[3]`, the path through the map).
        ring = [
            int(c[0])
            for c in gated
            if cfg.radius_m < c[2] <= min(cfg.radius_m + cfg.radius_per_m * c[3], cfg.max_radius_m)
            and abs(c[1][2]) <= _RING_MAX_HEADING_RAD
        ]
        if ring:
            # The drift's direction is unknown: each frame measures the next vertex of the ring, so that a
            # revisit tens of metres from where the odometry puts it is met within a few frames of driving.
            chosen.append(ring[self._ring_turn % len(ring)])
            self._ring_turn += 1
        return chosen

    def after_map(self, outcome: MapFrameOutcome) -> None:
        pass

    # Persistent: the ring's turn (a resumed run measures the ring where it stopped).
    def depends_on(self) -> dict[str, object]:
        return {}

    def export_state(self) -> dict[str, np.ndarray]:
        return {"ring_turn": np.array(self._ring_turn, np.int64)}

    def restore_state(self, saved: dict[str, np.ndarray]) -> None:
        self._ring_turn = int(saved["ring_turn"])
