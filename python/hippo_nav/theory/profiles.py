"""Periodic Gaussian grid profiles on a 1-D track (the paper's simplification of 2-D grid firing).

A grid module is a periodic firing profile: one Gaussian bump of standard deviation `bump_sigma_m` (metres on
the track) repeated every `spacing_m` metres, with one bump centred on `peak_m`:

    g(x) = Σ_k f(x | peak_m + k·spacing_m, bump_sigma_m²),   f(x | μ, σ²) = exp(−(x − μ)²/(2σ²)) / sqrt(2πσ²)

(a wrapped normal density per period). This is the paper's dorsal pattern "f(x|μ−δ) + f(x|μ) + f(x|μ+δ)"
continued over the whole track: every bump is one alternative estimate of the position, so the profile is a
SUM (mixture) of equally likely Gaussians, not a product. The paper's σ1 > σ2 > … run from ventral (large
spacing, broad bumps, low spatial frequency) to dorsal (small spacing, sharp bumps, high spatial frequency).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hippo_nav._core import HippoNavError

# Images of a bump further than this many σ away contribute < exp(−72) of the peak: below f64 resolution.
_IMAGE_REACH_SIGMAS = 12.0
_MAX_SIGMA_PER_SPACING = 1.0e4  # a profile sums about 24 × this many images at most


def as_positions(positions_m: ArrayLike, name: str = "positions_m") -> NDArray[np.float64]:
    """Validate a 1-D array of finite positions (any numpy layout) and return it as contiguous float64."""
    array = np.asarray(positions_m, dtype=np.float64)
    if array.ndim != 1:
        raise HippoNavError(f"{name} must be a 1-D array of positions in metres, got shape {array.shape}")
    if array.size == 0:
        raise HippoNavError(f"{name} is empty: pass at least one position")
    if not np.all(np.isfinite(array)):
        raise HippoNavError(f"{name} contains NaN or infinite values: pass finite positions in metres")
    return np.ascontiguousarray(array)


def as_positive(values: ArrayLike, name: str) -> NDArray[np.float64]:
    """Validate a 1-D array of finite, strictly positive numbers (widths, spacings, weights)."""
    array = np.atleast_1d(np.asarray(values, dtype=np.float64))
    if array.ndim != 1 or array.size == 0:
        raise HippoNavError(f"{name} must be a non-empty 1-D sequence, got shape {array.shape}")
    if not np.all(np.isfinite(array)) or np.any(array <= 0.0):
        raise HippoNavError(f"{name} must be finite and > 0, got {array.tolist()}")
    return np.ascontiguousarray(array)


def check_finite(value: float, name: str) -> float:
    if not math.isfinite(value):
        raise HippoNavError(f"{name} must be finite, got {value}")
    return float(value)


@dataclass(frozen=True)
class GridModule:
    """One grid module on a 1-D track: bump width σ, field spacing (period) and the centre of one bump."""

    spacing_m: float
    bump_sigma_m: float
    peak_m: float = 0.0

    def __post_init__(self) -> None:
        for name in ("spacing_m", "bump_sigma_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise HippoNavError(f"GridModule.{name} must be finite and > 0, got {value}")
        check_finite(self.peak_m, "GridModule.peak_m")

    def shifted(self, offset_m: float) -> GridModule:
        """The same module with every bump moved by `offset_m` (an alignment offset)."""
        return GridModule(self.spacing_m, self.bump_sigma_m, self.peak_m + check_finite(offset_m, "offset_m"))

    def bump_centres_m(self, lo_m: float, hi_m: float) -> NDArray[np.float64]:
        """Centres of every bump in [lo_m, hi_m] (inclusive), ascending."""
        first = math.ceil((lo_m - self.peak_m) / self.spacing_m)
        last = math.floor((hi_m - self.peak_m) / self.spacing_m)
        return self.peak_m + self.spacing_m * np.arange(first, last + 1, dtype=np.float64)

    def profile(self, positions_m: ArrayLike) -> NDArray[np.float64]:
        """The periodic profile g(x) at `positions_m` (a density per period: each bump has unit area)."""
        return periodic_gaussian_profile(positions_m, self.peak_m, self.bump_sigma_m, self.spacing_m)


def gaussian_pdf(positions_m: ArrayLike, mean_m: float, sigma_m: float) -> NDArray[np.float64]:
    """f(x | μ, σ²), the normal density (non-periodic)."""
    x = as_positions(positions_m)
    sigma = float(as_positive(sigma_m, "sigma_m")[0])
    z = (x - check_finite(mean_m, "mean_m")) / sigma
    return np.exp(-0.5 * z * z) / (math.sqrt(2.0 * math.pi) * sigma)


def periodic_gaussian_profile(
    positions_m: ArrayLike, peak_m: float, bump_sigma_m: float, spacing_m: float
) -> NDArray[np.float64]:
    """Σ_k f(x | peak + k·spacing, σ²): a Gaussian bump repeated every `spacing_m` (wrapped normal density).

    Evaluated exactly to f64 precision: x is reduced to its offset d ∈ [0, spacing) from the nearest bump on
    the left, then every image within 12σ (plus one period) of d is summed.
    """
    x = as_positions(positions_m)
    sigma = float(as_positive(bump_sigma_m, "bump_sigma_m")[0])
    spacing = float(as_positive(spacing_m, "spacing_m")[0])
    offset = np.mod(x - check_finite(peak_m, "peak_m"), spacing)
    if sigma > _MAX_SIGMA_PER_SPACING * spacing:
        # Bumps this much wider than their spacing overlap into a flat line (1/spacing to f64 precision), and
        # summing their images would take more memory than the machine has.
        raise HippoNavError(
            f"bump_sigma_m = {sigma:g} is {sigma / spacing:.3g} times spacing_m = {spacing:g}; a grid profile "
            f"needs σ ≤ {_MAX_SIGMA_PER_SPACING:g} spacings (the paper's modules: about 0.1–0.3)"
        )
    reach = math.ceil(_IMAGE_REACH_SIGMAS * sigma / spacing) + 1
    images = spacing * np.arange(-reach, reach + 1, dtype=np.float64)
    z = (offset[:, None] - images[None, :]) / sigma
    return np.exp(-0.5 * z * z).sum(axis=1) / (math.sqrt(2.0 * math.pi) * sigma)
