"""An open-field session's settings: the arena, the animal's motion, the landmarks and the network.

Defaults are a rodent's: a 2 m square box (the size grid-cell labs record large modules in), RatInABox's
foraging statistics at a foraging rat's speed (0.16 ± 0.08 m/s: RatInABox's own 0.08 m/s left most of the
box unvisited in 10 minutes; rotational velocity σ 120 °/s), 20 minutes, and a torus period of
0.8 m, so the three modules' lattices have spacings 0.8, 0.4 and 0.2 m (the model's 1 : ½ : ¼) and the
coarsest one still fits 2.5 periods into the box, enough for its autocorrelogram to show the lattice.

The engine's velocity ranges are widened for a rat, measured on a 20 s circle (radius 0.3 m, 0.15 m/s) against
the integrated path: a car turns at ≲ 2 rad/s, a foraging rat's head at up to 7.5 rad/s (RatInABox, smoothed
as `trajectory` says, 20 minutes), beyond the default ring's ±3.7 rad/s. `hd_nu_max` 0.25 with 20 ms
sub-steps represents ±11 rad/s and keeps the heading within 0.12° on the circle; 0.3 loses 14° (the ring's
velocity tuning is not rescaled with its range). One sub-step per 20 ms step: a 20-minute session is
60 000 engine steps. The grid modules' range: at P = 0.8 m and 20 ms sub-steps the default 0.06 represents
±0.33 m/s per axis, and RatInABox at 0.16 m/s mean reaches 0.83 m/s; `grid_nu_max` 0.18 (±1.0 m/s) integrates
the circle to 1.1 % of its length, as 0.15 and 0.2 do, while 0.22 gives 7 %. The tori keep their default
sizes.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from hippo_nav._defaults import ConfigSection

__all__ = ["LESIONS", "LandmarkConfig", "OpenFieldConfig"]

LESIONS = ("none", "ventral", "intermediate", "dorsal")
"""Lesion conditions ("MEC inactivation"): no module off, or one grid module off."""


class LandmarkConfig(ConfigSection):
    """The arena's cues as view cells (docs/spec.md §7): the view from a place and heading sector is a cell.
    The first time a cell is seen it stores the network's state (`CompactView`); seen again after
    `revisit_gap_s`, it recalls that state, moved by the pose between then and now (the view measures where
    the animal stands relative to where it stood, as the pipeline's `measured` placement does), and injects
    it with strength `initial_strength · decay_per_step^a`, `a` the steps it has stayed active. Without them
    the networks integrate motion alone and drift (docs/neuro.md says by how much), as grid maps do in
    rodents in darkness."""

    enabled: bool = True
    cell_size_m: float = Field(0.2, gt=0.0, le=10.0, description="side of a landmark view cell's place bin")
    heading_sectors: int = Field(8, ge=1, le=360, description="heading sectors per place bin")
    revisit_gap_s: float = Field(
        5.0, ge=0.0, le=600.0, description="a cell recalls only when it was last active this long ago"
    )
    initial_strength: float = Field(1.0, ge=0.0, le=1e3, description="injection strength on the first step")
    decay_per_step: float = Field(0.7, gt=0.0, le=1.0, description="factor per step the cell stays active")
    min_strength: float = Field(0.05, ge=0.0, description="injection stops below this strength")


class OpenFieldConfig(ConfigSection):
    """One open-field session (module doc)."""

    arena_shape: Literal["square", "circle"] = "square"
    arena_size_m: float = Field(2.0, gt=0.1, le=100.0, description="side of the square or circle's diameter")
    duration_s: float = Field(1200.0, gt=0.0, le=86_400.0, description="session length (s)")
    step_dt_s: float = Field(0.02, ge=0.001, le=0.1, description="trajectory and network step (s)")
    sample_dt_s: float = Field(0.1, ge=0.001, le=10.0, description="recording interval (s)")
    speed_mean_m_s: float = Field(0.16, gt=0.0, le=5.0, description="RatInABox speed_mean (module doc)")
    speed_std_m_s: float = Field(0.08, ge=0.0, le=5.0, description="RatInABox speed_std")
    rotational_velocity_std_rad_s: float = Field(
        2.0943951023931953, ge=0.0, le=20.0, description="RatInABox rotational_velocity_std (120 °/s)"
    )
    seed: int = Field(0, ge=0, le=2**32 - 1, description="trajectory seed (the networks are deterministic)")
    torus_period_m: float = Field(0.8, ge=0.1, le=1e5, description="the torus period P (module k: P/k)")
    hd_nu_max: float = Field(
        0.25, gt=0.0, le=1.0, description="the HD ring's velocity half-range (module doc)"
    )
    grid_nu_max: float = Field(0.18, gt=0.0, le=1.0, description="each grid module's velocity half-range")
    max_substep_s: float = Field(0.02, ge=1e-4, le=0.1, description="the engine's longest sub-step (s)")
    lesion: Literal["none", "ventral", "intermediate", "dorsal"] = "none"
    landmarks: LandmarkConfig = Field(default_factory=LandmarkConfig)

    @model_validator(mode="after")
    def _sampling_fits(self) -> OpenFieldConfig:
        steps = self.sample_dt_s / self.step_dt_s
        if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
            raise ValueError(
                f"sample_dt_s = {self.sample_dt_s} must be a whole multiple of step_dt_s = {self.step_dt_s}"
            )
        if self.duration_s < 2 * self.sample_dt_s:
            raise ValueError(f"duration_s = {self.duration_s} holds fewer than two samples")
        return self

    @property
    def steps_per_sample(self) -> int:
        return round(self.sample_dt_s / self.step_dt_s)
