"""Closures at home (`"home"`): a drive that ends where it began is measured against where it began, however far
its odometry has drifted, once it has been away.

Most real drives end on the road they started from (home to home, a robot back at its dock, a rat back at its
nest), and the road the two passes share can be a few metres long: the car started from rest there. The view
cells need the same look; the proximity proposer reaches 1 % of the path; the sequence proposer needs 30 m of
shared road. Home is the one place whose odometry error is simply the whole drive's, so it can be searched for
everywhere the map's own loop gate admits it (`loop_gate_m + loop_gate_per_m · path`, 10 m + 10 % by default)
at the cost of one measurement every `every_m` of travel while the agent is there — a few dozen a loop, where the
sequence proposer measures hundreds.

Home is the session's first vertex and those made within `length_m` of travel after it (a session inside a
loaded memory gets its own: where it began; a memory saved without this proposer's state, before it existed or
by a chain without it, gives every session's home from its map at the first frame). The proposer arms when the agent has been away: every home vertex
out of the map's gate although far enough back along the path (`min_loop_separation_m`), so a drive still leaving
home measures nothing. Armed, a frame (at most one per `every_m` of travel) measures each home vertex the gate
admits that was passed in about the agent's direction (within `max_heading_deg` + `max_heading_deg_per_m` × the
path to it: a forward camera sees nothing of a street driven the other way), at most `max_vertices`, at the
proximity proposer's bar; the one with the most inliers is proposed once a path neighbour confirms it
(`closure.confirm`). All of home is measured because an odometry tens of metres off says nothing of which of
its few vertices the agent is passing. A closure onto home, accepted by the map, disarms the proposer until the
agent has been away again. Noted `accepted_home`; refused, `home_unconfirmed`, `home_disagrees` or the
measurement's reason.

Measured on the KITTI 07 render at `strong` with the 1 %-drifting odometry, whose drive ends 33 m from where the
odometry puts its start after 695 m: frames 1050-1070 measure the first 15 frames' keyframes with 24-44 inliers,
0.1 m from the truth, where nothing else closed (docs/results.md, "Lost loops").
"""

from __future__ import annotations

import json

import numpy as np
from pydantic import ConfigDict, Field

from hippo_nav._defaults import ConfigSection
from hippo_nav.closure.base import NO_ATTEMPT, ClosureAttempt, ClosureContext, ProposedClosure
from hippo_nav.closure.measure import LoopMeasurement
from hippo_nav.map import ExperienceMap, MapFrameOutcome

__all__ = ["HomeConfig", "HomeProposer"]


class HomeConfig(ConfigSection):
    """`closure.home`: what home is, and how often it is measured once the agent has been away."""

    model_config = ConfigDict(frozen=True)

    length_m: float = Field(
        10.0,
        ge=0.0,
        le=1000.0,
        description="home is the session's first vertex and those made within this much travel after it (the "
        "road a returning drive shares with its start can be a few metres: KITTI 07's first 25 frames cover "
        "4.6 m)",
    )
    every_m: float = Field(
        2.0,
        gt=0.0,
        le=1000.0,
        description="at most one home measurement per this much travel (a revisit is in view for 10-20 m)",
    )
    max_heading_deg: float = Field(
        30.0,
        gt=0.0,
        le=180.0,
        description="only home vertices passed in about the agent's direction by the odometry, within this "
        "plus `max_heading_deg_per_m` × the path through the map to the vertex (a forward camera sees nothing "
        "of a street driven the other way)",
    )
    max_heading_deg_per_m: float = Field(
        0.02,
        ge=0.0,
        le=1.0,
        description="the heading an odometry drifts a metre of path (the 1 %-drifting odometry of the KITTI 09 "
        "render turns 31° off over 1 703 m)",
    )
    max_vertices: int = Field(
        8,
        ge=1,
        le=1000,
        description="at most this many home vertices measured a try, nearest to where the odometry puts the "
        "agent first (home is a few vertices: a vertex every 2-3 m)",
    )
    min_inliers: int = Field(
        15, ge=6, le=20000, description="PnP inliers a measurement needs (as `closure.proximity.min_inliers`)"
    )
    confirm: bool = Field(
        True,
        description="a measurement is proposed only when a path neighbour of its vertex, measured from the same "
        "frame, agrees (`closure.confirm`)",
    )


class HomeProposer:
    """Closures onto where the session began, once the agent has been away (module doc)."""

    def __init__(self, config: HomeConfig | None = None) -> None:
        self.config = config if config is not None else HomeConfig()
        self._homes: list[int] = []  # every session's home vertices, oldest first
        self._home_odometer_m = np.nan  # the map's odometer at this session's first home vertex
        self._odometer_m = 0.0  # the map's odometer after the frame being proposed for
        self._pending = True  # the next vertex made starts a session's home
        self._lost = False  # the last frame was a session's before it joined its memory
        self._away = False  # armed: the agent has been out of home's gate since the last closure onto it
        self._next_try_m = -np.inf  # the odometer before which no home measurement is tried
        self._separation_m: float | None = None  # the map's `min_loop_separation_m`
        self._known = False  # the homes known: from a restored state, or read from the map at the first frame

    def propose(self, context: ClosureContext) -> ClosureAttempt:
        experience_map, cfg = context.experience_map, self.config
        self._odometer_m = experience_map.odometer_m + float(np.hypot(*context.planar_step[:2]))
        if not self._known:
            self._known = True
            if not self._homes and len(experience_map) > 0:
                self._homes_from_map(experience_map)
        if context.lost:
            # A session started inside a loaded memory begins at a home of its own.
            if not self._lost:
                self._pending, self._next_try_m = True, -np.inf
            self._lost = True
            return NO_ATTEMPT
        self._lost = False
        if not self._homes or not context.spaced or self._odometer_m < self._next_try_m:
            return NO_ATTEMPT
        gated = self._gated_homes(context)
        if not self._away:
            separation_m = self._min_separation_m(experience_map)
            if not gated and self._odometer_m - self._home_odometer_m >= separation_m:
                self._away = True  # out of the gate of every home vertex, and not for being too recent
            return NO_ATTEMPT
        store = context.keyframes
        candidates = [
            v
            for v, yaw_rad, path_m in gated
            if abs(np.degrees(yaw_rad)) <= cfg.max_heading_deg + cfg.max_heading_deg_per_m * path_m
            and v not in store.measured
        ]
        if not candidates:
            return NO_ATTEMPT
        self._next_try_m = self._odometer_m + cfg.every_m
        current, why = store.current()
        if current is None:
            return ClosureAttempt(None, why)
        # Every admitted home vertex, the one measured with the most inliers proposed: the odometry, tens of
        # metres off, says nothing of which of home's few vertices the agent is passing.
        best: tuple[int, LoopMeasurement] | None = None
        for vertex in candidates[: cfg.max_vertices]:
            measurement, why_not = store.measure(vertex, current, cfg.min_inliers)
            if measurement is not None and (best is None or measurement.inliers > best[1].inliers):
                best = (vertex, measurement)
            why = why_not if best is None else why
        if best is None:
            return ClosureAttempt(None, why)
        vertex, measurement = best
        if cfg.confirm:
            confirmed, why = store.confirmed(experience_map, vertex, measurement, current, "home")
            if not confirmed:
                return ClosureAttempt(None, why)
        closure = ProposedClosure(vertex, measurement.agent_from_target, measurement.information, "home")
        return ClosureAttempt(closure, "measured")

    def _gated_homes(self, context: ClosureContext) -> list[tuple[int, float, float]]:
        """The home vertices (every session's) with a keyframe that the map's loop gate admits, nearest to where
        the odometry puts the agent first: (vertex, its heading seen from the agent in rad, the path through the
        map to it in m)."""
        homes = context.keyframes.keyframed(self._homes)
        if not homes:
            return []
        gated = context.experience_map.loop_candidates(homes, context.planar_step)
        return [(int(c[0]), float(c[1][2]), float(c[3])) for c in gated]

    def _homes_from_map(self, experience_map: ExperienceMap) -> None:
        """Every session's home read from a map made without this proposer (a memory saved before it, or by a
        chain without it): a session's first vertex is the one no odometry link leads to (vertex 0, and each
        `start_session`'s first), its home that vertex and those made within `length_m` of travel after it.
        Without this a resumed run would take the first vertex it makes, wherever it is, for where it began."""
        graph = experience_map.export()
        odometer_m = np.asarray(graph["vertex_odometer_m"], np.float64)
        led_to = np.zeros(len(odometer_m), bool)
        led_to[np.asarray(graph["links"], np.int64)[~np.asarray(graph["link_is_loop"], bool), 1]] = True
        starts = np.flatnonzero(~led_to)
        ends = np.r_[starts[1:], len(odometer_m)]
        for start, end in zip(starts, ends, strict=True):
            travelled_m = odometer_m[start:end] - odometer_m[start]
            self._homes.extend(
                int(start) + int(i) for i in np.flatnonzero(travelled_m <= self.config.length_m)
            )
        self._home_odometer_m = float(odometer_m[starts[-1]])
        self._pending = False  # this session's home is among them; a new session, lost, gets its own

    def _min_separation_m(self, experience_map: ExperienceMap) -> float:
        if self._separation_m is None:
            self._separation_m = float(json.loads(experience_map.params_json())["min_loop_separation_m"])
        return self._separation_m

    def after_map(self, outcome: MapFrameOutcome) -> None:
        if outcome.loop_closure is not None and outcome.loop_closure[1] in self._homes:
            self._away = False  # home reached: measured again only after being away again
        if not outcome.created or outcome.vertex is None:
            return
        if self._pending:
            self._pending = False
            self._homes.append(int(outcome.vertex))
            self._home_odometer_m = self._odometer_m
            self._away = False
        elif self._odometer_m - self._home_odometer_m <= self.config.length_m:
            self._homes.append(int(outcome.vertex))

    # Persistent: the homes and where the search stands. A memory's next session keeps the earlier homes and
    # starts lost (`ExperienceMap.start_session`), which gives it a home of its own.
    def depends_on(self) -> dict[str, object]:
        return {}

    def export_state(self) -> dict[str, np.ndarray]:
        return {
            "vertices": np.array(self._homes, np.int64),
            "odometer_m": np.array([self._home_odometer_m, self._next_try_m], np.float64),
            "flags": np.array([self._pending, self._away], np.bool_),
        }

    def restore_state(self, saved: dict[str, np.ndarray]) -> None:
        if not {"vertices", "odometer_m", "flags"} <= saved.keys():
            return  # a damaged state: start fresh
        vertices = np.asarray(saved["vertices"], np.int64).ravel()
        odometer_m = np.asarray(saved["odometer_m"], np.float64).ravel()
        flags = np.asarray(saved["flags"], np.bool_).ravel()
        if len(odometer_m) != 2 or len(flags) != 2 or (vertices < 0).any():
            return
        self._homes = [int(v) for v in vertices]
        self._home_odometer_m, self._next_try_m = float(odometer_m[0]), float(odometer_m[1])
        self._pending, self._away = bool(flags[0]), bool(flags[1])
        self._known = True
