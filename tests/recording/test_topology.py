"""Persistent homology of population activity (`hippo_nav.recording.topology`): an ideal grid module is a
torus, an ideal head-direction ring a circle, and activity without co-activity (noise, shuffles) neither."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ripser")
pytest.importorskip("sklearn")

from hippo_nav.recording import GRID_POPULATIONS, Recording
from hippo_nav.recording.topology import (
    TopologyError,
    TopologyParams,
    TopologyResult,
    activity_topology,
    population_topology,
    write_topology_figure,
)

BOX_M = 1.5
PERIOD_M = 1.5
"""The torus period: the box holds 1, 2 and 4 periods of the k = 1, 2, 4 modules, so each module's torus is
covered."""
FAST = TopologyParams(n_points=450, n_points_h2=200, n_shuffles=3)
"""Fewer points and shuffles than the defaults: ~5 s a call, and still every torus bar ≥ 2.5× the threshold
and every sampling bar ≤ 0.85× it (seeds 0–2)."""


def _walk(n_time: int, dt_s: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random walk in the box at 0.25 m/s whose heading diffuses; the walls turn it back."""
    position = np.empty((n_time, 2))
    heading = np.empty(n_time)
    position[0], heading[0] = BOX_M / 2, 0.0
    for t in range(1, n_time):
        h = heading[t - 1] + rng.normal(0.0, 0.25)
        step = 0.25 * dt_s * np.array([np.cos(h), np.sin(h)])
        if not np.all((position[t - 1] + step > 0) & (position[t - 1] + step < BOX_M)):
            h += np.pi
            step = -step
        position[t], heading[t] = position[t - 1] + step, h
    return position, np.mod(heading, 2 * np.pi)


def _torus_units(position: np.ndarray, n_side: int, k: int, kappa: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit (i, j) has phase (2πj/n, 2πi/n) and fires where the module's phase 2πk·x/P is near it: a product
    over x, y of von Mises bumps."""
    theta = 2 * np.pi * np.arange(n_side) / n_side
    tx, ty = np.meshgrid(theta, theta)
    phase = np.stack([tx.ravel(), ty.ravel()], axis=1)
    bump_phase = 2 * np.pi * k * position / PERIOD_M
    dx = bump_phase[:, :1] - phase[None, :, 0]
    dy = bump_phase[:, 1:] - phase[None, :, 1]
    return np.exp(kappa * (np.cos(dx) + np.cos(dy) - 2)).astype(np.float32), phase


def ideal_session(n_time: int = 6000, n_side: int = 16, seed: int = 0) -> Recording:
    """A small session with idealised tuning: three grid modules, a place torus, a 60-unit HD ring."""
    rng = np.random.default_rng(seed)
    dt_s = 0.05
    position, heading = _walk(n_time, dt_s, rng)
    populations, phases = {}, {}
    for name, k in zip(GRID_POPULATIONS, (1, 2, 4)):
        populations[name], phases[name] = _torus_units(position, n_side, k, kappa=4.0)
    populations["place"], phases["place"] = _torus_units(position, n_side, 1, kappa=8.0)
    hd_phase = 2 * np.pi * np.arange(60) / 60
    populations["hd"] = np.exp(4.0 * (np.cos(heading[:, None] - hd_phase[None]) - 1)).astype(np.float32)
    phases["hd"] = hd_phase
    speed = np.r_[0.0, np.linalg.norm(np.diff(position, axis=0), axis=1) / dt_s]
    return Recording(
        time_s=np.arange(n_time) * dt_s,
        position_m=position,
        heading_rad=heading,
        speed_m_s=speed,
        decoded_position_m=position.copy(),
        decoded_heading_rad=heading.copy(),
        populations=populations,
        unit_phase_rad=phases,
        torus_period_m=PERIOD_M,
        module_k=(1, 2, 4),
        lesioned=(False, False, False),
        metadata={"seed": seed, "arena": {"shape": "square", "size_m": BOX_M}},
    )


@pytest.fixture(scope="module")
def session() -> Recording:
    return ideal_session()


@pytest.fixture(scope="module")
def dorsal(session: Recording) -> TopologyResult:
    return population_topology(session, "grid_dorsal", FAST)


@pytest.mark.parametrize("population", ["grid_intermediate", "grid_dorsal"])
def test_an_ideal_grid_module_is_a_torus(session: Recording, dorsal: TopologyResult, population: str) -> None:
    result = dorsal if population == "grid_dorsal" else population_topology(session, population, FAST)
    assert result.betti == (1, 2, 1), result.summary()
    assert result.is_torus
    # The torus's two circles and its void stand well clear of the shuffles' longest bars, and the next
    # loop (a sampling artefact) well under them.
    assert result.lifetimes[1][1] > 2 * result.thresholds[1]
    assert result.lifetimes[2][0] > 2 * result.thresholds[2]
    assert result.lifetimes[1][2] < result.thresholds[1]


def test_the_ideal_head_direction_ring_is_a_circle(session: Recording) -> None:
    result = population_topology(session, "hd", FAST)
    assert result.betti == (1, 1, 0), result.summary()
    assert result.is_ring


def _nothing_stands_out(result: TopologyResult) -> None:
    """No torus, and no loop or void far over the null: activity without co-activity is a shuffle itself,
    so a bar may pass the maximum of a few shuffles by chance (module doc, step 8), never by a torus's
    margin."""
    assert not result.is_torus, result.summary()
    for dim in (1, 2):
        assert result.lifetimes[dim].max(initial=0.0) < 1.5 * result.thresholds[dim], result.summary()


def test_noise_is_not_a_torus(session: Recording) -> None:
    noise = np.random.default_rng(1).random((session.time_s.size, 256)).astype(np.float32)
    _nothing_stands_out(activity_topology(noise, sample_dt_s=session.sample_dt_s, params=FAST, name="noise"))


def test_a_shuffled_grid_module_is_not_a_torus(session: Recording) -> None:
    grid = session.populations["grid_intermediate"]
    offsets = np.random.default_rng(2).integers(0, grid.shape[0], grid.shape[1])
    shuffled = np.stack([np.roll(grid[:, u], o) for u, o in enumerate(offsets)], axis=1)
    result = activity_topology(shuffled, sample_dt_s=session.sample_dt_s, params=FAST, name="shuffled")
    _nothing_stands_out(result)


def test_the_result_reports_its_diagrams_and_parameters(session: Recording, dorsal: TopologyResult) -> None:
    result = dorsal
    for dim in range(3):
        diagram, lifetimes = result.diagrams[dim], result.lifetimes[dim]
        assert diagram.shape == (lifetimes.size, 2)
        assert np.all(np.diff(lifetimes) <= 0)  # longest first
        assert np.all(diagram[:, 0] <= diagram[:, 1])
    assert result.shuffled_longest.shape == (FAST.n_shuffles, 3)
    assert result.thresholds == tuple(result.shuffled_longest.max(axis=0))
    assert 0 < result.n_time_points <= session.time_s.size and result.n_units == 256
    assert result.diagrams[0].shape[0] == FAST.n_points  # one H0 bar per point of the cover
    summary = result.summary()
    assert summary["betti"] == [1, 2, 1] and summary["params"]["n_points"] == FAST.n_points
    # Seeded: the same call gives the same numbers.
    again = population_topology(session, "grid_dorsal", FAST)
    assert again.thresholds == result.thresholds
    np.testing.assert_array_equal(again.lifetimes[1], result.lifetimes[1])


def test_a_silent_population_is_a_clear_error(session: Recording) -> None:
    silent = np.zeros_like(session.populations["grid_ventral"])
    with pytest.raises(TopologyError, match="active, moving time points"):
        activity_topology(silent, sample_dt_s=session.sample_dt_s, speed_m_s=session.speed_m_s, params=FAST)
    with pytest.raises(TopologyError, match="no population 'grid_x'"):
        population_topology(session, "grid_x", FAST)
    # An animal that never moved leaves no moving time point: the same clear error (an IndexError before).
    still = np.zeros_like(session.speed_m_s)
    with pytest.raises(TopologyError, match="0 active, moving time points"):
        activity_topology(
            session.populations["hd"], sample_dt_s=session.sample_dt_s, speed_m_s=still, params=FAST
        )


def test_the_figure_is_written_as_png_and_pdf(session: Recording, tmp_path: Path) -> None:
    result = population_topology(session, "hd", TopologyParams(n_points=80, n_shuffles=1))
    paths = write_topology_figure(result, tmp_path / "hd_topology")
    assert [p.name for p in paths] == ["hd_topology.png", "hd_topology.pdf"]
    assert paths[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert paths[1].read_bytes()[:5] == b"%PDF-"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hd_topology.pdf", "hd_topology.png"]
