"""The paper's 1-D theory: place fields by Bayesian fusion of periodic grid profiles (see docs/theory.md).

- profiles: periodic Gaussian grid profiles (`GridModule`).
- fusion: closed-form Gaussian products, the exact mixture of periodic products, numerical products, and the
  paper's "number of bumps as a scale factor" step.
- lesions: σ_red / σ_green / σ_yellow for N modules, `predicted_lesion_order` for every subset, and the
  lesion experiment for both hypotheses in one setting.
- fourier: the Fourier-summation baseline and its curvature width.
- alignment: offsets between modules — where the field sits, when it degrades, when it jumps cycle.
- figures: the PNG figures matching the paper's figures 1–3 (`hippo-nav figures --out DIR`).
"""

from hippo_nav.theory.alignment import (
    AlignmentPoint,
    alignment_sweep,
    default_alignment_modules,
    field_cycle,
    fused_peak,
    paper_alignment_peak,
    rival_ratio,
    tolerated_offset,
)
from hippo_nav.theory.fields import FieldPeak, field_near, local_maxima, measure_peak
from hippo_nav.theory.fourier import fourier_field_sigma, fourier_place_field
from hippo_nav.theory.fusion import (
    GaussianProduct,
    Moments,
    PaperScaledPosterior,
    PosteriorMixture,
    fused_sigma,
    gaussian_product,
    moments,
    numerical_product,
    paper_product_of_products,
    product_of_modules,
)
from hippo_nav.theory.lesions import (
    LesionExperiment,
    LesionSetting,
    LesionWidths,
    bayesian_lesion_widths,
    default_lesion_setting,
    fourier_lesion_widths,
    predicted_lesion_order,
    relative_change,
    run_lesion_experiment,
)
from hippo_nav.theory.profiles import GridModule, gaussian_pdf, periodic_gaussian_profile

__all__ = [
    "AlignmentPoint",
    "FieldPeak",
    "GaussianProduct",
    "GridModule",
    "LesionExperiment",
    "LesionSetting",
    "LesionWidths",
    "Moments",
    "PaperScaledPosterior",
    "PosteriorMixture",
    "alignment_sweep",
    "bayesian_lesion_widths",
    "default_alignment_modules",
    "default_lesion_setting",
    "field_cycle",
    "field_near",
    "fourier_field_sigma",
    "fourier_lesion_widths",
    "fourier_place_field",
    "fused_peak",
    "fused_sigma",
    "gaussian_pdf",
    "gaussian_product",
    "local_maxima",
    "measure_peak",
    "moments",
    "numerical_product",
    "paper_alignment_peak",
    "paper_product_of_products",
    "periodic_gaussian_profile",
    "predicted_lesion_order",
    "product_of_modules",
    "relative_change",
    "rival_ratio",
    "run_lesion_experiment",
    "tolerated_offset",
]
