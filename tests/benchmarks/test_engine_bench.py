"""Python-level engine benchmarks (`make bench`; skipped by the default test run).

Compare within one run: the default 10 Hz frame against the camera period (`frame_default`), and the
paper-size network (20×20 × 7×7) stepped by the engine against the same layer's recurrent input done with a
dense weight matrix in numpy (`paper_size_*` group).
"""

from __future__ import annotations

import numpy as np
import pytest
from hippo_nav.engine import N_MODULES, EngineConfig, SpatialMemory


@pytest.fixture(scope="module")
def default_engine() -> SpatialMemory:
    return SpatialMemory()


def test_frame_default(benchmark, default_engine: SpatialMemory):
    benchmark.group = "frame_10hz"
    benchmark(default_engine.step, 0.2, 12.0, 0.1)


def test_readout(benchmark, default_engine: SpatialMemory):
    """The boundary's cost per frame: the readout object (built in Rust) and the fields the pipeline reads."""
    benchmark.group = "readout"

    def read() -> tuple:
        r = default_engine.readout()
        return r.heading_rad, r.place, r.fused, r.place_position_m

    benchmark(read)


def _paper_config() -> EngineConfig:
    grid = [{"n_theta": 20, "n_nu": 7}] * N_MODULES
    return EngineConfig.model_validate({"grid": grid, "place": {"n_theta": 20}})


def test_paper_size_engine_frame(benchmark):
    benchmark.group = "paper_size"
    sm = SpatialMemory(_paper_config())
    benchmark(sm.step, 0.2, 12.0, 0.1)


def test_paper_size_dense_numpy_layer(benchmark):
    """One recurrent-input evaluation of ONE k = 1 grid layer with its dense weight matrix (f32, 1.5 GB)."""
    benchmark.group = "paper_size"
    cfg = _paper_config().grid[0]
    n, m, k, lam = cfg.n_theta, cfg.n_nu, cfg.k, cfg.lambda_
    theta = 2 * np.pi * np.arange(n) / n
    nu = np.linspace(-cfg.nu_max, cfg.nu_max, m)
    ty, tx = np.meshgrid(theta, theta, indexing="ij")
    vy, vx = np.meshgrid(nu, nu, indexing="ij")
    # Unit order: [νy][νx][θy][θx].
    TX = np.broadcast_to(tx, (m, m, n, n)).ravel()
    TY = np.broadcast_to(ty, (m, m, n, n)).ravel()
    VX = np.broadcast_to(vx[:, :, None, None], (m, m, n, n)).ravel()
    VY = np.broadcast_to(vy[:, :, None, None], (m, m, n, n)).ravel()
    units = TX.size
    weights = np.empty((units, units), dtype=np.float32)
    wrap = lambda d: (d + np.pi) % (2 * np.pi) - np.pi
    for start in range(0, units, 2000):
        sl = slice(start, start + 2000)
        dx = wrap(TX[sl, None] - TX[None, :] - VX[None, :])
        dy = wrap(TY[sl, None] - TY[None, :] - VY[None, :])
        dv = np.hypot(VX[sl, None] - VX[None, :], VY[sl, None] - VY[None, :])
        weights[sl] = (cfg.jk / units) * np.cos(k * np.hypot(dx, dy)) * np.cos(lam * dv)
    activity = np.random.default_rng(0).random(units, dtype=np.float32)
    benchmark(weights.dot, activity)
