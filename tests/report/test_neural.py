"""A run's networks measured and drawn from its results folder (`hippo-nav figures --run DIR`,
`hippo_nav.report.neural`): the figures (PNG and PDF) and `neural_measures.json` without running again; the
decoded phase's circular error small beside each module's spacing (and large when the phase is computed with
the wrong period); rate maps that are occupancy-normalised and folded on the torus; an older results folder
refused with the way out; the lab's measures (grid scores, spacing, orientation, information, fields, HD
tuning, topology) on maps folded onto two spacings, which find each module's lattice along a long synthetic
road and, on the short demo drive, say why they cannot be read.

The run is the shared `demo_results` folder (tests/conftest.py); it is copied before anything is written. The
long drive is synthetic: ideal units of the modules' periods along a car's winding road (`road_recording`)."""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest
from hippo_nav.cli import main
from hippo_nav.pipeline.recording import MODULE_PHASE_FILE, RECORDING_FILE
from hippo_nav.recording import GRID_POPULATIONS, Recording
from hippo_nav.report.neural import (
    DPI,
    FIGURES,
    LAB_FOLD_PERIODS,
    LAB_MIN_COVERAGE,
    MEASURES_FILE,
    PAGE_WIDTH_IN,
    STYLE,
    circular_error,
    decoded_phase_errors,
    drive_measures,
    drive_topology,
    finite_frames,
    fold_coverage,
    lab_measures_figure,
    load_run_recording,
    rate_maps,
)
from matplotlib import rc_context

MAX_RMS_ERROR_M = 1.0  # the demo's 60 frames: 0.31–0.34 m per module; 3.3 m with the period 10 % off
MAX_RMS_FRACTION = 0.04  # of the spacing P/k: 0.3 % (k = 1) to 1.4 % (k = 4)
ROAD_PERIOD_M = 100.0  # the runs' torus period: spacings 100, 50 and 25 m
ROAD_SPEED_M_S = 12.0
ROAD_DT_S = 0.1  # KITTI's frame interval
ROAD_MODULE_K = (1, 2, 4)


@pytest.fixture
def run_copy(demo_results, tmp_path):
    """The demo run's recording in a folder of its own (the figures are written into it)."""
    folder = tmp_path / "run"
    folder.mkdir()
    for name in (RECORDING_FILE, MODULE_PHASE_FILE, "metrics.json"):
        shutil.copy(demo_results / name, folder / name)
    return folder


def test_figures_run_writes_png_pdf_and_the_measures_into_the_run_folder(run_copy, capsys):
    assert main(["figures", "--run", str(run_copy)]) == 0
    out = run_copy / "figures"
    for stem in FIGURES:
        png, pdf = out / f"{stem}.png", out / f"{stem}.pdf"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and pdf.read_bytes()[:5] == b"%PDF-"
        width_px = int.from_bytes(png.read_bytes()[16:20], "big")  # the IHDR chunk
        assert width_px == round(PAGE_WIDTH_IN * DPI)  # a double column at 300 dpi
    measures = json.loads((out / MEASURES_FILE).read_text())
    assert set(measures["decoded_phase"]) == {*GRID_POPULATIONS, "place"}
    for name in GRID_POPULATIONS:
        error = measures["decoded_phase"][name]
        assert (
            error["rms_error_m"] < MAX_RMS_ERROR_M
            and error["rms_error_fraction_of_spacing"] < MAX_RMS_FRACTION
        )
        assert error["spacing_m"] == 100.0 / error["k"] and error["frames"] == 60
        assert len(measures["rate_maps"]["example_units"][name]) == 3
    assert measures["rate_maps"]["track"]["bin_size_m"] > 0 and measures["position_source"] == "ground truth"
    lab = measures["lab_measures"]
    assert set(lab["populations"]) == {*GRID_POPULATIONS, "place", "hd"}
    assert lab["fold_periods"] == LAB_FOLD_PERIODS and lab["bins_per_spacing"] > 0
    assert measures["topology"]["computed"] is False and "topology=True" in measures["topology"]["reason"]
    assert "lab_measures.png" in measures["figures"]
    assert "neural_measures.json" in capsys.readouterr().out


def test_figures_run_topology_says_why_a_short_drive_has_none(run_copy, capsys):
    assert main(["figures", "--run", str(run_copy), "--topology"]) == 0
    topology = json.loads((run_copy / "figures" / MEASURES_FILE).read_text())["topology"]
    # The demo's 60 frames are far from the 600 moving frames a point cloud needs: each population says so.
    assert set(topology) == {*GRID_POPULATIONS, "hd"}
    for name, population in topology.items():
        assert population["computed"] is False, name
        assert "60 moving frames, fewer than" in population["reason"], name
    assert main(["figures", "--topology"]) == 2
    assert "give --run DIR" in capsys.readouterr().err


def test_the_decoded_phase_error_is_small_and_a_wrong_period_is_caught(demo_results):
    recording, phases = load_run_recording(demo_results)
    errors = decoded_phase_errors(recording, phases)
    for name in GRID_POPULATIONS:
        assert errors[name]["rms_error_m"] < MAX_RMS_ERROR_M, name
        assert errors[name]["rms_error_fraction_of_spacing"] < MAX_RMS_FRACTION, name
    # The same phases read with a period 10 % off (or positions in another frame) miss by metres.
    wrong_period = dataclasses.replace(recording, torus_period_m=0.9 * recording.torus_period_m)
    wrong_frame = dataclasses.replace(recording, position_m=recording.position_m[:, ::-1])
    for wrong in (wrong_period, wrong_frame):
        for name, error in decoded_phase_errors(wrong, phases).items():
            if name != "place":
                assert error["rms_error_m"] > 2 * MAX_RMS_ERROR_M, name


def test_an_older_results_folder_without_a_recording_is_refused_with_the_way_out(
    demo_results, tmp_path, capsys
):
    old = tmp_path / "old"
    shutil.copytree(demo_results, old, ignore=shutil.ignore_patterns(RECORDING_FILE, MODULE_PHASE_FILE))
    assert main(["figures", "--run", str(old)]) == 2
    message = capsys.readouterr().err
    assert RECORDING_FILE in message and "run it again" in message and "--overwrite" in message
    assert not (old / "figures").exists()  # nothing made
    assert main(["figures", "--run", str(tmp_path / "nowhere")]) == 2
    assert "no such results folder" in capsys.readouterr().err


def _truncated(path) -> None:
    path.write_bytes(path.read_bytes()[:300])


def _phases_of_fewer_frames(path) -> None:
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    for name in ("frame_index", "timestamp_s", "tracked_rad", "position_m"):
        arrays[name] = arrays[name][:5]
    np.savez(path, **arrays)


def _phases_with_a_short_array(path) -> None:
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["position_m"] = arrays["position_m"][:5]
    np.savez(path, **arrays)


@pytest.mark.parametrize(
    ("damage", "says"),
    [
        (_truncated, "not a readable module-phase file"),
        (_phases_with_a_short_array, "position_m has shape"),
        (_phases_of_fewer_frames, "come from different runs"),
    ],
)
def test_figures_run_on_damaged_or_mismatched_files_is_one_line(run_copy, capsys, damage, says):
    damage(run_copy / MODULE_PHASE_FILE)
    assert main(["figures", "--run", str(run_copy)]) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (run_copy / "figures").exists()


def test_circular_error_wraps_whole_spacings_and_reports_rms():
    true = np.column_stack([np.linspace(0.0, 200.0, 101), np.zeros(101)])
    decoded = true + [0.5, 0.0] + 25.0 * (np.arange(101)[:, None] % 3)  # off by 0.5 m and whole spacings
    error = circular_error(decoded, true, 25.0)
    assert error["rms_error_m"] == pytest.approx(0.5) and error[
        "rms_error_fraction_of_spacing"
    ] == pytest.approx(0.02)
    assert error["rms_error_x_m"] == pytest.approx(0.5) and error["rms_error_y_m"] == pytest.approx(0.0)


def test_rate_maps_are_occupancy_normalised():
    # Along a road, dwelling ten times longer in the first half must not raise that half's rate.
    x = np.concatenate([np.repeat(np.arange(0.0, 20.0, 0.5), 10), np.arange(20.0, 40.0, 0.5)])
    positions = np.column_stack([x, np.zeros_like(x)])
    maps = rate_maps(positions, np.full((len(x), 1), 3.0), dt_s=0.1, bin_size_m=2.0, sigma_m=3.0)
    visited = maps.rates[0][np.isfinite(maps.rates[0])]
    np.testing.assert_allclose(visited, 3.0)
    assert np.isnan(maps.rates[0]).any()  # bins off the road are left blank, not zero


def test_folded_rate_maps_gather_a_lattice_onto_one_field_smoothed_across_the_fold():
    spacing_m, field_m = 25.0, np.array([0.4, 24.6])  # a field at the fold's corner
    axis = np.arange(0.0, 100.0, 0.5)
    positions = np.stack(np.meshgrid(axis, axis), axis=-1).reshape(-1, 2)
    offset = np.remainder(positions - field_m + spacing_m / 2, spacing_m) - spacing_m / 2
    activity = np.exp(-0.5 * np.sum(offset**2, axis=1) / 1.5**2)[:, None]  # fields every 25 m
    maps = rate_maps(
        positions, activity, 0.1, bin_size_m=spacing_m / 32, sigma_m=spacing_m / 32, period_m=spacing_m
    )
    rate = maps.rates[0]
    assert rate.shape == (32, 32) and maps.extent_m == (0.0, 25.0, 0.0, 25.0) and np.isfinite(rate).all()
    row, col = np.unravel_index(np.argmax(rate), rate.shape)
    assert (row, col) == (31, 0)  # one field, at the lattice's phase
    # Smoothed on the torus: the bins across the fold from the peak are as high as those beside it.
    assert rate[0, 0] == pytest.approx(rate[30, 0], rel=0.05) and rate[31, 31] == pytest.approx(
        rate[31, 1], rel=0.05
    )


# ------------------------------------------------------------------------------------------------
# The lab's measures of a whole drive


def road_drive(frames: int, seed: int = 5, box_m: float = 800.0) -> tuple[np.ndarray, np.ndarray]:
    """Positions (frames, 2) m and headings (rad) of a car at 12 m/s on winding roads: long straights and
    curves (the turn rate an Ornstein–Uhlenbeck process), turned back at the walls of [0, box_m]²."""
    rng = np.random.default_rng(seed)
    position, heading = np.empty((frames, 2)), np.empty(frames)
    here, theta_rad, turn_rad = np.full(2, box_m / 2), 0.4, 0.0
    for i in range(frames):
        turn_rad = 0.97 * turn_rad + rng.normal(0.0, 0.012)
        theta_rad += turn_rad
        step = ROAD_SPEED_M_S * ROAD_DT_S * np.array([np.cos(theta_rad), np.sin(theta_rad)])
        for axis in range(2):
            if not 0.0 <= here[axis] + step[axis] <= box_m:
                step[axis] = -step[axis]
        theta_rad = float(np.arctan2(step[1], step[0]))
        here = here + step
        position[i], heading[i] = here, theta_rad
    return position, heading


def lattice_units(position_m: np.ndarray, k: int, kappa: float) -> tuple[np.ndarray, np.ndarray]:
    """64 ideal units of a module k (a run's 8 × 8 sub-grid of the unit cell, phases in [0, 2π/k)²): each a
    square lattice of fields of spacing P/k, exp(κ(cos(k(2πx/P − θ)) − 1)) per axis; and their phases."""
    i, j = np.divmod(np.arange(64), 8)
    phase_rad = np.stack([2 * np.pi * j / 8, 2 * np.pi * i / 8], axis=1) / k
    angle = k * (2 * np.pi * position_m[:, None, :] / ROAD_PERIOD_M - phase_rad[None])
    return np.exp(kappa * (np.cos(angle) - 1.0)).prod(axis=2).astype(np.float32), phase_rad


def road_recording(
    frames: int = 6000, populations: tuple[str, ...] = (*GRID_POPULATIONS, "place", "hd")
) -> Recording:
    """A run's recording along `road_drive` with ideal units: the modules' lattices (fields about a fifth
    of the spacing wide), the place torus's narrower ones, and an HD ring tuned to the true heading."""
    position, heading = road_drive(frames)
    activity, phases = {}, {}
    for name, k, kappa in zip((*GRID_POPULATIONS, "place"), (*ROAD_MODULE_K, 1), (4.0, 4.0, 4.0, 8.0)):
        if name in populations:
            activity[name], phases[name] = lattice_units(position, k, kappa)
    if "hd" in populations:
        phases["hd"] = 2 * np.pi * np.arange(64) / 64
        activity["hd"] = np.exp(4.0 * (np.cos(heading[:, None] - phases["hd"][None]) - 1.0)).astype(
            np.float32
        )
    return Recording(
        time_s=np.arange(frames) * ROAD_DT_S,
        position_m=position,
        heading_rad=heading,
        speed_m_s=np.full(frames, ROAD_SPEED_M_S),
        decoded_position_m=position.copy(),
        decoded_heading_rad=heading.copy(),
        populations=activity,
        unit_phase_rad=phases,
        torus_period_m=ROAD_PERIOD_M,
        module_k=ROAD_MODULE_K,
        lesioned=(False, False, False),
        metadata={"source": "tests: ideal units along a synthetic road"},
    )


def test_folded_lab_measures_find_each_modules_square_lattice_along_a_road(tmp_path):
    recording = road_recording()
    measures = drive_measures(recording, units_per_population=8, shuffles=10)
    populations = measures.summary["populations"]
    for name in (*GRID_POPULATIONS, "place"):
        entry = populations[name]
        assert entry["measured"] and entry["coverage"] > 0.8, name  # the winding road covers the fold
        assert entry["fold_m"] == LAB_FOLD_PERIODS * entry["design_spacing_m"], name
        # A square lattice: every unit passes the shuffle test at 90°, none at 60°.
        assert entry["fraction_passing_90"] == 1.0 and entry["fraction_passing_60"] == 0.0, name
        assert entry["median_score_90"] > entry["threshold_90"] > entry["median_score_60"], name
        assert entry["spacing_over_design"] == pytest.approx(1.0, abs=0.03), name  # spacing P/k
        assert abs(entry["orientation_mean_deg"]) < 3.0, name  # the torus's axes
        assert entry["information_mean_bits_per_spike"] > 1.0 and entry["field_count_mean"] >= 2, name
    ratios = measures.summary["module_spacing_ratios"]
    assert [ratios[name] for name in GRID_POPULATIONS] == pytest.approx([1.0, 0.5, 0.25], rel=0.03)
    hd = populations["hd"]
    assert hd["measured"] and hd["fraction_passing"] == 1.0 and hd["direction_error_max_abs_deg"] < 3.0
    json.dumps(measures.summary, allow_nan=False)  # NaN written as null, never as NaN
    with rc_context(STYLE):
        figure = lab_measures_figure(recording, measures)
    assert len(figure.axes[0].images) == 1 and len(figure.axes[1].images) == 1  # a map, its autocorrelogram
    figure.savefig(tmp_path / "lab.png")


def test_on_the_short_demo_drive_the_lab_measures_run_and_say_why_they_cannot_be_read(demo_results):
    recording, _ = load_run_recording(demo_results)
    summary = drive_measures(recording).summary
    for name in (*GRID_POPULATIONS, "place"):
        entry = summary["populations"][name]
        # 60 frames of a road cover a few % of a square two spacings wide: nothing is measured, and it says so.
        assert not entry["measured"] and entry["coverage"] < LAB_MIN_COVERAGE, name
        assert "visited" in entry["reason"] and "a longer drive" in entry["reason"], name
    assert (
        not summary["populations"]["hd"]["measured"] and "heading" in summary["populations"]["hd"]["reason"]
    )
    assert summary["module_spacing_ratios"] == {}
    json.dumps(summary, allow_nan=False)
    topology, results = drive_topology(recording)
    assert results == {} and set(topology) == {*GRID_POPULATIONS, "hd"}
    assert all(not e["computed"] and "moving frames" in e["reason"] for e in topology.values())
    lesioned = dataclasses.replace(recording, lesioned=(False, True, False))
    entry = drive_measures(lesioned).summary["populations"]["grid_intermediate"]
    assert not entry["measured"] and entry["reason"].startswith("lesioned")


def test_the_topology_of_a_module_along_a_long_road_is_a_torus():
    # One module, so that the test stays a few seconds (each population's topology takes ~3-10 s).
    recording = road_recording(frames=4000, populations=("grid_dorsal",))
    topology, results = drive_topology(recording)
    entry = topology["grid_dorsal"]
    assert entry["computed"] and entry["coverage"] > 0.9
    assert entry["betti"] == [1, 2, 1] and entry["matches_expected"] and results["grid_dorsal"].is_torus


def test_fold_coverage_and_the_frames_the_measures_drop():
    # A straight road along x folds onto one row of the square: 1 of 10 rows, every column.
    x = np.arange(0.0, 1000.0, 1.0)
    coverage, per_bin = fold_coverage(np.column_stack([x, np.full_like(x, 3.0)]), 50.0, 10)
    assert coverage == pytest.approx(0.1) and per_bin == pytest.approx(100.0)
    recording = road_recording(frames=50, populations=("grid_dorsal",))
    recording.position_m[10] = np.nan
    recording.populations["grid_dorsal"][20, 3] = np.nan
    kept = finite_frames(recording)
    assert len(kept.time_s) == 48 and np.isfinite(kept.position_m).all()
    assert np.allclose(np.diff(kept.time_s), ROAD_DT_S)  # uniform again, as the measures require
