"""The Fourier-summation baseline: a place field as a weighted sum of gratings with a common peak.

Solstad et al. (2006) and McNaughton et al. (2006) proposed that a place field is the linear sum of grid
inputs of several spacings λ_m whose peaks coincide at the field centre p. In 1-D, each grid module is a
cosine grating around its mean rate, and the field is

    F(x) = Σ_m w_m cos(2π (x − p) / λ_m).

Its width, measured by the curvature at the peak (the σ of the Gaussian with the same peak and curvature):

    σ_F² = F(p) / (−F''(p)) = Σ_m w_m / Σ_m w_m (2π/λ_m)².

A sum whose curvature is a w-weighted mean of squared wave numbers: removing the LOW-frequency (ventral, long
λ) grating removes a term that adds more to the numerator than to the denominator, so σ_F SHRINKS — the
Fourier prediction of a narrower field after ventral inactivation, which the experiments contradict.
Removing the high-frequency (dorsal) grating widens it. The numerical measure (fields.py) is the half-height
width above the mean rate (0 here), which gives the same ordering.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hippo_nav._core import HippoNavError
from hippo_nav.theory.profiles import as_positions, as_positive, check_finite


def _weights(spacings: NDArray[np.float64], weights: ArrayLike | None) -> NDArray[np.float64]:
    if weights is None:
        return np.ones_like(spacings)
    w = as_positive(weights, "weights")
    if w.shape != spacings.shape:
        raise HippoNavError(f"weights {w.shape} must match spacings_m {spacings.shape}")
    return w


def fourier_place_field(
    positions_m: ArrayLike, spacings_m: ArrayLike, peak_m: float = 0.0, weights: ArrayLike | None = None
) -> NDArray[np.float64]:
    """F(x) = Σ w_m cos(2π(x − peak)/λ_m): Fourier-like summation of gratings with a common peak."""
    x = as_positions(positions_m)
    spacings = as_positive(spacings_m, "spacings_m")
    w = _weights(spacings, weights)
    phase = 2.0 * math.pi * (x[:, None] - check_finite(peak_m, "peak_m")) / spacings[None, :]
    return np.cos(phase) @ w


def fourier_field_sigma(spacings_m: ArrayLike, weights: ArrayLike | None = None) -> float:
    """Curvature width σ_F = sqrt(Σ w / Σ w (2π/λ)²) of the summed field (see the module doc)."""
    spacings = as_positive(spacings_m, "spacings_m")
    w = _weights(spacings, weights)
    wave_numbers = 2.0 * math.pi / spacings
    return float(math.sqrt(float(w.sum()) / float(np.dot(w, wave_numbers**2))))
