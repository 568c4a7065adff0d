"""The per-frame system's policies: small objects that own their state (docs/pipeline.md, "Per frame").

- `ViewRecall`: which stored views a frame is compared with, which view cell is active, and what a familiar
  one recalls — the network state stored when its view was first seen (`CompactView`), injected with a
  decaying strength (`InjectionConfig`), and the vertex where it was first seen (a loop closure's anchor).
- `MotionLimiter`: what the engine is given — the odometry's planar step as velocities, over at most
  `max_gap_s`, clamped to `MotionLimits`, held still when the engine refuses.

(The third, loop closing, is a `hippo_nav.closure.ClosureProposer`; the odometry's failure prior is the
front end's `OdometryGuard`.)
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.engine import CompactView, SpatialMemory, SpatialReadout, ViewPatterns
from hippo_nav.map import ExperienceMap
from hippo_nav.pipeline.config import InjectionConfig, MotionLimits, ViewSearchConfig
from hippo_nav.view_cells import ViewDescriptor, ViewObservation

log = logging.getLogger("hippo_nav.pipeline")

__all__ = ["Motion", "MotionLimiter", "ViewRecall"]


class ViewRecall:
    """Local view cells as the system uses them (module doc).

    Per frame: `observe` (match the frame's description against the cells near the agent; updates which
    cell is active and for how long), `injection` (the recalled patterns and their strength), after the
    engine step `remember` (a new cell stores the network's state), after the map `anchor` (a new cell
    remembers its vertex). `active_cell` is the cell the map is given: the last informative one.
    """

    def __init__(
        self, descriptor: ViewDescriptor, search: ViewSearchConfig, injection: InjectionConfig
    ) -> None:
        self.descriptor = descriptor
        self.search = search
        self.injection_config = injection
        self.stored: dict[int, CompactView] = {}  # view cell -> the network state recalled on revisits
        self._cell_vertex: dict[int, int] = {}  # view cell -> the vertex the agent was at when it was made
        self._vertex_cells: dict[int, list[int]] = {}  # the inverse
        self.active_cell: int | None = None
        self._active_run = 0  # frames the active cell has stayed active, after the first
        self._last_active: dict[int, int] = {}  # view cell -> run position it was last active at
        self._activation_gap: int | None = None  # frames between the active cell's last two activations

    def __len__(self) -> int:
        return len(self.descriptor)

    def anchor_of(self, cell: int) -> int | None:
        """The vertex the agent was at when `cell` was made (None: it was made while lost)."""
        return self._cell_vertex.get(cell)

    def candidates(self, planar_step: Sequence[float], experience_map: ExperienceMap) -> list[int] | None:
        """The cells to compare this frame with (None: all; see `ViewSearchConfig`)."""
        cfg = self.search
        if not cfg.near_only or len(experience_map) == 0:
            return None
        radius_m = min(experience_map.loop_gate()[0] + cfg.radius_margin_m, cfg.max_radius_m)
        step = (float(planar_step[0]), float(planar_step[1]), float(planar_step[2]))
        cells = [
            c for v in experience_map.vertices_near(radius_m, step) for c in self._vertex_cells.get(v, ())
        ]
        n = len(self.descriptor)
        cells.extend(range(max(n - cfg.recent_cells, 0), n))
        return cells

    def observe(
        self, description: Any, planar_step: Sequence[float], experience_map: ExperienceMap, position: int
    ) -> ViewObservation:
        """Match this frame (run position `position`) and track which cell is active."""
        obs = self.descriptor.observe(description, self.candidates(planar_step, experience_map))
        if obs.cell_id is not None:
            cell = int(obs.cell_id)
            if cell == self.active_cell:
                self._active_run += 1
            else:
                self._active_run = 0
                last = self._last_active.get(cell)
                self._activation_gap = position - last if last is not None else None
            self._last_active[cell] = position
            self.active_cell = cell
        return obs

    def injection(self, obs: ViewObservation) -> tuple[ViewPatterns | None, float]:
        """The stored patterns of a familiar view, scaled by the decaying strength (docs/model.md)."""
        cfg = self.injection_config
        if not cfg.enabled or obs.is_new or obs.cell_id is None:
            return None, 0.0
        stored = self.stored.get(int(obs.cell_id))
        # Only a revisit injects: a cell seen again within `revisit_gap_frames` belongs to the passage the
        # agent is still on, and its (older) stored state would drag path integration backwards.
        gap = self._activation_gap
        if stored is None or gap is None or gap <= cfg.revisit_gap_frames:
            return None, 0.0
        strength = cfg.initial_strength * cfg.decay_per_frame**self._active_run
        if strength < cfg.min_strength or strength == 0.0:
            return None, 0.0
        # The stored heading is where the camera faced when the view was stored; now it faces
        # `relative_heading_rad` further (counter-clockwise), so the recalled heading turns with it.
        offset = float(obs.relative_heading_rad) if cfg.shift_heading else 0.0
        return stored.patterns(strength=strength, heading_offset_rad=offset), strength

    def remember(self, obs: ViewObservation, engine: SpatialMemory) -> None:
        """After the engine step of the frame that made a new cell: store what the cell recalls, the bumps'
        phases and widths (88 bytes), not the patterns (~50 kB)."""
        if obs.is_new and obs.cell_id is not None:
            self.stored[int(obs.cell_id)] = CompactView.from_engine(engine)

    def anchor(self, obs: ViewObservation, vertex: int | None) -> None:
        """After the map took the frame that made a new cell: the vertex the agent is at."""
        if obs.is_new and obs.cell_id is not None and vertex is not None:
            self._cell_vertex[int(obs.cell_id)] = int(vertex)
            self._vertex_cells.setdefault(int(vertex), []).append(int(obs.cell_id))


@dataclass(frozen=True)
class Motion:
    """What the engine integrated for one frame, and why it differs from the odometry if it does."""

    yaw_rate_rad_s: float
    speed_m_s: float
    flag: str  # "ok", "vo:<status>", "gap", "clamped" or "engine_skipped"


class MotionLimiter:
    """Drives the engine with the odometry's planar step (module doc). The engine gets `yaw_rate = Δyaw/dt`
    and `speed = ±|Δxy|/dt` (negative when reversing)."""

    def __init__(self, limits: MotionLimits) -> None:
        self.limits = limits

    def drive(
        self,
        engine: SpatialMemory,
        planar_step: Sequence[float],
        dt_s: float,
        vo_status: str,
        view: ViewPatterns | None,
    ) -> tuple[SpatialReadout, Motion]:
        """Step the engine (not on the first frame: there is no motion yet); clamp absurd motion, and if the
        engine still refuses, hold still."""
        flag = "ok" if vo_status in ("ok", "first") else f"vo:{vo_status}"
        if dt_s <= 0:
            return engine.readout(), Motion(0.0, 0.0, flag)
        limits = self.limits
        if dt_s > limits.max_gap_s:
            # Integrate the measured step over the longest plausible frame time, not over the whole gap
            # (the networks cannot represent slow motion over minutes, and need not).
            dt_s = limits.max_gap_s
            flag = "gap"
        forward_m, left_m, yaw_rad = (float(v) for v in planar_step)
        yaw_rate = yaw_rad / dt_s
        speed = float(np.copysign(np.hypot(forward_m, left_m), forward_m)) / dt_s
        if abs(speed) > limits.max_speed_m_s or abs(yaw_rate) > limits.max_yaw_rate_rad_s:
            speed = float(np.clip(speed, -limits.max_speed_m_s, limits.max_speed_m_s))
            yaw_rate = float(np.clip(yaw_rate, -limits.max_yaw_rate_rad_s, limits.max_yaw_rate_rad_s))
            flag = "clamped"
        try:
            return engine.step(yaw_rate, speed, dt_s, view), Motion(yaw_rate, speed, flag)
        except HippoNavError as err:
            log.warning(
                "engine refused yaw rate %.3g rad/s, speed %.3g m/s (%s); frame held", yaw_rate, speed, err
            )
        # dt outside the engine's range (a long gap) or velocities it cannot represent: hold still.
        held = Motion(0.0, 0.0, "engine_skipped")
        try:
            return engine.step(0.0, 0.0, min(max(dt_s, 1e-3), 10.0), view), held
        except HippoNavError:
            return engine.readout(), held
