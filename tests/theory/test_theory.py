"""The paper's 1-D theory (docs/spec.md §6, docs/theory.md): fusion, lesions, Fourier baseline, alignment."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hippo_nav._core import HippoNavError
from hippo_nav.theory import (
    GridModule,
    LesionSetting,
    alignment_sweep,
    bayesian_lesion_widths,
    default_alignment_modules,
    default_lesion_setting,
    field_near,
    fourier_field_sigma,
    fourier_lesion_widths,
    fourier_place_field,
    fused_peak,
    fused_sigma,
    gaussian_pdf,
    gaussian_product,
    measure_peak,
    moments,
    numerical_product,
    paper_alignment_peak,
    paper_product_of_products,
    periodic_gaussian_profile,
    predicted_lesion_order,
    product_of_modules,
    relative_change,
    rival_ratio,
    run_lesion_experiment,
    tolerated_offset,
)

SEED = 20240611


def sorted_sigmas(rng: np.random.Generator, count: int) -> np.ndarray:
    """σ1 > σ2 > … > σN (ventral to dorsal), distinct, spread over two decades."""
    while True:
        sigmas = np.sort(10.0 ** rng.uniform(-2.0, 0.0, size=count))[::-1]
        if np.all(np.diff(sigmas) < 0.0):
            return sigmas


# --- closed form vs numerical fusion -------------------------------------------------------------------


def test_gaussian_product_equals_numerical_product_of_gaussians_to_1e6():
    """Compared: the closed form s·f(x | μ_f, σ_f²) against the product of the NON-periodic densities sampled
    on a fine grid (±14 σ_f, trapezoid): area = s, mean = μ_f, standard deviation = σ_f, each to 1e-6."""
    rng = np.random.default_rng(SEED)
    for _ in range(60):
        count = int(rng.integers(2, 5))
        means = rng.uniform(-1.0, 1.0, size=count)
        sigmas = rng.uniform(0.3, 1.5, size=count)
        closed = gaussian_product(means, sigmas)
        x = np.linspace(closed.mean_m - 14.0 * closed.sigma_m, closed.mean_m + 14.0 * closed.sigma_m, 40001)
        product = np.prod([gaussian_pdf(x, m, s) for m, s in zip(means, sigmas)], axis=0)
        measured = moments(x, product)
        assert measured.area == pytest.approx(closed.scale, rel=1e-6)
        assert abs(measured.mean_m - closed.mean_m) < 1e-6 * closed.sigma_m
        assert measured.sigma_m == pytest.approx(closed.sigma_m, rel=1e-6)
        np.testing.assert_allclose(closed.density(x), product, rtol=0.0, atol=1e-9 * product.max())


def test_two_module_product_is_the_papers_formula():
    s1, s2, mu1, mu2 = 0.8, 0.3, 0.25, -0.1
    closed = gaussian_product([mu1, mu2], [s1, s2])
    assert closed.sigma_m**2 == pytest.approx(s1**2 * s2**2 / (s1**2 + s2**2), rel=1e-12)
    assert closed.mean_m == pytest.approx((mu1 / s1**2 + mu2 / s2**2) * closed.sigma_m**2, rel=1e-12)
    # The evidence of two Gaussians is the density of their difference: f(μ1 | μ2, σ1² + σ2²).
    joint = math.sqrt(s1**2 + s2**2)
    assert closed.scale == pytest.approx(float(gaussian_pdf([mu1], mu2, joint)[0]), rel=1e-12)


def test_mixture_closed_form_equals_numerical_product_of_periodic_profiles():
    """Periodic profiles: the exact closed form is a mixture over bump combinations; it must equal the
    point-by-point product on the whole window, whatever the phases."""
    rng = np.random.default_rng(SEED + 1)
    setting = default_lesion_setting()
    for _ in range(5):
        modules = [
            GridModule(m.spacing_m, m.bump_sigma_m, float(rng.uniform(-0.1, 0.1))) for m in setting.modules()
        ]
        x = np.linspace(-1.6, 1.6, 3001)
        numerical = numerical_product(x, modules)
        closed = product_of_modules(modules, -1.6, 1.6).density(x)
        np.testing.assert_allclose(closed, numerical, rtol=0.0, atol=1e-9 * numerical.max())


def test_periodic_fusion_equals_closed_form_when_rival_fields_vanish():
    """With widths small against the spacings, every rival bump combination has evidence < 1e-12 of the
    best (asserted first), so the moments of the whole numerical product over one ventral period must be
    the closed-form single Gaussian's to 1e-6."""
    ventral, dorsal = GridModule(4.0, 0.12, 0.3), GridModule(1.0, 0.05, 0.33)
    mixture = product_of_modules([ventral, dorsal], -1.7, 2.3)
    best, rival = mixture.strongest(2)
    assert rival.scale / best.scale < 1e-12
    closed = gaussian_product([0.3, 0.33], [0.12, 0.05])
    x = np.linspace(-1.7, 2.3, 40001)
    measured = moments(x, numerical_product(x, [ventral, dorsal]))
    assert measured.area == pytest.approx(closed.scale, rel=1e-6)
    assert abs(measured.mean_m - closed.mean_m) < 1e-6 * closed.sigma_m
    assert measured.sigma_m == pytest.approx(closed.sigma_m, rel=1e-6)
    assert best.mean_m == pytest.approx(closed.mean_m, abs=1e-12)


def test_papers_bump_count_scale_factor():
    """The paper multiplies the n per-bump products (variance σ12²/n) and rescales by n to get σ12². That is
    right only for dorsal bumps symmetric about the ventral peak; summing (the mixture) needs no factor."""
    s1, s2, delta = 0.6, 0.2, 1.0
    sigma_12 = fused_sigma([s1, s2])
    symmetric = paper_product_of_products(0.0, s1, [-delta, 0.0, delta], s2)
    assert symmetric.product_of_products.sigma_m == pytest.approx(sigma_12 / math.sqrt(3.0), rel=1e-12)
    assert symmetric.scaled_sigma_m == pytest.approx(sigma_12, rel=1e-12)
    assert symmetric.product_of_products.mean_m == pytest.approx(0.0, abs=1e-12)

    centres = [-delta, 0.0, delta, 2.0 * delta]
    x = np.linspace(-3.0, 4.0, 14001)
    posterior = gaussian_pdf(x, 0.0, s1) * sum(gaussian_pdf(x, c, s2) for c in centres)
    field = field_near(x, posterior, 0.0)
    paper = paper_product_of_products(0.0, s1, centres, s2)
    assert abs(field.position_m) < 1e-3
    assert field.sigma_m == pytest.approx(sigma_12, rel=1e-3)
    assert (
        abs(paper.product_of_products.mean_m) > 0.2
    )  # the product of products drifts towards the extra bump


# --- lesions: Bayesian ---------------------------------------------------------------------------------


@pytest.mark.parametrize("count", [2, 3, 4, 5, 6])
def test_every_lesion_widens_and_dorsal_loss_widens_most(count):
    rng = np.random.default_rng(SEED + count)
    for _ in range(300):
        sigmas = sorted_sigmas(rng, count)
        widths = bayesian_lesion_widths(sigmas)
        assert widths.ventral_index == 0 and widths.dorsal_index == count - 1
        assert widths.yellow_m > widths.green_m > widths.red_m
        assert widths.red_m < sigmas.min()  # fusion is sharper than its sharpest input
        shuffled = rng.permutation(sigmas)
        again = bayesian_lesion_widths(shuffled)
        assert (again.red_m, again.green_m, again.yellow_m) == pytest.approx(
            (widths.red_m, widths.green_m, widths.yellow_m), rel=1e-12
        )


def test_papers_four_module_formulas():
    s1, s2, s3, s4 = 0.9, 0.5, 0.3, 0.1  # ventral → dorsal
    widths = bayesian_lesion_widths([s1, s2, s3, s4])
    assert widths.red_m == pytest.approx((1 / s1**2 + 1 / s2**2 + 1 / s3**2 + 1 / s4**2) ** -0.5, rel=1e-12)
    assert widths.green_m == pytest.approx((1 / s2**2 + 1 / s3**2 + 1 / s4**2) ** -0.5, rel=1e-12)
    assert widths.yellow_m == pytest.approx((1 / s1**2 + 1 / s2**2 + 1 / s3**2) ** -0.5, rel=1e-12)


def test_predicted_lesion_order_covers_every_subset_and_is_monotone():
    sigmas = [1.16, 5.42, 21.39]  # the paper's table, x axis: modules k = 4, 2, 1
    order = predicted_lesion_order(sigmas)
    assert set(order) == {s for n in (1, 2, 3) for s in itertools.combinations(range(3), n)}
    assert order[(0, 1, 2)] == pytest.approx(1.133, abs=1e-3)  # docs/spec.md §4 check value
    assert order[(1,)] == pytest.approx(5.42, rel=1e-12)
    for small, large in itertools.permutations(order, 2):
        if set(small) < set(large):
            assert order[small] > order[large]
    # Losing the sharpest module widens most: the single lesions, widest first, drop modules 0, 1, 2.
    single = sorted(((order[k], k) for k in order if len(k) == 2), reverse=True)
    assert [k for _, k in single] == [(1, 2), (0, 2), (0, 1)]


def test_lesion_rejects_unusable_inputs():
    with pytest.raises(HippoNavError, match="at least 2 modules"):
        bayesian_lesion_widths([0.3])
    with pytest.raises(HippoNavError, match="equal"):
        bayesian_lesion_widths([0.3, 0.3])
    with pytest.raises(HippoNavError, match="finite and > 0"):
        predicted_lesion_order([0.3, -0.1])
    with pytest.raises(HippoNavError, match="finite and > 0"):
        fused_sigma([0.3, float("nan")])
    with pytest.raises(HippoNavError, match="increase with spacing"):
        LesionSetting(spacings_m=(1.0, 0.5), bump_sigmas_m=(0.05, 0.1))
    with pytest.raises(HippoNavError, match="one per module"):
        LesionSetting(spacings_m=(1.0, 0.5), bump_sigmas_m=(0.1,))


# --- lesions: Bayesian vs Fourier in one setting --------------------------------------------------------


def test_lesion_experiment_bayes_widens_fourier_narrows_after_ventral_loss():
    experiment = run_lesion_experiment(default_lesion_setting())
    measured, predicted = experiment.bayesian_measured, experiment.bayesian_predicted
    for name in ("red_m", "green_m", "yellow_m"):
        assert getattr(measured, name) == pytest.approx(getattr(predicted, name), rel=1e-4)
    assert measured.yellow_m > measured.green_m > measured.red_m
    bayes = relative_change(measured)
    assert 0.0 < bayes["green"] < 0.05  # ventral loss: weak widening
    assert bayes["yellow"] > 0.5  # dorsal loss: strong widening

    for fourier in (experiment.fourier_measured, experiment.fourier_predicted):
        assert fourier.green_m < fourier.red_m < fourier.yellow_m  # ventral loss NARROWS the summed field
    assert relative_change(experiment.fourier_measured)["green"] < -0.05


def test_lesion_predictions_hold_over_random_settings():
    rng = np.random.default_rng(SEED + 99)
    for _ in range(12):
        count, ratio, width_fraction = int(rng.integers(3, 5)), rng.uniform(1.3, 2.0), rng.uniform(0.08, 0.15)
        spacings = tuple(float(ratio**i) for i in reversed(range(count)))
        setting = LesionSetting(spacings, tuple(width_fraction * s for s in spacings))
        experiment = run_lesion_experiment(setting, samples=4001)
        bayes, fourier = experiment.bayesian_measured, experiment.fourier_measured
        assert bayes.yellow_m > bayes.green_m > bayes.red_m
        assert bayes.red_m == pytest.approx(experiment.bayesian_predicted.red_m, rel=1e-3)
        assert fourier.green_m < fourier.red_m < fourier.yellow_m


def test_fourier_curvature_width():
    # One grating: σ_F = λ/(2π). Measured on the sum, the curvature at the peak gives the same σ_F.
    assert fourier_field_sigma([0.5]) == pytest.approx(0.5 / (2 * math.pi), rel=1e-12)
    spacings = [3.2, 1.6, 0.8, 0.4]
    x = np.linspace(-1e-3, 1e-3, 3)
    field = fourier_place_field(x, spacings)
    curvature = (field[0] - 2 * field[1] + field[2]) / (x[1] - x[0]) ** 2
    assert math.sqrt(field[1] / -curvature) == pytest.approx(fourier_field_sigma(spacings), rel=1e-5)
    rng = np.random.default_rng(SEED + 5)
    for _ in range(200):
        widths = fourier_lesion_widths(np.sort(rng.uniform(0.2, 5.0, size=int(rng.integers(2, 6)))))
        assert widths.green_m < widths.red_m < widths.yellow_m


# --- alignment -----------------------------------------------------------------------------------------


def test_field_follows_the_dorsal_peak_not_the_papers_equation():
    s1, s2, delta = 1.0, 0.05, 0.1
    exact = fused_peak(0.0, s1, -delta, s2)
    assert exact == pytest.approx(-delta * s1**2 / (s1**2 + s2**2), rel=1e-12)
    assert abs(exact + delta) < 0.01 * delta  # μ_p ≈ μ − Δ
    paper = paper_alignment_peak(0.0, delta, s1, s2)
    assert abs(paper) < 0.01 * delta  # the paper's swapped terms give μ_p ≈ μ
    ventral, dorsal = GridModule(20.0, s1, 0.0), GridModule(1.0, s2, 0.0)
    (point,) = alignment_sweep(ventral, dorsal, [delta], samples=20001)
    assert point.measured_peak_m == pytest.approx(exact, abs=1e-6)


def test_alignment_sweep_matches_closed_forms():
    ventral, dorsal = default_alignment_modules()
    s1, s2, spacing = ventral.bump_sigma_m, dorsal.bump_sigma_m, dorsal.spacing_m
    joint_var = s1**2 + s2**2
    offsets = np.array([0.0, 0.05, 0.1, 0.2, 0.3, 0.35, 0.39, 0.41, 0.5, 0.7])
    sweep = alignment_sweep(ventral, dorsal, offsets)
    sigma_p = fused_sigma([s1, s2])
    for point in sweep:
        assert point.measured_peak_m == pytest.approx(point.predicted_peak_m, abs=1e-6)
        assert point.measured_sigma_m == pytest.approx(sigma_p, rel=1e-3)  # the offset never changes σ
        assert point.measured_cycle == point.predicted_cycle == (0 if point.offset_m < spacing / 2 else 1)
        assert point.measured_rival_ratio == pytest.approx(point.predicted_rival_ratio, abs=1e-5)
        misfit = min(abs(point.offset_m), abs(point.offset_m - spacing))
        assert point.relative_height == pytest.approx(math.exp(-(misfit**2) / (2 * joint_var)), rel=1e-4)


def test_tolerated_offset():
    ventral, dorsal = default_alignment_modules()
    s1, s2, spacing = ventral.bump_sigma_m, dorsal.bump_sigma_m, dorsal.spacing_m
    for ratio in (0.01, 0.1, 0.5, 0.9):
        limit = tolerated_offset(s1, s2, spacing, ratio)
        assert 0.0 < limit < spacing / 2
        assert rival_ratio(limit, s1, s2, spacing) == pytest.approx(ratio, rel=1e-9)
        (inside, outside) = alignment_sweep(ventral, dorsal, [0.98 * limit, 1.02 * limit], samples=4001)
        assert inside.measured_rival_ratio < ratio < outside.measured_rival_ratio
    # A ventral bump as broad as the dorsal spacing cannot pick one cycle even when aligned.
    assert tolerated_offset(0.8, s2, spacing, 0.5) < 0.0
    assert rival_ratio(0.0, 0.8, s2, spacing) > 0.5
    with pytest.raises(HippoNavError, match="max_rival_ratio"):
        tolerated_offset(s1, s2, spacing, 1.5)


# --- profiles, field measurement and input handling ----------------------------------------------------


def test_periodic_profile_is_a_unit_area_bump_per_period():
    x = np.linspace(0.0, 0.8, 8001)
    profile = periodic_gaussian_profile(x, 0.13, 0.3, 0.8)  # σ comparable to the spacing: images overlap
    assert np.trapezoid(profile, x) == pytest.approx(1.0, rel=1e-7)
    shifted = periodic_gaussian_profile(x + 0.8 * 3, 0.13, 0.3, 0.8)
    np.testing.assert_allclose(shifted, profile, rtol=1e-10)


def test_any_array_layout_is_accepted():
    grid = np.linspace(-1.0, 1.0, 401)
    matrix = np.stack([grid, grid], axis=1)  # column 0 is a strided view
    strided = matrix[:, 0]
    assert not strided.flags.c_contiguous
    np.testing.assert_array_equal(
        periodic_gaussian_profile(strided, 0.0, 0.1, 0.5), periodic_gaussian_profile(grid, 0.0, 0.1, 0.5)
    )
    coarse = grid[::2]
    values = gaussian_pdf(coarse, 0.05, 0.2)
    peak = measure_peak(coarse, values, int(np.argmax(values)))
    assert peak.sigma_m == pytest.approx(0.2, rel=1e-3)
    assert peak.position_m == pytest.approx(0.05, abs=1e-4)


def test_bad_inputs_say_what_to_fix():
    with pytest.raises(HippoNavError, match="1-D array"):
        periodic_gaussian_profile(np.zeros((3, 3)), 0.0, 0.1, 1.0)
    with pytest.raises(HippoNavError, match="NaN"):
        periodic_gaussian_profile([0.0, float("nan")], 0.0, 0.1, 1.0)
    with pytest.raises(HippoNavError, match="spacing_m"):
        GridModule(spacing_m=0.0, bump_sigma_m=0.1)
    with pytest.raises(HippoNavError, match="half height"):
        x = np.linspace(-0.1, 0.1, 101)
        field_near(x, gaussian_pdf(x, 0.0, 1.0), 0.0)
    with pytest.raises(HippoNavError, match="strictly increasing"):
        moments([0.0, 0.0, 1.0], [1.0, 1.0, 1.0])


def test_inputs_too_large_to_compute_are_refused_up_front():
    # Before: 30 modules listed 2^30 subsets (no end), three fine modules built 10^9 bump combinations (all the
    # memory), and a bump 10^299 spacings wide asked numpy for an array beyond any machine.
    from hippo_nav.theory.fusion import product_of_modules
    from hippo_nav.theory.lesions import predicted_lesion_order

    with pytest.raises(HippoNavError, match="2\\^30 subsets"):
        predicted_lesion_order([0.1 * (i + 1) for i in range(30)])
    assert len(predicted_lesion_order([0.1, 0.2, 0.3])) == 7
    fine = [GridModule(0.01, 0.001), GridModule(0.011, 0.001), GridModule(0.013, 0.001)]
    with pytest.raises(HippoNavError, match="bump combinations.*narrow the window"):
        product_of_modules(fine, 0.0, 10.0)
    with pytest.raises(HippoNavError, match="times spacing_m"):
        GridModule(1e-9, 0.1).profile([0.0])
    with pytest.raises(HippoNavError, match="spacing_m must lie between 1e-09 and 1e\\+09 m"):
        GridModule(1e-300, 0.1)


def test_lengths_and_values_beyond_what_a_float_holds_are_refused_not_computed():
    # Before: a fused width of 0 (1/σ² overflowed), ZeroDivisionError, OverflowError or NaN moments.
    from hippo_nav.theory import field_cycle, fourier_field_sigma, fused_sigma, relative_change
    from hippo_nav.theory.lesions import LesionWidths

    for call, words in [
        (lambda: fused_sigma([1e-200, 1e-200]), "sigmas_m must lie between"),
        (lambda: fused_sigma([1e200, 1e200]), "sigmas_m must lie between"),
        (lambda: fourier_field_sigma([1e-200]), "spacings_m must lie between"),
        (lambda: field_cycle(1e300, 0.5), "offset_m must lie within"),
        (lambda: moments([0.0, 1.0, 2.0], [1e308] * 3), "values must be at most"),
        (lambda: moments([1e200, 2e200, 3e200], [1.0, 2.0, 1.0]), "positions_m must lie within"),
        (
            lambda: relative_change(LesionWidths(0.0, 1.0, 1.0, 0, 1)),
            "LesionWidths.red_m must be finite and > 0",
        ),
        (lambda: measure_peak([0.0, 1.0, 2.0], [0.0, 1.0, 0.0], 1.0), "whole sample number"),  # type: ignore[arg-type]
    ]:
        with pytest.raises(HippoNavError, match=words):
            call()
    # At the range's edges the numbers are still right.
    assert fused_sigma([1e-9, 1e-9]) == pytest.approx(1e-9 / math.sqrt(2.0))
    assert fused_sigma([1e9, 1e9]) == pytest.approx(1e9 / math.sqrt(2.0))


def test_a_width_or_centre_given_as_several_numbers_is_refused_not_read_as_its_first():
    # Before: gaussian_pdf([0], 0, [1, 100]) was the density for σ = 1 and fused_peak(0, [1, 9], 1, 1) was 0.5,
    # silently; a text width was a TypeError from math.
    from hippo_nav.theory import fused_peak, tolerated_offset

    with pytest.raises(HippoNavError, match="sigma_m must be one number, got 2 values"):
        gaussian_pdf([0.0], 0.0, [1.0, 100.0])
    with pytest.raises(HippoNavError, match="mean_m must be one number"):
        gaussian_pdf([0.0], [0.0, 5.0], 1.0)
    with pytest.raises(HippoNavError, match="ventral_sigma_m must be one number"):
        fused_peak(0.0, [1.0, 9.0], 1.0, 1.0)
    with pytest.raises(HippoNavError, match="bump_sigma_m must be one number"):
        periodic_gaussian_profile([0.0, 0.1], 0.0, [0.1, 5.0], 1.0)
    with pytest.raises(HippoNavError, match="GridModule.spacing_m must be a number, got the text"):
        GridModule("1", 0.1)  # type: ignore[arg-type]
    with pytest.raises(HippoNavError, match="GridModule.spacing_m must be one number"):
        GridModule(np.array([1.0, 2.0]), 0.1)  # type: ignore[arg-type]
    with pytest.raises(HippoNavError, match="must be a number, got the text"):
        tolerated_offset(0.24, 0.06, 0.8, "0.5")  # type: ignore[arg-type]
    # One number in any numpy form is that number.
    assert GridModule(np.float32(1.0), np.array([0.1])).bump_sigma_m == pytest.approx(0.1)  # type: ignore[arg-type]
    assert gaussian_pdf([0.0], 0.0, np.array([1.0]))[0] == pytest.approx(1.0 / math.sqrt(2.0 * math.pi))
