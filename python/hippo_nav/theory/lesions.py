"""MEC inactivation: place-field widths when grid modules are switched off, Bayesian vs Fourier.

Bayesian fusion (the paper's σ_red, σ_green, σ_yellow, generalised to N ≥ 2 modules with widths σ_m):

    σ_S = (Σ_{m ∈ S} 1/σ_m²)^(−1/2)   for the set S of modules still active;
    red    = all modules,
    green  = ventral lost (the broadest module, largest σ, lowest spatial frequency),
    yellow = dorsal lost  (the sharpest module, smallest σ, highest spatial frequency).

Removing any module removes a positive precision, so every lesion widens the field; removing the sharpest
removes the largest precision, so σ_yellow > σ_green > σ_red whenever the widths differ. (The paper defines
σ1 > … > σ4 from ventral to dorsal and then calls σ1 "the component with highest spatial frequency"; its
formulas are right, its words are swapped: the dorsal, high-frequency module is σ4.)

Fourier summation (fourier.py) in the same setting: σ_F² = Σ w / Σ w k², so losing the ventral grating
NARROWS the field while losing the dorsal one widens it.

`predicted_lesion_order` gives σ_S for every non-empty subset; it is what the 2-D network lesion test compares
its measured place-bump widths against.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hippo_nav._core import HippoNavError
from hippo_nav.theory.fields import field_near
from hippo_nav.theory.fourier import fourier_field_sigma, fourier_place_field
from hippo_nav.theory.fusion import fused_sigma, numerical_product
from hippo_nav.theory.profiles import GridModule, as_positive, as_positive_scalar


@dataclass(frozen=True)
class LesionWidths:
    """Field widths with all modules (red), ventral lost (green), dorsal lost (yellow)."""

    red_m: float
    green_m: float
    yellow_m: float
    ventral_index: int
    dorsal_index: int

    def __post_init__(self) -> None:
        # Each width is a ratio's denominator somewhere (`relative_change`): 0 was a ZeroDivisionError there.
        for name in ("red_m", "green_m", "yellow_m"):
            as_positive_scalar(getattr(self, name), f"LesionWidths.{name}")


def _two_or_more(sigmas_m: ArrayLike, name: str) -> NDArray[np.float64]:
    values = as_positive(sigmas_m, name)
    if values.size < 2:
        raise HippoNavError(f"a lesion needs at least 2 modules (one to lose, one to keep); {name} has 1")
    return values


MAX_LESION_MODULES = 16
"""Modules `predicted_lesion_order` takes at most (2^16 subsets, under a second)."""


def predicted_lesion_order(sigmas_m: ArrayLike) -> dict[tuple[int, ...], float]:
    """Bayesian σ of the place field for every non-empty subset of active modules.

    Keys are the sorted indices (into `sigmas_m`) of the modules that stay ACTIVE; `(0, 1, 2)` is the intact
    system for three modules, `(1, 2)` the one with module 0 switched off. Sorting the dict's items by value
    gives the predicted order of field widths.
    """
    sigmas = as_positive(sigmas_m, "sigmas_m")
    if sigmas.size > MAX_LESION_MODULES:
        raise HippoNavError(
            f"predicted_lesion_order lists every subset of the modules: {sigmas.size} modules are 2^{sigmas.size} "
            f"subsets; give at most {MAX_LESION_MODULES} (the paper has 3)"
        )
    indices = range(sigmas.size)
    return {
        subset: fused_sigma(sigmas[list(subset)])
        for size in range(1, sigmas.size + 1)
        for subset in itertools.combinations(indices, size)
    }


def bayesian_lesion_widths(sigmas_m: ArrayLike) -> LesionWidths:
    """σ_red, σ_green, σ_yellow of Bayesian fusion; ventral = largest σ, dorsal = smallest σ."""
    sigmas = _two_or_more(sigmas_m, "sigmas_m")
    ventral, dorsal = int(np.argmax(sigmas)), int(np.argmin(sigmas))
    if ventral == dorsal:
        raise HippoNavError("all module widths are equal: dorsal and ventral modules are undefined")
    return LesionWidths(
        red_m=fused_sigma(sigmas),
        green_m=fused_sigma(np.delete(sigmas, ventral)),
        yellow_m=fused_sigma(np.delete(sigmas, dorsal)),
        ventral_index=ventral,
        dorsal_index=dorsal,
    )


def fourier_lesion_widths(spacings_m: ArrayLike, weights: ArrayLike | None = None) -> LesionWidths:
    """Curvature widths of the Fourier sum; ventral = longest spacing, dorsal = shortest spacing."""
    spacings = _two_or_more(spacings_m, "spacings_m")
    w = np.ones_like(spacings) if weights is None else as_positive(weights, "weights")
    if w.shape != spacings.shape:
        raise HippoNavError(f"weights {w.shape} must match spacings_m {spacings.shape}")
    ventral, dorsal = int(np.argmax(spacings)), int(np.argmin(spacings))
    if ventral == dorsal:
        raise HippoNavError("all spacings are equal: dorsal and ventral modules are undefined")
    return LesionWidths(
        red_m=fourier_field_sigma(spacings, w),
        green_m=fourier_field_sigma(np.delete(spacings, ventral), np.delete(w, ventral)),
        yellow_m=fourier_field_sigma(np.delete(spacings, dorsal), np.delete(w, dorsal)),
        ventral_index=ventral,
        dorsal_index=dorsal,
    )


@dataclass(frozen=True)
class LesionSetting:
    """Grid modules sharing one field centre, used by both hypotheses.

    Bayesian fusion uses the periodic Gaussian profiles (spacing, bump σ); Fourier summation uses unit-weight
    cosine gratings of the same spacings. Spacings and widths must be ordered alike (larger spacing, broader
    bumps), which is what makes "ventral" and "dorsal" unambiguous.
    """

    spacings_m: tuple[float, ...]
    bump_sigmas_m: tuple[float, ...]
    field_centre_m: float = 0.0

    def __post_init__(self) -> None:
        spacings = _two_or_more(self.spacings_m, "spacings_m")
        sigmas = as_positive(self.bump_sigmas_m, "bump_sigmas_m")
        if sigmas.shape != spacings.shape:
            raise HippoNavError(
                f"{sigmas.size} bump widths for {spacings.size} spacings: give one per module"
            )
        if not np.array_equal(np.argsort(spacings, kind="stable"), np.argsort(sigmas, kind="stable")):
            raise HippoNavError("bump widths must increase with spacing (ventral = broad and widely spaced)")
        if np.unique(spacings).size != spacings.size:
            raise HippoNavError("spacings must be distinct: each module has its own spatial frequency")

    @property
    def ventral_index(self) -> int:
        return int(np.argmax(self.spacings_m))

    @property
    def dorsal_index(self) -> int:
        return int(np.argmin(self.spacings_m))

    def modules(self, active: Sequence[int] | None = None) -> list[GridModule]:
        chosen = range(len(self.spacings_m)) if active is None else active
        return [GridModule(self.spacings_m[i], self.bump_sigmas_m[i], self.field_centre_m) for i in chosen]

    def conditions(self) -> dict[str, list[int]]:
        """Active module indices of the three conditions: red (all), green (no ventral), yellow (no dorsal)."""
        every = list(range(len(self.spacings_m)))
        return {
            "red": every,
            "green": [i for i in every if i != self.ventral_index],
            "yellow": [i for i in every if i != self.dorsal_index],
        }

    def window_m(self, samples: int) -> NDArray[np.float64]:
        """One period of the coarsest module centred on the field, where both fields are single-peaked."""
        half = 0.5 * max(self.spacings_m)
        return np.linspace(self.field_centre_m - half, self.field_centre_m + half, samples)


def default_lesion_setting() -> LesionSetting:
    """Four modules with spacings doubling from dorsal to ventral (8, 4, 2, 1 fields on a 3.2 m track) and
    bump σ = 12 % of the spacing (the grid-field width scales with the spacing)."""
    spacings = (3.2, 1.6, 0.8, 0.4)
    return LesionSetting(spacings_m=spacings, bump_sigmas_m=tuple(0.12 * s for s in spacings))


@dataclass(frozen=True)
class LesionExperiment:
    """Numerically measured and closed-form widths of both hypotheses in one setting."""

    bayesian_measured: LesionWidths
    bayesian_predicted: LesionWidths
    fourier_measured: LesionWidths
    fourier_predicted: LesionWidths


def run_lesion_experiment(setting: LesionSetting, samples: int = 8001) -> LesionExperiment:
    """Build each condition's field on a grid and measure its half-height σ around the common centre."""
    if samples < 101:
        raise HippoNavError(f"samples must be >= 101 to resolve the field, got {samples}")
    x = setting.window_m(samples)
    centre = setting.field_centre_m
    bayes: dict[str, float] = {}
    fourier: dict[str, float] = {}
    for name, active in setting.conditions().items():
        posterior = numerical_product(x, setting.modules(active))
        bayes[name] = field_near(x, posterior, centre).sigma_m
        summed = fourier_place_field(x, [setting.spacings_m[i] for i in active], centre)
        fourier[name] = field_near(x, summed, centre, baseline=0.0).sigma_m
    ventral, dorsal = setting.ventral_index, setting.dorsal_index
    return LesionExperiment(
        bayesian_measured=LesionWidths(bayes["red"], bayes["green"], bayes["yellow"], ventral, dorsal),
        bayesian_predicted=bayesian_lesion_widths(setting.bump_sigmas_m),
        fourier_measured=LesionWidths(fourier["red"], fourier["green"], fourier["yellow"], ventral, dorsal),
        fourier_predicted=fourier_lesion_widths(setting.spacings_m),
    )


def relative_change(widths: LesionWidths) -> dict[str, float]:
    """Width change of each lesion relative to the intact field (+0.1 = 10 % wider)."""
    return {"green": widths.green_m / widths.red_m - 1.0, "yellow": widths.yellow_m / widths.red_m - 1.0}
