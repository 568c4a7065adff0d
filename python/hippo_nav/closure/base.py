"""The closure plug point: what a proposer sees of a frame (`ClosureContext`), what it answers
(`ClosureAttempt`, holding a `ProposedClosure` or a note), and the `ClosureProposer` protocol.

Python proposes and measures; the map decides. Once per frame (in the map's geometric closure mode) the chain
(`chain.ClosureChain`) asks its proposers, in the configured order (`parts.closure`), for a closure: a target
vertex, the target's pose seen from the agent (`agent_from_target`, planar `(forward_m, left_m, yaw_rad)`,
`hippo_nav.geometry`) and its information (3 × 3, inverse covariance). The first proposal is handed to the
experience map (Rust, `hippo_map`, docs/map.md), which accepts it as a loop link or rejects it (too recent,
outside the loop gate around the odometry's prediction, inconsistent with the graph). Every proposer measures
against the one keyframe store (`store.KeyframeStore`): one keyframe per vertex, and the current frame's,
extracted once a frame for all of them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from hippo_nav.datasets.base import StereoFrame
from hippo_nav.map import ExperienceMap, MapFrameOutcome

if TYPE_CHECKING:
    from hippo_nav.closure.store import KeyframeStore

__all__ = ["NO_ATTEMPT", "ClosureAttempt", "ClosureContext", "ClosureProposer", "ProposedClosure"]


@dataclass(frozen=True)
class ClosureContext:
    """What a proposer sees of one frame, before the map takes it."""

    frame: StereoFrame
    planar_step: tuple[float, float, float]  # the map's odometry step to this frame (forward, left, yaw)
    anchor_vertex: (
        int | None
    )  # the vertex where this frame's familiar view was first seen (None: not familiar)
    experience_map: ExperienceMap
    keyframes: KeyframeStore  # every vertex's keyframe, and this frame's (`current()`)
    # Travel since the last accepted closure is at least `closure.spacing_m` (closer ones add little).
    spaced: bool = True

    @property
    def lost(self) -> bool:
        """A session started inside a loaded map that has not yet relocalised: the odometry says nothing of
        where in the old map the agent is, so only relocalisation may propose."""
        return self.experience_map.unjoined_from is not None


@dataclass(frozen=True)
class ProposedClosure:
    """A measured loop closure, as the map takes it."""

    target_vertex: int
    agent_from_target: tuple[float, float, float]  # planar (forward m, left m, yaw rad)
    information: np.ndarray  # (3, 3) inverse covariance of agent_from_target
    # What proposed it: the proposer's name ("view_cell", "proximity", "birdseye", …), or a variant of it
    # ("view_cell_confirmed"); an accepted one is noted "accepted" (view cells) or "accepted_<via>".
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
    """One way of proposing loop closures: a module of `closure/` and a line in `closure.PROPOSERS`."""

    def propose(self, context: ClosureContext) -> ClosureAttempt:
        """A measured closure for this frame, or why none (module doc)."""
        ...

    def after_map(self, outcome: MapFrameOutcome) -> None:
        """The map has taken the frame (`outcome.loop_closure`: the closure it accepted, whoever proposed it)."""
        ...
