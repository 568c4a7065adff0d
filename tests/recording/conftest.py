"""An ideal recording: a 10-minute random walk in a 1.5 m box at 20 Hz with tuning that is exactly the
model's design, so every measure has a known answer (spacing P/k, a square lattice, HD units preferring
their designed heading). Deterministic and small (12 000 samples, 148 units).

tests/recording is a package (an empty __init__.py) so that this file is `recording.conftest`: a conftest.py
outside a package is imported as `conftest` and would shadow tests/conftest.py for the `from conftest import …`
of every test module collected after it."""

from __future__ import annotations

import numpy as np
import pytest
from hippo_nav.recording import GRID_POPULATIONS, Recording

IDEAL_PERIOD_M = 1.0
IDEAL_ARENA_M = 1.5
IDEAL_MODULE_K = (1, 2, 4)
IDEAL_SAMPLE_DT_S = 0.05
IDEAL_DURATION_S = 600.0
GRID_KAPPA = 2.5
"""Concentration of each axis's von Mises-like bump: fields about a quarter of the spacing wide (FWHM)."""
HD_KAPPA = 4.0
"""Concentration of the HD units' von Mises tuning: mean vector length I1(4)/I0(4) = 0.86."""


def random_walk(seed: int = 7) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (T, 2) m, headings (T,) rad (the direction of motion) and speeds (T,) m/s of a walk with
    a smoothly wandering heading and speed, reflected at the walls of [0, IDEAL_ARENA_M]²."""
    rng = np.random.default_rng(seed)
    steps = round(IDEAL_DURATION_S / IDEAL_SAMPLE_DT_S)
    position = np.empty((steps, 2))
    heading = np.empty(steps)
    speed = np.empty(steps)
    here = np.array([0.5, 0.5]) * IDEAL_ARENA_M
    theta, v = 0.3, 0.25
    for i in range(steps):
        theta += rng.normal(0.0, 0.35)
        # Ornstein–Uhlenbeck speed around 0.25 m/s: a rat's foraging pace, enough to cover the box in 10 min.
        v = float(np.clip(v + 0.1 * (0.25 - v) + rng.normal(0.0, 0.03), 0.05, 0.5))
        step = v * IDEAL_SAMPLE_DT_S * np.array([np.cos(theta), np.sin(theta)])
        nxt = here + step
        for axis in range(2):
            if not 0.0 <= nxt[axis] <= IDEAL_ARENA_M:
                step[axis] = -step[axis]
                nxt[axis] = here[axis] + step[axis]
        theta = float(np.arctan2(step[1], step[0]))
        here = nxt
        position[i], heading[i], speed[i] = here, theta, v
    return position, heading, speed


def grid_phases(per_axis: int) -> np.ndarray:
    """Unit (i, j) (row-major, θy then θx) has phase (2πj/n, 2πi/n) (θx, θy), as `Recording` documents."""
    i, j = np.divmod(np.arange(per_axis * per_axis), per_axis)
    return np.stack([2 * np.pi * j / per_axis, 2 * np.pi * i / per_axis], axis=1)


def lattice_activity(position_m: np.ndarray, phases_rad: np.ndarray, k: int) -> np.ndarray:
    """Product over x, y of exp(κ(cos(2πk·x/P − φ) − 1)): a square lattice of fields, spacing P/k."""
    bump = 2 * np.pi * k * position_m / IDEAL_PERIOD_M
    x = np.exp(GRID_KAPPA * (np.cos(bump[:, None, 0] - phases_rad[None, :, 0]) - 1.0))
    y = np.exp(GRID_KAPPA * (np.cos(bump[:, None, 1] - phases_rad[None, :, 1]) - 1.0))
    return (x * y).astype(np.float32)


def make_ideal_recording() -> Recording:
    position, heading, speed = random_walk()
    populations: dict[str, np.ndarray] = {}
    phases: dict[str, np.ndarray] = {}
    hd_phase = 2 * np.pi * np.arange(36) / 36
    populations["hd"] = np.exp(HD_KAPPA * (np.cos(heading[:, None] - hd_phase[None, :]) - 1.0)).astype(
        np.float32
    )
    phases["hd"] = hd_phase
    for name, k in zip(GRID_POPULATIONS, IDEAL_MODULE_K):
        phases[name] = grid_phases(4)
        populations[name] = lattice_activity(position, phases[name], k)
    phases["place"] = grid_phases(6)
    populations["place"] = lattice_activity(position, phases["place"], 1)
    time_s = np.arange(len(position)) * IDEAL_SAMPLE_DT_S
    return Recording(
        time_s=time_s,
        position_m=position,
        heading_rad=heading,
        speed_m_s=speed,
        decoded_position_m=position.copy(),
        decoded_heading_rad=heading.copy(),
        populations=populations,
        unit_phase_rad=phases,
        torus_period_m=IDEAL_PERIOD_M,
        module_k=IDEAL_MODULE_K,
        lesioned=(False, False, False),
        metadata={"arena": {"shape": "square", "size_m": IDEAL_ARENA_M}, "trajectory": "ideal random walk"},
    )


@pytest.fixture(scope="session")
def ideal_recording() -> Recording:
    """The ideal recording (module doc). Shared by the session: copy before changing it."""
    return make_ideal_recording()
