"""Measuring a sampled 1-D place field: its peaks and its width.

Width convention: the Gaussian-equivalent σ from the full width at half height,
σ = FWHM / (2·sqrt(2 ln 2)), where "height" is measured above a baseline (0 for a posterior density, the
mean rate for a Fourier sum whose gratings swing around their mean). For a Gaussian field this is exactly
its σ, so numerical widths are directly comparable with the closed-form σ_f of the Bayesian fusion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hippo_nav._core import HippoNavError
from hippo_nav.theory.profiles import as_positions, check_finite

FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


@dataclass(frozen=True)
class FieldPeak:
    """One local maximum of a sampled field: position (parabola-refined), height, half-height σ."""

    position_m: float
    height: float
    sigma_m: float


def _validated(positions_m: ArrayLike, values: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    x = as_positions(positions_m)
    y = np.asarray(values, dtype=np.float64)
    if y.shape != x.shape:
        raise HippoNavError(f"values {y.shape} must match positions_m {x.shape}")
    if not np.all(np.isfinite(y)):
        raise HippoNavError("values contain NaN or infinite entries")
    if x.size < 3 or np.any(np.diff(x) <= 0.0):
        raise HippoNavError("positions_m must be strictly increasing with at least 3 samples")
    return x, y


def local_maxima(positions_m: ArrayLike, values: ArrayLike) -> NDArray[np.int64]:
    """Indices of strict interior local maxima (plateaus count once, at their left end), tallest first."""
    _, y = _validated(positions_m, values)
    inner = np.flatnonzero((y[1:-1] >= y[:-2]) & (y[1:-1] > y[2:])) + 1
    return inner[np.argsort(-y[inner], kind="stable")]


def _crossing(x: NDArray[np.float64], y: NDArray[np.float64], start: int, step: int, level: float) -> float:
    i = start
    while 0 <= i + step < y.size:
        j = i + step
        if y[j] < level:
            # Linear interpolation between the last sample above and the first below the level.
            return float(x[i] + (x[j] - x[i]) * (y[i] - level) / (y[i] - y[j]))
        i = j
    raise HippoNavError(
        "the field does not fall to half height inside the sampled window: widen the window or raise the "
        "sampling range around the peak"
    )


def measure_peak(positions_m: ArrayLike, values: ArrayLike, index: int, baseline: float = 0.0) -> FieldPeak:
    """Position, height and half-height σ of the local maximum at sample `index`."""
    x, y = _validated(positions_m, values)
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
        raise HippoNavError(f"peak index must be a whole sample number, got {index!r}")
    if not 0 < index < x.size - 1:
        raise HippoNavError(f"peak index {index} must be an interior sample (1..{x.size - 2})")
    baseline = check_finite(baseline, "baseline")
    if not y[index] > baseline:
        raise HippoNavError(f"the peak ({y[index]}) is not above the baseline ({baseline})")
    # Parabola through the three samples around the maximum: sub-sample peak position and height.
    y0, y1, y2 = y[index - 1], y[index], y[index + 1]
    curvature = y0 - 2.0 * y1 + y2
    shift = 0.5 * (y0 - y2) / curvature if curvature < 0.0 else 0.0
    spacing = 0.5 * (x[index + 1] - x[index - 1])
    position = float(x[index] + shift * spacing)
    height = float(y1 - 0.25 * (y0 - y2) * shift)
    level = baseline + 0.5 * (height - baseline)
    left = _crossing(x, y, index, -1, level)
    right = _crossing(x, y, index, +1, level)
    return FieldPeak(position_m=position, height=height, sigma_m=(right - left) / FWHM_PER_SIGMA)


def field_near(positions_m: ArrayLike, values: ArrayLike, near_m: float, baseline: float = 0.0) -> FieldPeak:
    """The place field whose peak is closest to `near_m` (ties: the taller), measured by `measure_peak`."""
    x, y = _validated(positions_m, values)
    peaks = local_maxima(x, y)
    if peaks.size == 0:
        raise HippoNavError("no local maximum inside the sampled window: the field peaks at its edge")
    distance = np.abs(x[peaks] - check_finite(near_m, "near_m"))
    best = peaks[np.lexsort((-y[peaks], distance))[0]]
    return measure_peak(x, y, int(best), baseline)
