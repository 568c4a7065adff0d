"""An open-field session: the spatial memory driven along a foraging trajectory, every unit recorded.

Per step (`step_dt_s`): the landmark view of the pose at the step's end may recall a stored state
(`LandmarkViews`), the engine integrates the head's angular velocity and the speed along the head's direction
(`Trajectory.drive`), and a new landmark cell stores the state it leaves. Every `sample_dt_s` the recording
takes every unit of every population (`hippo_nav.recording.Recording`), the true pose and the decoded one.

The network starts where the animal starts: the ring's bump at the animal's head direction, every module's
bump at phase 0, so a unit's phase θ maps to the positions `x₀ + θ·P/2π + n·P/k`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.engine import EngineConfig, SpatialMemory, ViewPatterns
from hippo_nav.engine.config import MODULE_NAMES
from hippo_nav.engine.recall import CompactView
from hippo_nav.openfield.config import LandmarkConfig, OpenFieldConfig
from hippo_nav.openfield.trajectory import Trajectory, foraging_trajectory
from hippo_nav.recording import GRID_POPULATIONS, Recording

__all__ = ["LandmarkViews", "engine_config", "record_session"]


def engine_config(config: OpenFieldConfig) -> EngineConfig:
    """The engine for an arena: the session's torus period, sub-step and HD range, the lesion applied."""
    lesioned = [config.lesion == name for name in MODULE_NAMES]
    return EngineConfig.model_validate(
        {
            "torus_period_m": config.torus_period_m,
            "max_substep_s": config.max_substep_s,
            "hd": {"nu_max": config.hd_nu_max},
            "grid": {"nu_max": config.grid_nu_max},
            "lesioned": lesioned,
        }
    )


@dataclass
class _Cell:
    view: CompactView
    position_m: np.ndarray
    heading_rad: float
    last_active_s: float


class LandmarkViews:
    """The arena's landmark view cells (`LandmarkConfig`): a cell per place bin and heading sector."""

    def __init__(self, config: LandmarkConfig, torus_period_m: float) -> None:
        self.config = config
        self._period_m = torus_period_m
        self._cells: dict[tuple[int, int, int], _Cell] = {}
        self._active: tuple[int, int, int] | None = None
        self._active_steps = 0
        self._recalling = False
        self.recalls = 0

    def __len__(self) -> int:
        return len(self._cells)

    def key(self, position_m: np.ndarray, heading_rad: float) -> tuple[int, int, int]:
        size = self.config.cell_size_m
        sector = math.floor((heading_rad % (2 * math.pi)) / (2 * math.pi) * self.config.heading_sectors)
        return (
            math.floor(position_m[0] / size),
            math.floor(position_m[1] / size),
            sector % self.config.heading_sectors,
        )

    def recall(self, position_m: np.ndarray, heading_rad: float, time_s: float) -> ViewPatterns | None:
        """What the view at this pose injects into the step that ends here, if anything."""
        if not self.config.enabled:
            return None
        key = self.key(position_m, heading_rad)
        cell = self._cells.get(key)
        if key != self._active:
            # A cell that comes back within the gap is the same passage: recalling its older state would
            # pull the network back along the path it is on.
            self._recalling = cell is not None and time_s - cell.last_active_s >= self.config.revisit_gap_s
            self._active, self._active_steps = key, 0
        else:
            self._active_steps += 1
        if cell is None:
            return None
        cell.last_active_s = time_s
        strength = self.config.initial_strength * self.config.decay_per_step**self._active_steps
        if not self._recalling or strength < self.config.min_strength:
            return None
        if self._active_steps == 0:
            self.recalls += 1
        moved = position_m - cell.position_m
        shift = (2 * math.pi * moved[0] / self._period_m, 2 * math.pi * moved[1] / self._period_m)
        return cell.view.patterns(strength, heading_rad - cell.heading_rad, shift)

    def remember(
        self, engine: SpatialMemory, position_m: np.ndarray, heading_rad: float, time_s: float
    ) -> None:
        """A view seen for the first time stores the state the step left."""
        if not self.config.enabled:
            return
        key = self.key(position_m, heading_rad)
        if key not in self._cells:
            self._cells[key] = _Cell(CompactView.from_engine(engine), position_m.copy(), heading_rad, time_s)


class _Recorder:
    """Every unit of every population at the sample steps (module doc of hippo_nav.recording.session)."""

    def __init__(self, engine: SpatialMemory, samples: int) -> None:
        cfg = engine.config
        self._cell = [cfg.place.n_theta // g.k for g in cfg.grid]
        self.rates: dict[str, np.ndarray] = {"hd": np.zeros((samples, cfg.hd.n_theta), np.float32)}
        for name, side in zip(GRID_POPULATIONS, self._cell):
            self.rates[name] = np.zeros((samples, side * side), np.float32)
        self.rates["place"] = np.zeros((samples, cfg.place.n_theta**2), np.float32)
        self.decoded_position_m = np.zeros((samples, 2))
        self.decoded_heading_rad = np.zeros(samples)

    def take(self, i: int, engine: SpatialMemory, readout: object) -> None:
        self.rates["hd"][i] = engine.hd_profile()
        for m, (name, side) in enumerate(zip(GRID_POPULATIONS, self._cell)):
            if not engine.config.lesioned[m]:
                self.rates[name][i] = engine.grid_layer2(m)[:side, :side].ravel()
        self.rates["place"][i] = engine.place_activity().ravel()
        self.decoded_position_m[i] = readout.place_position_m  # type: ignore[attr-defined]
        self.decoded_heading_rad[i] = readout.heading_rad  # type: ignore[attr-defined]

    def phases(self, engine: SpatialMemory) -> dict[str, np.ndarray]:
        cfg = engine.config
        n = cfg.place.n_theta
        out = {"hd": 2 * np.pi * np.arange(cfg.hd.n_theta) / cfg.hd.n_theta}
        for name, side in zip([*GRID_POPULATIONS, "place"], [*self._cell, n]):
            iy, ix = np.divmod(np.arange(side * side), side)
            out[name] = np.stack([2 * np.pi * ix / n, 2 * np.pi * iy / n], axis=1)
        return out


def record_session(
    config: OpenFieldConfig,
    trajectory: Trajectory | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Recording:
    """Drive the spatial memory along `trajectory` (RatInABox foraging per `config` when None) and record
    every unit every `sample_dt_s`. `progress(done, total)` is called every sample."""
    traj = trajectory if trajectory is not None else foraging_trajectory(config)
    if trajectory is not None and abs(traj.step_dt_s - config.step_dt_s) > 1e-9:
        raise HippoNavError(f"the trajectory steps {traj.step_dt_s} s, the session {config.step_dt_s} s")
    engine = SpatialMemory(engine_config(config))
    engine.reset(heading_rad=float(traj.head_direction_rad[0]))
    yaw_rate, speed = traj.drive()
    every = config.steps_per_sample
    samples = len(yaw_rate) // every + 1
    recorder = _Recorder(engine, samples)
    views = LandmarkViews(config.landmarks, config.torus_period_m)
    origin = traj.position_m[0]
    recorder.take(0, engine, engine.readout())
    views.remember(engine, origin - origin, float(traj.head_direction_rad[0]), 0.0)
    for i in range(len(yaw_rate)):
        here, heading, now = (
            traj.position_m[i + 1] - origin,
            float(traj.head_direction_rad[i + 1]),
            traj.time_s[i + 1],
        )
        view = views.recall(here, heading, float(now))
        try:
            readout = engine.step(float(yaw_rate[i]), float(speed[i]), traj.step_dt_s, view)
        except HippoNavError as err:
            raise HippoNavError(
                f"step {i} (t = {now:.2f} s) of {traj.source}: {err}{traj.cut_short_hint}"
            ) from None
        views.remember(engine, here, heading, float(now))
        if (i + 1) % every == 0:
            recorder.take((i + 1) // every, engine, readout)
            if progress is not None:
                progress((i + 1) // every, samples - 1)
    sampled = slice(0, samples * every, every)
    return Recording(
        time_s=traj.time_s[sampled].copy(),
        position_m=traj.position_m[sampled].copy(),
        heading_rad=traj.head_direction_rad[sampled].copy(),
        speed_m_s=np.concatenate([[0.0], speed])[sampled],
        decoded_position_m=recorder.decoded_position_m + origin,
        decoded_heading_rad=recorder.decoded_heading_rad,
        populations=recorder.rates,
        unit_phase_rad=recorder.phases(engine),
        torus_period_m=config.torus_period_m,
        module_k=tuple(g.k for g in engine.config.grid),
        lesioned=tuple(engine.config.lesioned),
        metadata={
            "arena": {"shape": config.arena_shape, "size_m": config.arena_size_m},
            "trajectory": traj.source,
            # A given trajectory sets the session's length, whatever the config's `duration_s` said.
            "session": {
                **json.loads(config.model_dump_json()),
                "duration_s": float(traj.time_s[-1] - traj.time_s[0]),
            },
            "engine": json.loads(engine.config.to_json()),
            "landmark_cells": len(views),
            "landmark_recalls": views.recalls,
        },
    )
