"""Closures proposed by familiar views (`"view_cell"`, the paper's way): a familiar view suggests a place the map
knows; the candidates are the vertex where that view cell was first seen and its `anchor_neighbours` odometry
neighbours on either side, kept by the map when far enough back along the path and inside its loop gate
(`ExperienceMap.loop_candidates`); the current stereo frame measures the nearest `candidates_per_frame` against
their keyframes (SIFT + PnP, `KeyframeStore.measure`) and the first verified one is proposed.

A candidate measured with fewer inliers than the store's `min_inliers`, but at least `confirmed_min_inliers`,
is proposed only when a path neighbour of its vertex confirms it (`KeyframeStore.confirmed`); it is noted
`accepted_view_cell_confirmed`, a refused one `view_cell_unconfirmed` or `view_cell_disagrees`.
"""

from __future__ import annotations

from pydantic import ConfigDict, Field

from hippo_nav._defaults import ConfigSection
from hippo_nav.closure.base import NO_ATTEMPT, ClosureAttempt, ClosureContext, ProposedClosure
from hippo_nav.map import MapFrameOutcome

__all__ = ["ViewCellConfig", "ViewCellProposer"]


class ViewCellConfig(ConfigSection):
    """`closure.view_cell`: which vertices a familiar view's closure is measured against."""

    model_config = ConfigDict(frozen=True)

    candidates_per_frame: int = Field(
        2, ge=1, le=100, description="candidate vertices measured per frame at most"
    )
    anchor_neighbours: int = Field(
        1,
        ge=0,
        le=20,
        description="vertices on either side of a familiar view's anchor vertex that may be measured (the "
        "nearest `candidates_per_frame` by the odometry's prediction are)",
    )
    confirmed_min_inliers: int = Field(
        15,
        ge=6,
        le=20000,
        description="a familiar view's candidate measured with fewer than `min_inliers` PnP inliers but at least "
        "this many is proposed only when a path neighbour of its vertex, measured from the same frame, confirms "
        "it (`closure.confirm`): another sun or lane leaves a true revisit 15-30 "
        "inliers, unrelated places at most 9 (docs/views.md). Set it to `min_inliers` to turn it off",
    )


class ViewCellProposer:
    """Closures onto the vertex where the frame's familiar view was first seen (module doc)."""

    def __init__(self, config: ViewCellConfig | None = None) -> None:
        self.config = config if config is not None else ViewCellConfig()

    def propose(self, context: ClosureContext) -> ClosureAttempt:
        anchor = context.anchor_vertex
        if context.lost or not context.spaced or anchor is None:
            return NO_ATTEMPT
        cfg, store, experience_map = self.config, context.keyframes, context.experience_map
        reach = cfg.anchor_neighbours
        nearby = [v for v in range(anchor - reach, anchor + reach + 1) if 0 <= v < len(experience_map)]
        nearby = store.keyframed(nearby)
        gated = experience_map.loop_candidates(nearby, context.planar_step)
        candidates = [int(c[0]) for c in gated[: cfg.candidates_per_frame]]
        if not candidates:
            return ClosureAttempt(None, "no_candidate")
        current, why = store.current()
        if current is None:
            return ClosureAttempt(None, why)
        full_bar = store.config.min_inliers
        why = "no_keyframe"
        for vertex in candidates:
            if store.keyframe(vertex) is None:
                continue
            measurement, why = store.measure(vertex, current, min(cfg.confirmed_min_inliers, full_bar))
            if measurement is None:
                continue
            via = "view_cell"
            if measurement.inliers < full_bar:
                # Below the store's own bar: proposed only if a path neighbour confirms it.
                via = "view_cell_confirmed"
                confirmed, why = store.confirmed(experience_map, vertex, measurement, current, "view_cell")
                if not confirmed:
                    continue
            closure = ProposedClosure(vertex, measurement.agent_from_target, measurement.information, via)
            return ClosureAttempt(closure, "measured")
        return ClosureAttempt(None, why)

    def after_map(self, outcome: MapFrameOutcome) -> None:
        pass
