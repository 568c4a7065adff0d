"""Bird's-eye search speed (`make bench`; skipped by the default test run).

`test_search`: one round = one search as the pipeline runs it (`birdseye._coarse`): a query submap (30 m
around the newest vertex) registered onto the map's structure within 70 m of it, over the 9 headings of the
default `search_rad` and every shift within the default 40 m `search_m`. The street is synthetic (walls along a
grid of streets, posts on the pavements); the query is a stretch of it seen again, 12 m and 0.1 rad from where
the odometry puts it, and the search must find that (checked before timing).

`test_correlation` (group `birdseye_correlation`): the search's transforms alone — the spectra of the 9 rotated
query images and of the target, their correlations and energies — on OpenCV's packed spectra in single
precision (`packed`, what the search uses) against numpy's `rfft2` in double precision (`numpy_double`, what
it used before 2026-12-04), on the same images; the two agree (checked before timing). Compare within the group
for the speed-up.
"""

from __future__ import annotations

import numpy as np
import pytest
from hippo_nav.closure.birdseye import (
    _BLUR_M,
    _COARSE_CELL_M,
    BirdsEyeConfig,
    _blurred_spectra,
    _coarse,
    _correlations,
    _energy,
    _raster,
    structure_weights,
)

SHIFT_M = np.array([9.0, -8.0])
YAW_RAD = 0.1
HEADINGS = 9
SIZE = 288  # the default search's transform size (`_coarse`: 70 m of map, 30 m of query, 40 m of shifts)


def _street(rng: np.random.Generator) -> np.ndarray:
    """(n, 2) structure points of a street grid 160 m across: walls 7 m either side of each street every 40 m,
    posts every 9-15 m along the pavements, all with 0.2 m of stereo scatter."""
    parts = []
    for offset in np.arange(-80.0, 81.0, 40.0):
        for side in (-7.0, 7.0):
            along = rng.uniform(-80.0, 80.0, 600)
            parts.append(np.stack([along, np.full(600, offset + side)], axis=1))
            parts.append(np.stack([np.full(600, offset + side), along[::-1]], axis=1))
            posts = np.cumsum(rng.uniform(9.0, 15.0, 14)) - 80.0
            parts.append(np.repeat(np.stack([posts, np.full(14, offset + side * 0.6)], axis=1), 6, axis=0))
    points = np.concatenate(parts)
    return (points + rng.normal(0.0, 0.2, points.shape)).astype(np.float32)


@pytest.fixture(scope="module")
def search() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(query points, target points, their weights) with the query's true pose in the target's frame."""
    rng = np.random.default_rng(3)
    world = _street(rng)
    target = world[np.hypot(world[:, 0], world[:, 1]) <= 70.0]
    # The query: what stands within 30 m of the true place, in the frame of that place.
    c, s = np.cos(YAW_RAD), np.sin(YAW_RAD)
    rel = world - SHIFT_M
    query = np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], axis=1).astype(
        np.float32
    )
    query = query[np.hypot(query[:, 0], query[:, 1]) <= 30.0]
    query = query + rng.normal(0.0, 0.1, query.shape).astype(np.float32)
    return query, target, structure_weights(query, 30.0), structure_weights(target, 70.0)


def test_search(benchmark, search) -> None:
    query, target, weights_q, weights_t = search
    prior = (np.zeros(3), 40.0, 0.35)

    def run() -> tuple[float, np.ndarray, float]:
        return _coarse(
            query,
            target,
            30.0,
            BirdsEyeConfig(),
            prior,
            target_radius_m=70.0,
            query_weights=weights_q,
            target_weights=weights_t,
        )

    yaw_rad, shift_m, ratio = run()
    assert abs(yaw_rad - YAW_RAD) <= np.radians(5.0) and np.hypot(*(shift_m - SHIFT_M)) <= 1.5, (
        yaw_rad,
        shift_m,
    )
    assert ratio > 1.0
    benchmark(run)


@pytest.mark.parametrize("precision", ["packed", "numpy_double"])
def test_correlation(benchmark, search, precision: str) -> None:
    query, target, weights_q, weights_t = search
    half = int(np.ceil(70.0 / _COARSE_CELL_M))
    angles = np.linspace(-0.35, 0.35, HEADINGS)
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    rotated = np.stack([c * query[:, 0] - s * query[:, 1], s * query[:, 0] + c * query[:, 1]], axis=-1)
    fy, fx = np.fft.fftfreq(SIZE)[:, None], np.fft.rfftfreq(SIZE)[None, :]
    blur = np.exp(-2 * (np.pi * _BLUR_M / _COARSE_CELL_M) ** 2 * (fx**2 + fy**2))
    parseval = np.full(SIZE // 2 + 1, 2.0)
    parseval[[0, -1]] = 1.0

    def packed() -> tuple[np.ndarray, np.ndarray]:
        fq = _blurred_spectra(rotated, weights_q, half, SIZE)
        ft = _blurred_spectra(target[None], weights_t, half, SIZE)
        return _correlations(fq, ft[0]), _energy(fq)

    def numpy_double() -> tuple[np.ndarray, np.ndarray]:
        image_q = np.minimum(_raster(rotated, _COARSE_CELL_M, half, SIZE, HEADINGS, weights_q), 1.0)
        image_t = np.minimum(_raster(target[None], _COARSE_CELL_M, half, SIZE, 1, weights_t), 1.0)
        fq = np.fft.rfft2(image_q.astype(np.float64)) * blur
        ft = np.fft.rfft2(image_t.astype(np.float64)) * blur
        corr = np.fft.irfft2(np.conj(fq) * ft, s=(SIZE, SIZE))
        return corr, (np.abs(fq) ** 2 * parseval).sum(axis=(1, 2)) / SIZE**2

    expected, got = numpy_double(), packed()
    np.testing.assert_allclose(got[0], expected[0], atol=1e-5 * np.abs(expected[0]).max())
    np.testing.assert_allclose(got[1], expected[1], rtol=1e-5)
    benchmark.group = "birdseye_correlation"
    benchmark(packed if precision == "packed" else numpy_double)
