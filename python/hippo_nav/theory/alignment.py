"""Alignment of grid components: where the fused field sits when the modules' peaks disagree.

A broad ventral bump f(x | μ, σ1²) and a sharp dorsal profile whose bumps sit at μ − Δ + jλ2 (spacing λ2,
width σ2, alignment offset Δ). Their product is a mixture with one component per dorsal bump j
(fusion.py), all of width σ_p = (1/σ1² + 1/σ2²)^(−1/2), centred at

    μ_p(j) = (μ/σ1² + (μ − Δ + jλ2)/σ2²) / (1/σ1² + 1/σ2²)
           = (μ − Δ + jλ2) + (Δ − jλ2) · σ2²/(σ1² + σ2²),

with evidence ∝ exp(−(Δ − jλ2)² / (2(σ1² + σ2²))). Hence:
- the field sits on the dorsal bump nearest the ventral peak (j = round(Δ/λ2)): the ventral module picks the
  cycle, the dorsal module sets the position (μ_p ≈ μ − Δ when σ1 ≫ σ2) and the width (σ_p ≈ σ2);
  the paper's equation swaps the two numerators and concludes μ_p ≈ μ, contradicting its own text;
- the width does not depend on Δ; the offset only lowers the field's height, by exp(−Δ²/(2(σ1² + σ2²))),
  and raises a rival field on the next dorsal cycle. The rival/field height ratio for 0 ≤ Δ ≤ λ2/2 is

      ρ(Δ) = exp(−λ2 (λ2 − 2Δ) / (2(σ1² + σ2²))),

  so the fusion tolerates offsets up to Δ_max(ρ) = λ2/2 − (σ1² + σ2²) ln(1/ρ) / λ2 before the rival reaches
  ρ of the field, and at Δ = λ2/2 the field jumps to the next cycle (ρ = 1). If Δ_max(ρ) < 0 the ventral bump
  is too broad to pick one cycle even when aligned.
(The ventral module's own further bumps are one ventral spacing away and are neglected in the closed forms;
the numerical sweep includes them.)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hippo_nav._core import HippoNavError
from hippo_nav.theory.fields import local_maxima, measure_peak
from hippo_nav.theory.fusion import numerical_product
from hippo_nav.theory.profiles import GridModule, as_positive_scalar, check_finite


def _positive(value: float, name: str) -> float:
    return as_positive_scalar(value, name)


def fused_peak(
    ventral_peak_m: float, ventral_sigma_m: float, dorsal_peak_m: float, dorsal_sigma_m: float
) -> float:
    """μ_p = (μ1/σ1² + μ2/σ2²)/(1/σ1² + 1/σ2²): the precision-weighted centre of two bumps."""
    p1 = 1.0 / _positive(ventral_sigma_m, "ventral_sigma_m") ** 2
    p2 = 1.0 / _positive(dorsal_sigma_m, "dorsal_sigma_m") ** 2
    mu1, mu2 = check_finite(ventral_peak_m, "ventral_peak_m"), check_finite(dorsal_peak_m, "dorsal_peak_m")
    return (p1 * mu1 + p2 * mu2) / (p1 + p2)


def paper_alignment_peak(
    mu_m: float, offset_m: float, ventral_sigma_m: float, dorsal_sigma_m: float
) -> float:
    """The paper's (wrong) equation μ_p = ((μ − Δ)/σ1² + μ/σ2²)/(1/σ1² + 1/σ2²), kept to document the error."""
    return fused_peak(mu_m - offset_m, ventral_sigma_m, mu_m, dorsal_sigma_m)


def field_cycle(offset_m: float, dorsal_spacing_m: float) -> int:
    """Index j of the dorsal bump (at μ − Δ + jλ2) that holds the field: the one nearest the ventral peak."""
    return int(np.round(check_finite(offset_m, "offset_m") / _positive(dorsal_spacing_m, "dorsal_spacing_m")))


def rival_ratio(
    offset_m: float, ventral_sigma_m: float, dorsal_sigma_m: float, dorsal_spacing_m: float
) -> float:
    """Height of the strongest rival field over the main field's, from the two best-agreeing dorsal bumps."""
    spacing = _positive(dorsal_spacing_m, "dorsal_spacing_m")
    joint_var = (
        _positive(ventral_sigma_m, "ventral_sigma_m") ** 2 + _positive(dorsal_sigma_m, "dorsal_sigma_m") ** 2
    )
    j = field_cycle(offset_m, spacing)
    misfits = np.abs(offset_m - spacing * np.arange(j - 2, j + 3, dtype=np.float64))
    best, second = np.sort(misfits)[:2]
    return math.exp(-(second**2 - best**2) / (2.0 * joint_var))


def tolerated_offset(
    ventral_sigma_m: float, dorsal_sigma_m: float, dorsal_spacing_m: float, max_rival_ratio: float = 0.5
) -> float:
    """Largest |Δ| for which the rival field stays below `max_rival_ratio` of the main field (may be < 0)."""
    ratio = check_finite(max_rival_ratio, "max_rival_ratio")
    if not 0.0 < ratio < 1.0:
        raise HippoNavError(f"max_rival_ratio must lie in (0, 1), got {ratio}")
    spacing = _positive(dorsal_spacing_m, "dorsal_spacing_m")
    joint_var = (
        _positive(ventral_sigma_m, "ventral_sigma_m") ** 2 + _positive(dorsal_sigma_m, "dorsal_sigma_m") ** 2
    )
    return 0.5 * spacing - joint_var * math.log(1.0 / ratio) / spacing


@dataclass(frozen=True)
class AlignmentPoint:
    """Closed-form prediction and numerical measurement of the fused field at one offset Δ."""

    offset_m: float
    predicted_peak_m: float
    measured_peak_m: float
    measured_sigma_m: float
    relative_height: float
    predicted_rival_ratio: float
    measured_rival_ratio: float
    predicted_cycle: int
    measured_cycle: int


def default_alignment_modules() -> tuple[GridModule, GridModule]:
    """A broad ventral bump (σ1 = 0.24 m, one field on a 3.2 m track) and a sharp dorsal grid
    (σ2 = 0.06 m, spacing 0.8 m), both peaking at x = 0."""
    return GridModule(3.2, 0.24, 0.0), GridModule(0.8, 0.06, 0.0)


def alignment_sweep(
    ventral: GridModule, dorsal: GridModule, offsets_m: ArrayLike, samples: int = 8001
) -> list[AlignmentPoint]:
    """Shift the dorsal module by −Δ for each Δ, multiply with the ventral profile and measure the field.

    The window is one ventral period centred on the ventral peak. Heights are relative to the aligned field.
    """
    offsets = np.atleast_1d(np.asarray(offsets_m, dtype=np.float64))
    if offsets.ndim != 1 or not np.all(np.isfinite(offsets)):
        raise HippoNavError("offsets_m must be a 1-D array of finite offsets in metres")
    if samples < 101:
        raise HippoNavError(f"samples must be >= 101 to resolve the field, got {samples}")
    half = 0.5 * ventral.spacing_m
    x = np.linspace(ventral.peak_m - half, ventral.peak_m + half, samples)

    def main_and_rival(offset: float) -> tuple[NDArray[np.float64], int, float]:
        posterior = numerical_product(x, _pair(ventral, dorsal, offset))
        peaks = local_maxima(x, posterior)
        if peaks.size == 0:
            raise HippoNavError("the fused field peaks at the window edge: the ventral bump is too broad")
        rival = float(posterior[peaks[1]] / posterior[peaks[0]]) if peaks.size > 1 else 0.0
        return posterior, int(peaks[0]), rival

    aligned, aligned_index, _ = main_and_rival(0.0)
    aligned_height = measure_peak(x, aligned, aligned_index).height
    points = []
    for offset in offsets.tolist():
        posterior, index, rival = main_and_rival(offset)
        field = measure_peak(x, posterior, index)
        height = field.height
        cycle = field_cycle(offset, dorsal.spacing_m)
        dorsal_peak = dorsal.peak_m - offset + cycle * dorsal.spacing_m
        points.append(
            AlignmentPoint(
                offset_m=offset,
                predicted_peak_m=fused_peak(
                    ventral.peak_m, ventral.bump_sigma_m, dorsal_peak, dorsal.bump_sigma_m
                ),
                measured_peak_m=field.position_m,
                measured_sigma_m=field.sigma_m,
                relative_height=height / aligned_height,
                predicted_rival_ratio=rival_ratio(
                    offset, ventral.bump_sigma_m, dorsal.bump_sigma_m, dorsal.spacing_m
                ),
                measured_rival_ratio=rival,
                predicted_cycle=cycle,
                measured_cycle=int(
                    np.round((field.position_m - (dorsal.peak_m - offset)) / dorsal.spacing_m)
                ),
            )
        )
    return points


def _pair(ventral: GridModule, dorsal: GridModule, offset_m: float) -> Sequence[GridModule]:
    return (ventral, dorsal.shifted(-offset_m))
