"""Bayesian (precision-weighted) fusion of grid profiles: closed form and numerical.

Product of Gaussians. For densities f(x | μ_m, σ_m²), m = 1..M,

    Π_m f(x | μ_m, σ_m²) = s · f(x | μ_f, σ_f²),
    1/σ_f² = Σ_m 1/σ_m²,   μ_f = σ_f² Σ_m μ_m/σ_m²,
    s = Π_m (2πσ_m²)^(−1/2) · (2πσ_f²)^(1/2) · exp(−½ Σ_m (μ_m − μ_f)²/σ_m²).

Fused precision is the sum of precisions; the fused centre is the precision-weighted mean; s (the evidence)
says how well the bumps agree. For M = 2 this is the paper's f(x | μ, σ1²σ2²/(σ1² + σ2²)).

Product of periodic profiles. Each module is a sum of bumps (profiles.py), so the product of M modules is a
sum over every choice of one bump per module, each term a Gaussian product as above:

    Π_m g_m(x) = Σ_{(c_1..c_M)} s(c) · f(x | μ_f(c), σ_f²).

Every term has the same σ_f (it depends on the widths only); the term whose bumps agree best has the largest
s and is the place field. This mixture is the exact closed form of the numerical product of the periodic
profiles: `product_of_modules` builds it, `numerical_product` multiplies the profiles on a grid.

The paper's "number of bumps as a scale factor". The paper multiplies the n per-bump products together
(treating the dorsal bumps as n simultaneous observations) instead of summing them (they are alternatives).
n Gaussians of equal variance v multiply to variance v/n; the paper then rescales by n to get back
v = σ1²σ2²/(σ1² + σ2²). `paper_product_of_products` reproduces that step so that the documentation and the
tests can show where it agrees with the mixture (symmetric bumps) and where it does not.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hippo_nav._core import HippoNavError
from hippo_nav.theory.profiles import GridModule, as_positions, as_positive, check_finite

_MIN_RELATIVE_EVIDENCE = 1e-18


@dataclass(frozen=True)
class GaussianProduct:
    """s · f(x | mean_m, sigma_m²): the closed form of a product of Gaussian densities."""

    scale: float
    mean_m: float
    sigma_m: float

    def density(self, positions_m: ArrayLike) -> NDArray[np.float64]:
        x = as_positions(positions_m)
        z = (x - self.mean_m) / self.sigma_m
        return self.scale * np.exp(-0.5 * z * z) / (math.sqrt(2.0 * math.pi) * self.sigma_m)


def fused_sigma(sigmas_m: ArrayLike) -> float:
    """σ_f = (Σ 1/σ_m²)^(−1/2): the width of the fused place field (the paper's σ_red, σ_green, σ_yellow)."""
    sigmas = as_positive(sigmas_m, "sigmas_m")
    return float(1.0 / math.sqrt(float(np.sum(1.0 / sigmas**2))))


def gaussian_product(means_m: ArrayLike, sigmas_m: ArrayLike) -> GaussianProduct:
    """Closed form of Π f(x | μ_m, σ_m²) (see the module doc)."""
    means = np.atleast_1d(np.asarray(means_m, dtype=np.float64))
    sigmas = as_positive(sigmas_m, "sigmas_m")
    if means.shape != sigmas.shape:
        raise HippoNavError(f"means_m {means.shape} and sigmas_m {sigmas.shape} must have the same length")
    if not np.all(np.isfinite(means)):
        raise HippoNavError(f"means_m must be finite, got {means.tolist()}")
    precisions = 1.0 / sigmas**2
    sigma_f = 1.0 / math.sqrt(float(precisions.sum()))
    mean_f = sigma_f**2 * float(np.dot(precisions, means))
    log_scale = (
        -0.5 * float(np.sum(np.log(2.0 * math.pi * sigmas**2)))
        + 0.5 * math.log(2.0 * math.pi * sigma_f**2)
        - 0.5 * float(np.dot(precisions, (means - mean_f) ** 2))
    )
    return GaussianProduct(scale=math.exp(log_scale), mean_m=mean_f, sigma_m=sigma_f)


@dataclass(frozen=True)
class PosteriorMixture:
    """Σ_j scales[j] · f(x | means_m[j], sigma_m²): the exact product of periodic profiles, as components."""

    scales: NDArray[np.float64]
    means_m: NDArray[np.float64]
    sigma_m: float

    def density(self, positions_m: ArrayLike) -> NDArray[np.float64]:
        """The (unnormalised) product Π g_m(x), evaluated from the components."""
        x = as_positions(positions_m)
        z = (x[:, None] - self.means_m[None, :]) / self.sigma_m
        gauss = np.exp(-0.5 * z * z) / (math.sqrt(2.0 * math.pi) * self.sigma_m)
        return gauss @ self.scales

    def strongest(self, count: int = 1) -> list[GaussianProduct]:
        """The `count` components with the largest evidence s, strongest first (the place field first)."""
        order = np.argsort(-self.scales, kind="stable")[: max(count, 0)]
        return [GaussianProduct(float(self.scales[j]), float(self.means_m[j]), self.sigma_m) for j in order]


MAX_COMBINATIONS = 2_000_000
"""Bump combinations `product_of_modules` enumerates at most (about 50 MB for three modules)."""


def product_of_modules(modules: Sequence[GridModule], lo_m: float, hi_m: float) -> PosteriorMixture:
    """Closed form of Π_m g_m(x) for x in [lo_m, hi_m], as the mixture of all bump combinations.

    Bumps are enumerated within 12σ_m plus one spacing outside the window, so that on the window the mixture
    equals the product of the periodic profiles to f64 precision. Components whose evidence is below
    `_MIN_RELATIVE_EVIDENCE` of the strongest are dropped: all of them together change the product by less
    than (their count) × 1e-18 of its maximum, which is at least the strongest component's peak.
    """
    modules = list(modules)
    if len(modules) == 0:
        raise HippoNavError("product_of_modules needs at least one grid module")
    strangers = [type(m).__name__ for m in modules if not isinstance(m, GridModule)]
    if strangers:
        raise HippoNavError(
            f"product_of_modules takes GridModule(spacing_m, bump_sigma_m) items, got {strangers}"
        )
    lo_m, hi_m = check_finite(lo_m, "lo_m"), check_finite(hi_m, "hi_m")
    if not hi_m > lo_m:
        raise HippoNavError(f"window must have hi_m > lo_m, got [{lo_m}, {hi_m}]")
    sigmas = np.array([m.bump_sigma_m for m in modules])
    precisions = 1.0 / sigmas**2
    sigma_f = 1.0 / math.sqrt(float(precisions.sum()))
    centres = []
    for module in modules:
        margin = 12.0 * module.bump_sigma_m + module.spacing_m
        span = (hi_m - lo_m + 2.0 * margin) / module.spacing_m
        if span > MAX_COMBINATIONS:
            raise HippoNavError(
                f"a module of spacing {module.spacing_m:g} m has about {span:.3g} bumps in the window "
                f"[{lo_m:g}, {hi_m:g}] m; narrow the window or widen the spacing"
            )
        centres.append(module.bump_centres_m(lo_m - margin, hi_m + margin))
    count = math.prod(len(c) for c in centres)
    if count > MAX_COMBINATIONS:
        raise HippoNavError(
            f"the product of these modules over [{lo_m:g}, {hi_m:g}] m has {count:.3g} bump combinations, "
            f"more than {MAX_COMBINATIONS:g}; narrow the window (a few periods of the widest module)"
        )
    combos = np.array(list(itertools.product(*centres)), dtype=np.float64)  # (combinations, modules)
    means_f = sigma_f**2 * (combos @ precisions)
    log_scales = (
        -0.5 * float(np.sum(np.log(2.0 * math.pi * sigmas**2)))
        + 0.5 * math.log(2.0 * math.pi * sigma_f**2)
        - 0.5 * (((combos - means_f[:, None]) ** 2) @ precisions)
    )
    keep = log_scales >= log_scales.max() + math.log(_MIN_RELATIVE_EVIDENCE)
    return PosteriorMixture(scales=np.exp(log_scales[keep]), means_m=means_f[keep], sigma_m=sigma_f)


def numerical_product(positions_m: ArrayLike, modules: Sequence[GridModule]) -> NDArray[np.float64]:
    """Π_m g_m(x): the periodic profiles multiplied point by point (the numerical Bayesian fusion)."""
    if len(modules) == 0:
        raise HippoNavError("numerical_product needs at least one grid module")
    x = as_positions(positions_m)
    product = np.ones_like(x)
    for module in modules:
        product *= module.profile(x)
    return product


@dataclass(frozen=True)
class Moments:
    """Area, mean and standard deviation of a sampled non-negative function (trapezoid rule)."""

    area: float
    mean_m: float
    sigma_m: float


_MAX_VALUE = 1.0e100  # a density or rate this large leaves no room for its moments' products


def moments(positions_m: ArrayLike, values: ArrayLike) -> Moments:
    """Zeroth, first and second central moments of `values` sampled at increasing `positions_m`."""
    x = as_positions(positions_m)
    y = np.asarray(values, dtype=np.float64)
    if y.shape != x.shape:
        raise HippoNavError(f"values {y.shape} must match positions_m {x.shape}")
    if not np.all(np.isfinite(y)) or np.any(y < 0.0):
        raise HippoNavError("values must be finite and non-negative (a density or firing rate)")
    if np.any(np.diff(x) <= 0.0):
        raise HippoNavError("positions_m must be strictly increasing")
    if y.max() > _MAX_VALUE:
        raise HippoNavError(
            f"values must be at most {_MAX_VALUE:g} (their integral overflows), got {y.max():g}"
        )
    area = float(np.trapezoid(y, x))
    if not area > 0.0:
        raise HippoNavError("values integrate to zero: the sampled window misses the field")
    mean = float(np.trapezoid(x * y, x)) / area
    variance = float(np.trapezoid((x - mean) ** 2 * y, x)) / area
    return Moments(area=area, mean_m=mean, sigma_m=math.sqrt(variance))


@dataclass(frozen=True)
class PaperScaledPosterior:
    """The paper's two-module derivation: products per dorsal bump, multiplied, then rescaled by n."""

    component_products: list[GaussianProduct]
    product_of_products: GaussianProduct
    bump_count: int

    @property
    def scaled_sigma_m(self) -> float:
        """σ after the paper's "number of bumps as a scale factor": sqrt(n) × σ of the product of products."""
        return math.sqrt(self.bump_count) * self.product_of_products.sigma_m


def paper_product_of_products(
    ventral_mean_m: float, ventral_sigma_m: float, dorsal_centres_m: ArrayLike, dorsal_sigma_m: float
) -> PaperScaledPosterior:
    """The paper's p(θ | g12) = Π_j p(g1|θ) p(g2j|θ), with its bump-count rescaling (see module doc)."""
    centres = np.atleast_1d(np.asarray(dorsal_centres_m, dtype=np.float64))
    if centres.ndim != 1 or centres.size == 0 or not np.all(np.isfinite(centres)):
        raise HippoNavError("dorsal_centres_m must be a non-empty 1-D array of finite bump centres")
    parts = [gaussian_product([ventral_mean_m, float(c)], [ventral_sigma_m, dorsal_sigma_m]) for c in centres]
    # Evidence of the product of products is irrelevant to the paper's argument (it normalises); keep s = 1.
    combined = gaussian_product([p.mean_m for p in parts], [p.sigma_m for p in parts])
    return PaperScaledPosterior(
        component_products=parts,
        product_of_products=GaussianProduct(1.0, combined.mean_m, combined.sigma_m),
        bump_count=int(centres.size),
    )
