"""Relocalisation in a loaded map (`"relocalisation"`; a session started inside a loaded map,
`ExperienceMap.start_session`, docs/memory.md): until the session is joined the map offers no candidates (the
odometry says nothing about where in the old map the agent is), so a familiar view of the loaded map is measured
directly against the keyframes of its anchor vertex and neighbours, with the stricter `min_inliers`. Each such
measurement is a hypothesis of where the session lies in the old map; the closure is proposed (and the map
joins the session with it, without a gate) only once `confirmations` hypotheses from different frames within
`window_m` of travel put the agent at the same place (`agreement_m`, `agreement_rad`). Once joined, it proposes
nothing.
"""

from __future__ import annotations

import numpy as np
from pydantic import ConfigDict, Field

from hippo_nav._defaults import ConfigSection
from hippo_nav.closure.base import NO_ATTEMPT, ClosureAttempt, ClosureContext, ProposedClosure
from hippo_nav.closure.retrace import RetraceConfig, RetraceReport, retrace_lost_stretch
from hippo_nav.closure.store import KeyframeStore
from hippo_nav.geometry import se2_between, se2_compose
from hippo_nav.map import ExperienceMap, MapFrameOutcome

__all__ = ["RelocalisationConfig", "RelocalisationProposer"]


class RelocalisationConfig(ConfigSection):
    """`closure.relocalisation`: how a session started inside a loaded map finds where it is."""

    model_config = ConfigDict(frozen=True)

    anchor_neighbours: int = Field(
        1, ge=0, le=20, description="vertices on either side of the familiar view's anchor that are measured"
    )
    min_inliers: int = Field(
        60,
        ge=6,
        le=20000,
        description="PnP inliers a measurement needs to relocalise in a loaded map (no odometry gate checks it, "
        "so twice the closure bar)",
    )
    confirmations: int = Field(
        2,
        ge=1,
        le=100,
        description="measurements from different frames that must agree on where the session lies in the "
        "loaded map before it is joined",
    )
    window_m: float = Field(
        30.0, gt=0.0, description="travel within which the agreeing measurements must fall"
    )
    agreement_m: float = Field(
        1.0, gt=0.0, description="agreeing measurements put the agent within this distance of each other"
    )
    agreement_rad: float = Field(0.05, gt=0.0, description="… and within this heading of each other")
    retrace: RetraceConfig = Field(default_factory=RetraceConfig)


class RelocalisationProposer:
    """Joins a lost session to its loaded map once measurements from several frames agree (module doc)."""

    def __init__(self, config: RelocalisationConfig | None = None) -> None:
        self.config = config if config is not None else RelocalisationConfig()
        # Hypotheses: (odometer m, the session's pose in the loaded map (x, y, yaw)).
        self._hypotheses: list[tuple[float, np.ndarray]] = []
        # This frame's proposed join: the map, the store and the session's first vertex, for the retrace.
        self._joining: tuple[ExperienceMap, KeyframeStore, int] | None = None
        self.retraced: RetraceReport | None = None  # what the retrace at the join did

    def propose(self, context: ClosureContext) -> ClosureAttempt:
        self._joining = None
        experience_map = context.experience_map
        if experience_map.unjoined_from is None:  # joined (or never lost): nothing to relocalise
            return NO_ATTEMPT
        first_session_vertex = int(experience_map.unjoined_from)
        cfg, store, anchor = self.config, context.keyframes, context.anchor_vertex
        if anchor is None or anchor >= first_session_vertex:
            return NO_ATTEMPT
        here = experience_map.world_from_agent
        if here is None:  # the session's first frame: nothing to place yet
            return NO_ATTEMPT
        # Where the session's odometry puts the agent after this frame's step (in the session's frame).
        agent_in_session = se2_compose(np.array(here), np.array(context.planar_step))
        reach = cfg.anchor_neighbours
        nearby = [v for v in range(anchor - reach, anchor + reach + 1) if 0 <= v < first_session_vertex]
        current, why = store.current()
        if current is None:
            return ClosureAttempt(None, why)
        odometer = experience_map.odometer_m + float(np.hypot(*context.planar_step[:2]))
        self._hypotheses = [h for h in self._hypotheses if odometer - h[0] <= cfg.window_m]
        why = "no_keyframe"
        for vertex in sorted(nearby, key=lambda v: abs(v - anchor)):
            if store.keyframe(vertex) is None:
                continue
            measurement, why = store.measure(vertex, current)
            if measurement is None:
                continue
            if measurement.inliers < cfg.min_inliers:
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
            if agreeing + 1 < cfg.confirmations:
                return ClosureAttempt(None, "relocalisation_unconfirmed")
            closure = ProposedClosure(vertex, measurement.agent_from_target, measurement.information)
            self._joining = (experience_map, store, first_session_vertex)
            return ClosureAttempt(closure, "measured")
        return ClosureAttempt(None, why)

    def _agree(self, a: np.ndarray, b: np.ndarray, agent_in_session: np.ndarray) -> bool:
        """Whether two placements of the session put the agent at the same place and heading."""
        pa, pb = se2_compose(a, agent_in_session), se2_compose(b, agent_in_session)
        off = se2_between(pa, pb)
        return bool(
            np.hypot(off[0], off[1]) <= self.config.agreement_m and abs(off[2]) <= self.config.agreement_rad
        )

    def after_map(self, outcome: MapFrameOutcome) -> None:
        """The map joined the session with this proposer's closure: retrace the lost stretch."""
        joining, self._joining = self._joining, None
        if joining is None or not outcome.relocalized or outcome.vertex is None:
            return
        experience_map, store, first = joining
        self.retraced = retrace_lost_stretch(
            experience_map, store, first, int(outcome.vertex), self.config.retrace
        )

    # Persistent: the hypotheses not yet confirmed (a resumed run that was still lost keeps them).
    def depends_on(self) -> dict[str, object]:
        return {}

    def export_state(self) -> dict[str, np.ndarray]:
        return {"hypotheses": np.array([[o, *h] for o, h in self._hypotheses], np.float64).reshape(-1, 4)}

    def restore_state(self, saved: dict[str, np.ndarray]) -> None:
        self._hypotheses = [(float(h[0]), np.array(h[1:], np.float64)) for h in saved["hypotheses"]]
