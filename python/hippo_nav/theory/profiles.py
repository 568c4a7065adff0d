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
LENGTH_RANGE_M = (1.0e-9, 1.0e9)
"""Widths, spacings and positions a 1-D track's theory takes (a nanometre to a million kilometres): beyond
them a precision 1/σ² overflows or underflows to 0 and the fused width came out 0 or a ZeroDivisionError."""
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
    if np.abs(array).max() > LENGTH_RANGE_M[1]:
        raise HippoNavError(f"{name} must lie within ±{LENGTH_RANGE_M[1]:g} m, got {np.abs(array).max():g}")
    return np.ascontiguousarray(array)


def as_positive(values: ArrayLike, name: str) -> NDArray[np.float64]:
    """Validate a 1-D array of finite, strictly positive numbers (widths, spacings, weights); a length (a name
    ending in `_m`) must also lie in `LENGTH_RANGE_M`."""
    array = np.atleast_1d(np.asarray(values, dtype=np.float64))
    if array.ndim != 1 or array.size == 0:
        raise HippoNavError(f"{name} must be a non-empty 1-D sequence, got shape {array.shape}")
    if not np.all(np.isfinite(array)) or np.any(array <= 0.0):
        raise HippoNavError(f"{name} must be finite and > 0, got {array.tolist()}")
    low, high = LENGTH_RANGE_M
    if name.endswith("_m") and (np.any(array < low) or np.any(array > high)):
        raise HippoNavError(f"{name} must lie between {low:g} and {high:g} m, got {array.tolist()[:5]}")
    return np.ascontiguousarray(array)


def as_positive_scalar(value: ArrayLike, name: str) -> float:
    """One finite, strictly positive number (a width, a spacing): an array of several is refused rather than
    read as its first element."""
    array = _as_number_array(value, name)
    if array.size != 1:
        raise HippoNavError(
            f"{name} must be one number, got {array.size} values {array.ravel().tolist()[:5]}"
        )
    return float(as_positive(array.ravel(), name)[0])


def check_finite(value: float, name: str) -> float:
    array = _as_number_array(value, name)
    if array.size != 1:
        raise HippoNavError(
            f"{name} must be one number, got {array.size} values {array.ravel().tolist()[:5]}"
        )
    number = float(array.ravel()[0])
    if not math.isfinite(number):
        raise HippoNavError(f"{name} must be finite, got {number}")
    if name.endswith("_m") and abs(number) > LENGTH_RANGE_M[1]:
        raise HippoNavError(f"{name} must lie within ±{LENGTH_RANGE_M[1]:g} m, got {number:g}")
    return number


def _as_number_array(value: ArrayLike, name: str) -> NDArray[np.float64]:
    if isinstance(value, (str, bytes)):
        raise HippoNavError(f"{name} must be a number, got the text {value!r}")
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise HippoNavError(f"{name} must be a number, got {type(value).__name__}") from None


@dataclass(frozen=True)
class GridModule:
    """One grid module on a 1-D track: bump width σ, field spacing (period) and the centre of one bump."""

    spacing_m: float
    bump_sigma_m: float
    peak_m: float = 0.0

    def __post_init__(self) -> None:
        # Stored as floats: a one-element array or a numpy scalar is read as its number, several are refused.
        for name in ("spacing_m", "bump_sigma_m"):
            object.__setattr__(self, name, as_positive_scalar(getattr(self, name), f"GridModule.{name}"))
        object.__setattr__(self, "peak_m", check_finite(self.peak_m, "GridModule.peak_m"))

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
    sigma = as_positive_scalar(sigma_m, "sigma_m")
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
    sigma = as_positive_scalar(bump_sigma_m, "bump_sigma_m")
    spacing = as_positive_scalar(spacing_m, "spacing_m")
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
