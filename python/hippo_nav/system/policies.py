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

import bisect
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.engine import CompactView, SpatialMemory, SpatialReadout, ViewPatterns
from hippo_nav.geometry import se2_between, se2_compose
from hippo_nav.map import ExperienceMap
from hippo_nav.system.config import CorrectionConfig, InjectionConfig, MotionLimits, ViewSearchConfig
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
        self,
        descriptor: ViewDescriptor,
        search: ViewSearchConfig,
        injection: InjectionConfig,
        torus_period_m: float = 100.0,
    ) -> None:
        self.descriptor = descriptor
        self.torus_period_m = float(torus_period_m)
        self.search = search
        self.injection_config = injection
        self.stored: dict[int, CompactView] = {}  # view cell -> the network state recalled on revisits
        self._cell_vertex: dict[int, int] = {}  # view cell -> the vertex the agent was at when it was made
        # view cell -> where it was made, seen from that vertex (planar forward, left, yaw)
        self._cell_offset: dict[int, tuple[float, float, float]] = {}
        self._vertex_cells: dict[int, list[int]] = {}  # the inverse
        self.active_cell: int | None = None
        self._active_run = 0  # frames the active cell has stayed active, after the first
        self._last_active: dict[int, int] = {}  # view cell -> run position it was last active at
        self._activation_gap: int | None = None  # frames between the active cell's last two activations
        self._made_at_m: list[float] = []  # view cell -> the map's odometer when it was made (non-decreasing)

    def __len__(self) -> int:
        return len(self.descriptor)

    def anchor_of(self, cell: int) -> int | None:
        """The vertex the agent was at when `cell` was made (None: it was made while lost)."""
        return self._cell_vertex.get(cell)

    def candidates(self, planar_step: Sequence[float], experience_map: ExperienceMap) -> list[int] | None:
        """The cells to compare this frame with (None: all; see `ViewSearchConfig`)."""
        cfg = self.search
        # In a session not yet joined to its loaded map, the odometry says nothing about where the agent is.
        if not cfg.near_only or len(experience_map) == 0 or experience_map.unjoined_from is not None:
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
        self, description: object, planar_step: Sequence[float], experience_map: ExperienceMap, position: int
    ) -> ViewObservation:
        """Match this frame (run position `position`) and track which cell is active."""
        odometer_m = experience_map.odometer_m + float(np.hypot(planar_step[0], planar_step[1]))
        # The passage the agent is on: the cells made within the last `passage_m` of travel.
        first_recent = bisect.bisect_left(self._made_at_m, odometer_m - self.search.passage_m)
        recent = list(range(first_recent, len(self._made_at_m)))
        obs = self.descriptor.observe(description, self.candidates(planar_step, experience_map), recent)
        if obs.is_new and obs.cell_id is not None and int(obs.cell_id) == len(self._made_at_m):
            self._made_at_m.append(odometer_m)
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

    def injection(
        self,
        obs: ViewObservation,
        measured: tuple[int, tuple[float, float, float]] | None = None,
        experience_map: ExperienceMap | None = None,
    ) -> tuple[ViewPatterns | None, float]:
        """The stored patterns of a familiar view, scaled by the decaying strength (docs/model.md), placed
        as `InjectionConfig.placement` says. `measured`: this frame's measured loop closure (target vertex,
        agent_from_target), if any."""
        cfg = self.injection_config
        if not cfg.enabled:
            return None, 0.0
        if (
            experience_map is not None
            and experience_map.unjoined_from is not None
            and obs.cell_id is not None
        ):
            # A session not yet joined to its loaded map: the loaded cells' states are in a frame the networks
            # do not share yet (they are set when the session joins, `placed_state`).
            anchor = self._cell_vertex.get(int(obs.cell_id))
            if anchor is None or anchor < experience_map.unjoined_from:
                return None, 0.0
        if cfg.placement == "measured":
            return self._injection_measured(obs, measured, experience_map)
        if not self._revisit(obs):
            return None, 0.0
        strength = cfg.initial_strength * cfg.decay_per_frame**self._active_run
        # The stored heading is where the camera faced when the view was stored; now it faces
        # `relative_heading_rad` further (counter-clockwise), so the recalled heading turns with it.
        return self._recalled(int(obs.cell_id), strength, float(obs.relative_heading_rad))  # type: ignore[arg-type]

    def _revisit(self, obs: ViewObservation) -> bool:
        """Whether this frame's view is a familiar cell with a stored state, seen again after a gap. Only a
        revisit recalls: a cell seen again within `revisit_gap_frames` belongs to the passage the agent is
        still on, and its (older) stored state would drag path integration backwards."""
        if obs.is_new or obs.status != "familiar" or obs.cell_id is None:
            return False
        gap = self._activation_gap
        return (
            int(obs.cell_id) in self.stored
            and gap is not None
            and gap > self.injection_config.revisit_gap_frames
        )

    def _injection_measured(
        self,
        obs: ViewObservation,
        measured: tuple[int, tuple[float, float, float]] | None,
        experience_map: ExperienceMap | None,
    ) -> tuple[ViewPatterns | None, float]:
        """`measured` placement: recall the familiar cell's state moved to where the measured closure puts
        the agent relative to where the cell was made."""
        if measured is None or experience_map is None or not self._revisit(obs):
            return None, 0.0
        cell = int(obs.cell_id)  # type: ignore[arg-type]
        target, agent_from_target = measured
        world_from_agent = se2_compose(
            np.array(experience_map.vertex_pose(target)),
            se2_between(np.array(agent_from_target), np.zeros(3)),
        )
        moved = self._moved(cell, experience_map, world_from_agent)
        if moved is None or moved[1] > self.injection_config.max_placement_m:
            return None, 0.0
        _, _, yaw_rad, shift_rad = moved
        strength = (
            self.injection_config.initial_strength * self.injection_config.decay_per_frame**self._active_run
        )
        return self._recalled(cell, strength, yaw_rad, shift_rad, always_shift=True)

    def _moved(
        self, cell: int, experience_map: ExperienceMap, world_from_agent: np.ndarray
    ) -> tuple[CompactView, float, float, tuple[float, float]] | None:
        """What `cell` stored, and how far the agent at `world_from_agent` (map frame) is from where the cell
        was made: (stored state, distance m, turn rad, the bumps' shift on the torus (rad)); None when the
        cell stores nothing or has no anchor."""
        stored, anchor = self.stored.get(cell), self._cell_vertex.get(cell)
        offset = self._cell_offset.get(cell)
        if stored is None or anchor is None or offset is None:
            return None
        world_from_made = se2_compose(np.array(experience_map.vertex_pose(anchor)), np.array(offset))
        forward_m, left_m, yaw_rad = (float(v) for v in se2_between(world_from_made, world_from_agent))
        # The stored heading code ψ is the engine-frame direction the agent faced when the view was made: a
        # displacement (forward, left) from there is ψ-rotated into the engine frame, and moves every
        # module's bumps by 2π·d/P on the shared torus.
        psi = stored.hd.heading_rad
        dx = np.cos(psi) * forward_m - np.sin(psi) * left_m
        dy = np.sin(psi) * forward_m + np.cos(psi) * left_m
        scale = 2.0 * np.pi / self.torus_period_m
        return stored, float(np.hypot(forward_m, left_m)), yaw_rad, (float(scale * dx), float(scale * dy))

    def _recalled(
        self,
        cell: int,
        strength: float,
        relative_heading_rad: float,
        shift_rad: tuple[float, float] = (0.0, 0.0),
        always_shift: bool = False,
    ) -> tuple[ViewPatterns | None, float]:
        """A cell's stored patterns at `strength` (None below `min_strength`), the heading turned by
        `relative_heading_rad` when `shift_heading` (always for a measured placement), the bumps moved by
        `shift_rad`."""
        cfg = self.injection_config
        stored = self.stored.get(cell)
        if stored is None or strength < cfg.min_strength or strength == 0.0:
            return None, 0.0
        offset = relative_heading_rad if (cfg.shift_heading or always_shift) else 0.0
        return stored.patterns(strength=strength, heading_offset_rad=offset, shift_rad=shift_rad), strength

    def remember(self, obs: ViewObservation, engine: SpatialMemory) -> None:
        """After the engine step of the frame that made a new cell: store what the cell recalls, the bumps'
        phases and widths (88 bytes), not the patterns (~50 kB)."""
        if obs.is_new and obs.cell_id is not None:
            self.stored[int(obs.cell_id)] = CompactView.from_engine(engine)

    def placed_state(
        self, cell: int, experience_map: ExperienceMap, world_from_agent: Sequence[float]
    ) -> tuple[float, tuple[float, float]] | None:
        """The heading and torus phase the networks should hold for the agent at `world_from_agent` (map
        frame), from what `cell` stored where it was made, moved as a measured injection moves it (None: the
        cell stores nothing, or every module is lesioned). Used to set the networks when a session joins a
        loaded map (docs/memory.md)."""
        moved = self._moved(cell, experience_map, np.array(world_from_agent))
        if moved is None:
            return None
        stored, _, yaw_rad, (dx, dy) = moved
        modules = [m for m in stored.modules if m is not None]
        if not modules:
            return None
        # The coarsest stored module fixes the torus phase; finer ones agree with it modulo their period.
        phase = modules[0].phase_rad
        heading = stored.hd.heading_rad + yaw_rad
        return heading, ((phase[0] + dx) % (2 * np.pi), (phase[1] + dy) % (2 * np.pi))

    def forget_states(self, cells: Sequence[int]) -> None:
        """Drop what `cells` recall (their stored states were made in a frame the networks have left)."""
        for cell in cells:
            self.stored.pop(int(cell), None)

    def export_state(self) -> dict[str, np.ndarray]:
        """Everything this policy keeps, as arrays for a memory folder (the descriptor's cells apart)."""
        stored_cells = sorted(self.stored)
        sizes = next(iter(self.stored.values())).sizes if self.stored else (0, 0, ())
        cells = sorted(self._cell_vertex)
        with_offset = sorted(self._cell_offset)
        last = sorted(self._last_active.items())
        return {
            "stored_cell": np.array(stored_cells, np.int64),
            "stored_values": np.array([self.stored[c].values for c in stored_cells], np.float32).reshape(
                len(stored_cells), -1 if stored_cells else 0
            ),
            "stored_sizes": np.array([sizes[0], sizes[1], *sizes[2]], np.int64),
            "anchor_cell": np.array(cells, np.int64),
            "anchor_vertex": np.array([self._cell_vertex[c] for c in cells], np.int64),
            "offset_cell": np.array(with_offset, np.int64),
            "offset": np.array([self._cell_offset[c] for c in with_offset], np.float64).reshape(-1, 3),
            "made_at_m": np.array(self._made_at_m, np.float64),
            # Where the agent was in the passage of view cells (what a session continuing needs).
            "active_cell": np.array(-1 if self.active_cell is None else self.active_cell, np.int64),
            "active_run": np.array(self._active_run, np.int64),
            "last_active": np.array(last, np.int64).reshape(-1, 2),
            "activation_gap": np.array(
                -1 if self._activation_gap is None else self._activation_gap, np.int64
            ),
        }

    def restore_state(self, saved: dict[str, np.ndarray], *, resume: bool) -> None:
        """Take the state of `export_state`; with `resume` also where the agent was (else: no active cell)."""
        for name in ("offset", "made_at_m"):  # (stored values are NaN where a module was lesioned)
            if not np.isfinite(np.asarray(saved[name], np.float64)).all():
                # What this package saves is finite; a NaN here would surface later as "not finite" input
                # to the networks, blamed on the odometry.
                raise HippoNavError(
                    f"the saved view recall's {name} holds NaN or infinity; the memory is damaged"
                )
        sizes = [int(v) for v in saved["stored_sizes"]]
        self.stored = {
            int(c): CompactView(values, sizes[0], sizes[1], sizes[2:])
            for c, values in zip(saved["stored_cell"].tolist(), np.asarray(saved["stored_values"]))
        }
        self._cell_vertex = {int(c): int(v) for c, v in zip(saved["anchor_cell"], saved["anchor_vertex"])}
        self._cell_offset = {
            int(c): (float(o[0]), float(o[1]), float(o[2]))
            for c, o in zip(saved["offset_cell"], saved["offset"])
        }
        self._vertex_cells = {}
        for cell in sorted(self._cell_vertex):
            self._vertex_cells.setdefault(self._cell_vertex[cell], []).append(cell)
        self._made_at_m = [float(v) for v in saved["made_at_m"]]
        if resume:
            active = int(saved["active_cell"])
            self.active_cell = None if active < 0 else active
            self._active_run = int(saved["active_run"])
            self._last_active = {int(c): int(p) for c, p in saved["last_active"]}
            gap = int(saved["activation_gap"])
            self._activation_gap = None if gap < 0 else gap

    def anchor(
        self,
        obs: ViewObservation,
        vertex: int | None,
        vertex_from_agent: tuple[float, float, float] | None = None,
    ) -> None:
        """After the map took the frame that made a new cell: the vertex the agent is at, and where the
        agent is seen from it."""
        if obs.is_new and obs.cell_id is not None and vertex is not None:
            self._cell_vertex[int(obs.cell_id)] = int(vertex)
            if vertex_from_agent is not None:
                self._cell_offset[int(obs.cell_id)] = tuple(float(v) for v in vertex_from_agent)  # type: ignore[assignment]
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

    def __init__(self, limits: MotionLimits, stride: int = 1) -> None:
        self.limits = limits
        # `max_gap_s` is per sequence frame: a run of every 20th frame of a 10 Hz sequence has 2 s between
        # its frames, which is no gap (unscaled, every frame was flagged and its motion squeezed into 1 s).
        self.max_gap_s = limits.max_gap_s * max(int(stride), 1)
        self._clamping = False  # the last frame was clamped: a stretch of them is said once, at its start

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
        if dt_s > self.max_gap_s:
            # Integrate the measured step over the longest plausible frame time, not over the whole gap
            # (the networks cannot represent slow motion over minutes, and need not).
            dt_s = self.max_gap_s
            flag = "gap"
        forward_m, left_m, yaw_rad = (float(v) for v in planar_step)
        yaw_rate = yaw_rad / dt_s
        speed = float(np.copysign(np.hypot(forward_m, left_m), forward_m)) / dt_s
        if abs(speed) > limits.max_speed_m_s or abs(yaw_rate) > limits.max_yaw_rate_rad_s:
            if not self._clamping:
                log.warning(
                    "motion of %.4g m/s and %.4g rad/s is beyond the networks' limits (%.4g m/s, %.4g rad/s): "
                    "clamped from here until it is plausible again (frames.csv flags each frame 'clamped'); "
                    "check the odometry (its units, its frame rate, a jump)",
                    speed,
                    yaw_rate,
                    limits.max_speed_m_s,
                    limits.max_yaw_rate_rad_s,
                )
            self._clamping = True
            speed = float(np.clip(speed, -limits.max_speed_m_s, limits.max_speed_m_s))
            yaw_rate = float(np.clip(yaw_rate, -limits.max_yaw_rate_rad_s, limits.max_yaw_rate_rad_s))
            flag = "clamped"
        else:
            self._clamping = False
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


def final_correction(experience_map: ExperienceMap, cfg: CorrectionConfig) -> dict[str, Any]:
    """The configured correction run once after the last frame; its report (method "none" when disabled,
    loop-free, or when a session never joined its loaded map: the loaded part was corrected by its own run
    and nothing links the session's part to it)."""
    if experience_map.unjoined_from is not None:
        return {"method": "none", "reason": "not relocalised in the loaded map"}
    if cfg.method == "none" or not np.asarray(experience_map.export()["link_is_loop"]).any():
        return {"method": "none", "reason": "disabled" if cfg.method == "none" else "no loop closure"}
    if cfg.method == "relaxation":
        report = experience_map.correct("relaxation", passes=cfg.relaxation_passes, gain=cfg.relaxation_gain)
    else:
        report = experience_map.correct(
            "least_squares",
            initialization="current",
            robust_loss=cfg.robust_loss,
            robust_scale_chi2=cfg.robust_scale_chi2,
            max_iterations=cfg.max_iterations,
        )
    return {"method": cfg.method, **report.as_dict()}
