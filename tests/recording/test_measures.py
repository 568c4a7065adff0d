"""The lab's measures on the ideal recording (tests/recording/conftest.py), whose answers are known: each
module's lattice is square with spacing P/k, so the 90° score passes and the 60° score does not; a unit
shuffled in time fails; HD units prefer their designed heading. Also: the 60° score equals opexebo's own,
the rate map is the activity-weighted occupancy, bad input is refused, the numbers are deterministic per
seed, and the figures are written."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
import warnings

import numpy as np
import pytest

pytest.importorskip("opexebo")

from hippo_nav._core import HippoNavError
from hippo_nav.recording import GRID_POPULATIONS, Recording
from hippo_nav.recording.figures import _score_panel, write_measure_figures
from hippo_nav.recording.measures import (
    RecordingMeasures,
    autocorrelogram,
    firing_fields,
    grid_scores,
    measure_recording,
    passes_shuffle_test,
    rate_maps,
    square_lattice,
)


@pytest.fixture(scope="module")
def measures(ideal_recording: Recording) -> RecordingMeasures:
    # 5 units and 12 shuffles each (60 pooled shuffles a population): the fewest that keep the thresholds
    # meaningful, so the file stays fast.
    return measure_recording(ideal_recording, units_per_population=5, shuffles=12, seed=0)


def _with_population(rec: Recording, name: str, activity: np.ndarray) -> Recording:
    return dataclasses.replace(rec, populations={**rec.populations, name: activity})


# --------------------------------------------------------------------------------------------- grid modules


def test_each_module_spacing_is_its_design_p_over_k(measures, ideal_recording):
    period_m = ideal_recording.torus_period_m
    for name, k in zip(GRID_POPULATIONS, ideal_recording.module_k):
        population = measures.spatial[name]
        assert population.design_spacing_m == pytest.approx(period_m / k)
        assert population.spacing_mean_m == pytest.approx(period_m / k, rel=0.05), name
        for unit in population.units:
            # The coarsest module shows only 1.5 periods in the box: a field cut by a wall biases one unit.
            assert abs(unit.spacing_over_design - 1.0) < 0.075, (name, unit)
    # Design 1 : ½ : ¼ between modules.
    for name, ratio in measures.module_spacing_ratios.items():
        assert ratio == pytest.approx(measures.design_spacing_ratios[name], rel=0.05), name
    assert measures.design_spacing_ratios == {
        "grid_ventral": 1.0,
        "grid_intermediate": 0.5,
        "grid_dorsal": 0.25,
    }


def test_square_lattice_axes_are_the_arena_axes(measures):
    # The ideal lattice's axes are x and y: orientation 0 modulo 90°.
    for name in GRID_POPULATIONS:
        population = measures.spatial[name]
        assert abs(population.orientation_mean_deg) < 3.0, name
        assert population.orientation_std_deg < 3.0, name


def test_square_score_passes_and_hexagonal_score_does_not(measures):
    for name in GRID_POPULATIONS:
        population = measures.spatial[name]
        assert population.units_measured == 5
        assert len(population.shuffled_90) == 5 * 12
        assert population.fraction_passing_90 >= 0.9, name
        assert population.fraction_passing_60 <= 0.1, name
        for unit in population.units:
            assert unit.grid_score_90 > 0.8, (name, unit)
            assert unit.grid_score_60 < 0.2, (name, unit)
        # A circular shift destroys the lattice: the shuffles' threshold sits well below the units' scores.
        assert population.threshold_90 < min(u.grid_score_90 for u in population.units)


def test_a_unit_shuffled_in_time_fails(ideal_recording):
    rng = np.random.default_rng(11)
    activity = ideal_recording.populations["grid_intermediate"].copy()
    scrambled = (3, 10)
    for unit in scrambled:
        activity[:, unit] = rng.permutation(activity[:, unit])
    rec = _with_population(ideal_recording, "grid_intermediate", activity)
    result = measure_recording(rec, populations=["grid_intermediate"], units_per_population="all", shuffles=5)
    units = {u.unit: u for u in result.spatial["grid_intermediate"].units}
    assert len(units) == 16 and set(result.spatial) == {"grid_intermediate"} and result.head_direction is None
    for unit in scrambled:
        assert not units[unit].passes_90 and not units[unit].passes_60
        assert math.isnan(units[unit].spacing_m) or abs(units[unit].spacing_over_design - 1) > 0.05
    intact = [u for i, u in units.items() if i not in scrambled]
    assert all(u.passes_90 for u in intact)
    # Permuting a unit's samples leaves its activity but not its place: information collapses.
    assert units[3].information_bits_per_spike < 0.2 * min(u.information_bits_per_spike for u in intact)


def test_information_and_fields_follow_the_lattice(measures):
    ventral, intermediate, dorsal = (measures.spatial[name] for name in GRID_POPULATIONS)
    # Finer lattices have more, smaller fields and carry less information per spike.
    assert ventral.field_count_mean < intermediate.field_count_mean < dorsal.field_count_mean
    assert ventral.field_area_mean_m2 > intermediate.field_area_mean_m2 > dorsal.field_area_mean_m2
    assert ventral.information_mean_bits_per_spike > intermediate.information_mean_bits_per_spike
    assert intermediate.information_mean_bits_per_spike > dorsal.information_mean_bits_per_spike > 0.3
    # The dorsal lattice has (1.5 m / 0.25 m)² = 36 fields in the box, some cut below 9 bins by the walls.
    assert 20 <= dorsal.field_count_mean <= 36


# --------------------------------------------------------------------------------------------- head direction


def test_a_field_never_floods_bins_never_visited_or_silent():
    """A 1-second session visits a few bins: opexebo grew the field around its one peak over the whole
    arena (one field of 4 m² in a 2 m box). A field holds the visited, active bins connected to its peak."""
    sparse = np.full((80, 80), np.nan)
    sparse[40, 30:37] = [0.2, 0.5, 0.8, 1.0, 0.8, 0.5, 0.2]
    assert firing_fields(sparse, 0.025) == (0, pytest.approx(math.nan, nan_ok=True))
    assert firing_fields(np.nan_to_num(sparse), 0.025)[0] == 0
    # A real field beside silent bins keeps exactly its active bins.
    blob = np.zeros((80, 80))
    yy, xx = np.mgrid[0:80, 0:80]
    blob[np.hypot(yy - 40, xx - 40) <= 5] = 1.0
    count, area_m2 = firing_fields(blob, 0.025)
    assert count == 1 and area_m2 == pytest.approx(int((blob > 0).sum()) * 0.025**2)


def test_a_score_panel_of_no_finite_scores_draws_without_numpy_warnings():
    """A 1-second session's maps have no grid score: the histogram of nothing divided by zero, and numpy's
    warning reached the user's terminal on every short `record`."""
    import matplotlib.pyplot as plt

    figure, ax = plt.subplots()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _score_panel(ax, np.full(4, np.nan), np.full(3, np.nan), math.nan)
    plt.close(figure)


def test_a_negative_grid_score_never_passes_however_low_the_threshold():
    assert not passes_shuffle_test(-0.16, -0.1597)
    assert passes_shuffle_test(0.4, 0.3) and not passes_shuffle_test(0.2, 0.3)


def test_hd_units_prefer_their_designed_heading(measures):
    hd = measures.head_direction
    assert hd is not None and hd.units_measured == 5
    for unit in hd.units:
        assert abs(unit.direction_error_deg) < 3.0, unit
        # von Mises κ = 4: R = I1(4)/I0(4) = 0.86, less a little for the 6° bins and the smoothing.
        assert 0.8 < unit.mean_vector_length < 0.87, unit
        assert unit.passes
    assert hd.threshold_mean_vector_length < 0.2
    assert hd.fraction_passing == 1.0


# --------------------------------------------------------------------------------------------- the parts


def test_sixty_degree_score_is_opexebos(ideal_recording, monkeypatch):
    """Our port equals opexebo's grid_score given its central radius, and stays close with ours; opexebo
    0.7.2 needs one fix to run under NumPy ≥ 2.3 (its central radius is a one-element array)."""
    module = sys.modules["opexebo.analysis.grid_score"]
    original = module._findCentreRadius
    radii: list[float] = []

    def scalar_radius(acorr, **kwargs):
        radii.append(float(np.ravel(original(acorr, **kwargs))[0]))
        return radii[-1]

    monkeypatch.setattr(module, "_findCentreRadius", scalar_radius)
    import opexebo

    square = rate_maps(ideal_recording, "grid_dorsal", [5]).maps[0]
    n = 60
    x, y = np.meshgrid(np.arange(n), np.arange(n))
    angles = 0.2 + np.arange(3) * np.pi / 3
    hexagonal = np.exp(sum(np.cos(2 * np.pi / 10.4 * (np.cos(a) * x + np.sin(a) * y)) for a in angles))
    for rate_map, hexagonal_lattice in ((square, False), (hexagonal, True)):
        acorr = autocorrelogram(rate_map)
        with warnings.catch_warnings():
            # opexebo's grid statistics average an empty array on these maps (their peak search finds no
            # peak in a map without zeros); the score itself is unaffected.
            warnings.simplefilter("ignore", RuntimeWarning)
            reference, _ = opexebo.analysis.grid_score(acorr)
        port = grid_scores(acorr, central_radius_bins=int(radii[-1]))
        assert port.score_60 == pytest.approx(reference, abs=1e-9)
        assert grid_scores(acorr).score_60 == pytest.approx(reference, abs=0.1)
        # The 90° score tells the lattices apart the other way round.
        if hexagonal_lattice:
            assert reference > 1.0 and port.score_90 < 0.5
        else:
            assert reference < 0.2 and port.score_90 > 1.0


def test_rate_map_is_activity_weighted_occupancy(ideal_recording):
    # A unit whose activity is its x position: without smoothing, each bin holds the mean x of its samples.
    half = ideal_recording.position_m[:, 0] < 0.75
    rec = dataclasses.replace(
        ideal_recording,
        time_s=ideal_recording.time_s[: half.sum()],
        position_m=ideal_recording.position_m[half],
        heading_rad=ideal_recording.heading_rad[half],
        populations={"place": ideal_recording.position_m[half, :1].astype(np.float32)},
    )
    maps = rate_maps(rec, "place", sigma_bins=0.0, bin_size_m=0.05)
    assert maps.binning.shape == (30, 30) and maps.binning.extent_m == (0.0, 1.5, 0.0, 1.5)
    centres_x = (np.arange(30) + 0.5) * 0.05
    visited = np.isfinite(maps.maps[0])
    assert np.all(np.abs(maps.maps[0] - centres_x[None, :])[visited] <= 0.025 + 1e-6)
    assert not visited[:, 16:].any(), "bins the walk never entered must be NaN"
    assert maps.occupancy_s.sum() == pytest.approx(half.sum() * ideal_recording.sample_dt_s)
    # Smoothing the activity and the occupancy before dividing keeps a constant map constant, even beside
    # unvisited bins (smoothing a map with zeros there would pull its edge down).
    flat = dataclasses.replace(rec, populations={"place": np.full((half.sum(), 1), 0.5, dtype=np.float32)})
    smoothed = rate_maps(flat, "place", sigma_bins=2.0, bin_size_m=0.05).maps[0]
    assert np.array_equal(np.isfinite(smoothed), visited)
    assert np.allclose(smoothed[visited], 0.5, rtol=1e-9)


def test_square_lattice_reads_a_rotated_lattice():
    n = 60
    y, x = np.mgrid[0:n, 0:n].astype(np.float64)
    angle = np.radians(20.0)
    u, v = np.cos(angle) * x + np.sin(angle) * y, -np.sin(angle) * x + np.cos(angle) * y
    rate_map = np.exp(2 * (np.cos(2 * np.pi * u / 12) - 1)) * np.exp(2 * (np.cos(2 * np.pi * v / 12) - 1))
    lattice = square_lattice(autocorrelogram(rate_map), bin_size_m=0.025)
    assert lattice.spacing_m == pytest.approx(12 * 0.025, rel=0.02)
    assert lattice.orientation_deg == pytest.approx(20.0, abs=1.5)


def test_bad_input_is_refused_with_what_to_fix(ideal_recording):
    with pytest.raises(HippoNavError, match="no measures for population 'grid_extra'"):
        measure_recording(ideal_recording, populations=["grid_extra"])
    without_place = dataclasses.replace(
        ideal_recording, populations={k: v for k, v in ideal_recording.populations.items() if k != "place"}
    )
    with pytest.raises(HippoNavError, match="no population 'place' in this recording"):
        measure_recording(without_place, populations=["place"])
    position = ideal_recording.position_m.copy()
    position[100] = np.nan
    with pytest.raises(HippoNavError, match="1 samples with NaN.*drop or interpolate"):
        measure_recording(dataclasses.replace(ideal_recording, position_m=position))
    with pytest.raises(HippoNavError, match=r"position_m has shape \(12000, 3\)"):
        measure_recording(dataclasses.replace(ideal_recording, position_m=np.zeros((12000, 3))))
    short = ideal_recording.populations["hd"][:-1]
    with pytest.raises(HippoNavError, match=r"population 'hd' has shape \(11999, 36\)"):
        measure_recording(_with_population(ideal_recording, "hd", short))
    with pytest.raises(HippoNavError, match="units_per_population"):
        measure_recording(ideal_recording, units_per_population=0)


def test_deterministic_per_seed_and_any_array_layout(ideal_recording):
    def run(rec: Recording, seed: int) -> str:
        result = measure_recording(
            rec, populations=["place", "hd"], units_per_population=2, shuffles=3, seed=seed
        )
        return result.to_json()

    first = run(ideal_recording, 3)
    assert run(ideal_recording, 3) == first
    assert run(ideal_recording, 4) != first
    strided = {name: np.asfortranarray(a) for name, a in ideal_recording.populations.items()}
    assert run(dataclasses.replace(ideal_recording, populations=strided), 3) == first
    parsed = json.loads(first)
    assert set(parsed["spatial"]) == {"place"} and len(parsed["head_direction"]["units"]) == 2
    assert parsed["settings"]["seed"] == 3 and len(parsed["spatial"]["place"]["shuffled_90"]) == 6


def test_figures_are_written_as_png_and_pdf(ideal_recording, measures, tmp_path):
    import cv2

    paths = write_measure_figures(ideal_recording, measures, tmp_path / "figures")
    stems = {"measures_rate_maps", "measures_autocorrelograms", "measures_grid_scores", "measures_hd_tuning"}
    assert {p.name for p in paths} == {f"{s}{ext}" for s in stems for ext in (".png", ".pdf")}
    for path in paths:
        assert path.is_file() and path.stat().st_size > 5_000, path.name
        if path.suffix == ".png":
            image = cv2.imread(str(path), cv2.IMREAD_COLOR)
            assert image is not None and image.shape[1] >= 1200, path.name  # 300 dpi, ≥ 4 in wide
            colours = np.unique(
                image[::4, ::4].reshape(-1, 3).astype(np.int32) @ np.array([1 << 16, 1 << 8, 1])
            )
            assert len(colours) > 50, f"{path.name} looks blank"
        else:
            assert path.read_bytes().startswith(b"%PDF")


def test_importing_the_measures_imports_no_optional_library():
    code = (
        "import sys, hippo_nav, hippo_nav.recording.measures, hippo_nav.recording.figures\n"
        "heavy = [m for m in ('opexebo', 'matplotlib', 'skimage', 'astropy') if m in sys.modules]\n"
        "assert not heavy, heavy"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
