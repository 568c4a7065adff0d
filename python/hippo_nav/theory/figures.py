"""The theory figures, to compare with the paper's figures 1–3 (whose image files the paper source lacks).

- fig1_derivation.png — paper Fig. 1: a ventral bump and a three-bump dorsal pattern, the three per-bump
  products, and the posterior (the normalised mixture) against the closed form f(x | μ, σ1²σ2²/(σ1² + σ2²))
  and the paper's product of products before its bump-count rescaling.
- fig2_lesion_expansion.png — paper Fig. 2, with the Fourier-summation hypothesis beside it: the modules, then
  the intact (red), ventral-lost (green) and dorsal-lost (yellow) fields of each hypothesis in one setting.
- fig3_alignment.png — paper Fig. 3: aligned and offset modules (small offset, near the jump, jumped), then
  the field position and its height / rival ratio against the offset.

Figures are drawn on `matplotlib.figure.Figure` objects (Agg canvas), so no global pyplot state is touched.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from hippo_nav.io.atomic import atomic_path
from hippo_nav.theory.alignment import (
    alignment_sweep,
    default_alignment_modules,
    fused_peak,
    paper_alignment_peak,
    tolerated_offset,
)
from hippo_nav.theory.fourier import fourier_place_field
from hippo_nav.theory.fusion import gaussian_product, numerical_product, paper_product_of_products
from hippo_nav.theory.lesions import default_lesion_setting, relative_change, run_lesion_experiment
from hippo_nav.theory.profiles import GridModule, gaussian_pdf

CONDITION_COLOURS = {"red": "#d62728", "green": "#2ca02c", "yellow": "#e6b800"}
CONDITION_LABELS = {"red": "all modules", "green": "ventral lost", "yellow": "dorsal lost"}
DPI = 120


def _save(figure: Figure, path: Path) -> Path:
    with atomic_path(path) as tmp:
        figure.savefig(tmp, dpi=DPI)
    return path


def _label(ax: Axes, letter: str, title: str) -> None:
    ax.set_title(f"{letter}  {title}", loc="left", fontsize=10)


def derivation_figure(path: Path) -> Path:
    """Paper Fig. 1: two profiles, their per-bump products, the posterior."""
    mu, delta, sigma_v, sigma_d = 0.0, 1.0, 0.6, 0.2
    x = np.linspace(-2.5, 2.5, 2001)
    dorsal_centres = [mu - delta, mu, mu + delta]
    figure = Figure(figsize=(7.0, 8.5), layout="constrained")
    axes = figure.subplots(4, 1, sharex=True)

    dorsal = sum(gaussian_pdf(x, c, sigma_d) for c in dorsal_centres)
    axes[0].plot(x, dorsal, color="#1f77b4")
    _label(axes[0], "A", f"dorsal pattern: f(x|μ−δ) + f(x|μ) + f(x|μ+δ),  σ2 = {sigma_d}, δ = {delta}")
    ventral = gaussian_pdf(x, mu, sigma_v)
    axes[1].plot(x, ventral, color="#9467bd")
    _label(axes[1], "B", f"ventral pattern: f(x | μ, σ1²),  σ1 = {sigma_v}")

    mixture = np.zeros_like(x)
    parts = [gaussian_product([mu, c], [sigma_v, sigma_d]) for c in dorsal_centres]
    for name, part in zip(("a", "b", "c"), parts):
        values = part.density(x)
        mixture += values
        axes[2].plot(
            x, values, label=f"p(g1|θ) p(g2{name}|θ): mean {part.mean_m:+.3f}, evidence {part.scale:.3f}"
        )
    axes[2].legend(fontsize=7, loc="upper right")
    _label(axes[2], "C", "per-bump products (the dorsal bumps are alternatives: they are summed next)")

    posterior = mixture / np.trapezoid(mixture, x)
    closed = parts[1]
    # The central product's share of the total evidence is its share of the posterior's area.
    share = closed.scale / sum(p.scale for p in parts)
    paper = paper_product_of_products(mu, sigma_v, dorsal_centres, sigma_d)
    axes[3].plot(x, posterior, color="k", lw=2.0, label="posterior: normalised sum of C (numerical)")
    axes[3].plot(
        x,
        share * gaussian_pdf(x, closed.mean_m, closed.sigma_m),
        "--",
        color="#ff7f0e",
        label=f"closed form f(x | μ, σ1²σ2²/(σ1²+σ2²)) × evidence share {share:.2f},  σ = {closed.sigma_m:.3f}",
    )
    axes[3].plot(
        x,
        gaussian_pdf(x, paper.product_of_products.mean_m, paper.product_of_products.sigma_m),
        ":",
        color="#7f7f7f",
        label=f"paper: product of the 3 products, σ = {paper.product_of_products.sigma_m:.3f} "
        f"(× sqrt(3) → {paper.scaled_sigma_m:.3f})",
    )
    axes[3].legend(fontsize=7, loc="upper right")
    axes[3].set_xlabel("position x (m)")
    _label(axes[3], "D", "posterior p(θ | g12): the place field")
    for ax in axes:
        ax.axvline(mu, color="0.8", lw=0.8, zorder=0)
    return _save(figure, path)


def lesion_figure(path: Path) -> Path:
    """Paper Fig. 2 beside the Fourier prediction: fields after ventral and dorsal loss."""
    setting = default_lesion_setting()
    experiment = run_lesion_experiment(setting)
    x = setting.window_m(8001)
    centre = setting.field_centre_m
    figure = Figure(figsize=(11.0, 7.0), layout="constrained")
    (ax_bm, ax_fm), (ax_bf, ax_ff) = figure.subplots(2, 2, sharex="col")

    for i, module in enumerate(setting.modules()):
        role = (
            " (ventral)" if i == setting.ventral_index else " (dorsal)" if i == setting.dorsal_index else ""
        )
        profile = module.profile(x)
        ax_bm.plot(
            x,
            profile / profile.max() + 1.2 * i,
            label=f"λ = {module.spacing_m} m, σ = {module.bump_sigma_m:.3f} m{role}",
        )
        grating = fourier_place_field(x, [module.spacing_m], centre)
        ax_fm.plot(x, 0.5 * (grating + 1.0) + 1.2 * i, label=f"λ = {module.spacing_m} m{role}")
    _label(ax_bm, "A", "Bayesian: periodic Gaussian grid profiles")
    _label(ax_fm, "B", "Fourier: cosine gratings with a common peak")
    for ax in (ax_bm, ax_fm):
        ax.set_yticks([])
        ax.legend(fontsize=7, loc="upper right")

    bayes = {
        "red": experiment.bayesian_measured.red_m,
        "green": experiment.bayesian_measured.green_m,
        "yellow": experiment.bayesian_measured.yellow_m,
    }
    fourier = {
        "red": experiment.fourier_measured.red_m,
        "green": experiment.fourier_measured.green_m,
        "yellow": experiment.fourier_measured.yellow_m,
    }
    bayes_change = relative_change(experiment.bayesian_measured)
    fourier_change = relative_change(experiment.fourier_measured)
    for name, active in setting.conditions().items():
        posterior = numerical_product(x, setting.modules(active))
        summed = fourier_place_field(x, [setting.spacings_m[i] for i in active], centre)
        change_b = f" ({bayes_change[name]:+.1%})" if name in bayes_change else ""
        change_f = f" ({fourier_change[name]:+.1%})" if name in fourier_change else ""
        ax_bf.plot(
            x,
            posterior / posterior.max(),
            color=CONDITION_COLOURS[name],
            lw=2.0,
            label=f"{CONDITION_LABELS[name]}: σ = {bayes[name] * 100:.2f} cm{change_b}",
        )
        ax_ff.plot(
            x,
            summed / summed.max(),
            color=CONDITION_COLOURS[name],
            lw=2.0,
            label=f"{CONDITION_LABELS[name]}: σ = {fourier[name] * 100:.2f} cm{change_f}",
        )
    _label(ax_bf, "C", "Bayesian fusion: every lesion widens (dorsal strongly, ventral weakly)")
    _label(ax_ff, "D", "Fourier summation: ventral loss NARROWS the field")
    ax_bf.set_xlim(centre - 0.4, centre + 0.4)
    ax_ff.set_xlim(centre - 0.8, centre + 0.8)
    ax_ff.axhline(0.0, color="0.8", lw=0.8, zorder=0)
    for ax, where in ((ax_bf, "upper left"), (ax_ff, "lower center")):
        ax.set_xlabel("position x (m)")
        ax.set_ylabel("field / peak")
        ax.legend(fontsize=8, loc=where)
    return _save(figure, path)


def _alignment_panel(
    ax: Axes, ventral: GridModule, dorsal: GridModule, offset: float, aligned_peak: float
) -> None:
    x = np.linspace(ventral.peak_m - 1.2, ventral.peak_m + 1.2, 4001)
    shifted = dorsal.shifted(-offset)
    v, d = ventral.profile(x), shifted.profile(x)
    posterior = numerical_product(x, (ventral, shifted))
    ax.plot(x, v / v.max(), color="#9467bd", lw=1.0, label="ventral f(x | μ, σ1²)")
    ax.plot(x, d / d.max(), color="#1f77b4", lw=1.0, label="dorsal, peaks at μ − Δ + jλ2")
    ax.fill_between(
        x, posterior / aligned_peak, color="#d62728", alpha=0.35, label="fused field (÷ aligned peak)"
    )
    ax.axvline(ventral.peak_m, color="#9467bd", ls=":", lw=1.0)
    ax.axvline(ventral.peak_m - offset, color="#1f77b4", ls=":", lw=1.0)
    ax.set_ylim(0.0, 1.1)


def alignment_figure(path: Path) -> Path:
    """Paper Fig. 3: aligned and offset grid components and what the fused field does."""
    ventral, dorsal = default_alignment_modules()
    s1, s2, spacing = ventral.bump_sigma_m, dorsal.bump_sigma_m, dorsal.spacing_m
    x = np.linspace(ventral.peak_m - 1.2, ventral.peak_m + 1.2, 4001)
    aligned_peak = float(numerical_product(x, (ventral, dorsal)).max())
    tolerance = tolerated_offset(s1, s2, spacing, max_rival_ratio=0.5)
    cases = [
        ("A", 0.0, "aligned (Δ = 0)"),
        ("B", 0.1, "small offset (Δ = 0.10 m): field follows the dorsal peak"),
        ("C", 0.38, "Δ = 0.38 m ≈ λ2/2: degraded, a rival field grows"),
        ("D", 0.46, "Δ = 0.46 m > λ2/2: the field jumped to the next dorsal cycle"),
    ]
    figure = Figure(figsize=(11.0, 9.5), layout="constrained")
    axes = figure.subplots(3, 2)
    for ax, (letter, offset, title) in zip(axes[:2].ravel(), cases):
        _alignment_panel(ax, ventral, dorsal, offset, aligned_peak)
        _label(ax, letter, title)
        ax.set_xlabel("position x (m)")
    axes[0, 0].legend(fontsize=7, loc="upper left")

    offsets = np.linspace(0.0, 0.8, 161)
    sweep = alignment_sweep(ventral, dorsal, offsets, samples=4001)
    measured = np.array([p.measured_peak_m for p in sweep])
    ax = axes[2, 0]
    ax.plot(offsets, measured, "k.", ms=3, label="numerical peak of the product")
    ax.plot(
        offsets,
        [p.predicted_peak_m for p in sweep],
        color="#d62728",
        lw=1.0,
        label="closed form μ_p (nearest dorsal cycle)",
    )
    ax.plot(
        offsets,
        [paper_alignment_peak(0.0, o, s1, s2) for o in offsets],
        "--",
        color="0.5",
        label="paper's equation (terms swapped): μ_p ≈ μ",
    )
    ax.plot(
        offsets,
        [fused_peak(0.0, s1, -o, s2) for o in offsets],
        ":",
        color="#1f77b4",
        label="same cycle continued: ≈ μ − Δ",
    )
    ax.axvline(spacing / 2.0, color="0.7", lw=0.8)
    ax.set_xlabel("offset Δ (m)")
    ax.set_ylabel("field centre (m)")
    ax.legend(fontsize=7, loc="lower left")
    _label(ax, "E", "where the field sits")

    ax = axes[2, 1]
    ax.plot(offsets, [p.relative_height for p in sweep], color="#d62728", label="field height / aligned")
    ax.plot(offsets, [p.measured_rival_ratio for p in sweep], color="0.3", label="rival / field height")
    ax.plot(
        offsets, [p.predicted_rival_ratio for p in sweep], ":", color="k", label="rival ratio, closed form"
    )
    ax.plot(
        offsets,
        [p.measured_sigma_m / sweep[0].measured_sigma_m for p in sweep],
        "--",
        color="#2ca02c",
        label="field σ / aligned σ",
    )
    ax.axvline(tolerance, color="#ff7f0e", lw=1.0, label=f"tolerated offset (rival = 0.5): {tolerance:.3f} m")
    ax.axvline(spacing / 2.0, color="0.7", lw=0.8, label=f"λ2/2 = {spacing / 2:.2f} m: jump")
    ax.set_xlabel("offset Δ (m)")
    ax.set_ylim(0.0, 1.1)
    ax.legend(fontsize=7, loc="lower left")
    _label(ax, "F", f"degradation (σ1 = {s1} m, σ2 = {s2} m, λ2 = {spacing} m)")
    figure.suptitle(
        f"Alignment: ventral bump at μ = 0, dorsal bumps at μ − Δ + j·{spacing} m "
        f"(σ_p = {math.sqrt(1 / (1 / s1**2 + 1 / s2**2)):.4f} m for every Δ)",
        fontsize=10,
    )
    return _save(figure, path)


def write_all_figures(out_dir: str | Path) -> list[Path]:
    """Write every theory figure as PNG into `out_dir` (created if needed); return the paths written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return [
        derivation_figure(out / "fig1_derivation.png"),
        lesion_figure(out / "fig2_lesion_expansion.png"),
        alignment_figure(out / "fig3_alignment.png"),
    ]
