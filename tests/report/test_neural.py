"""A run's networks measured and drawn from its results folder (`hippo-nav figures --run DIR`,
`hippo_nav.report.neural`): the figures (PNG and PDF) and `neural_measures.json` without running again; the
decoded phase's circular error small beside each module's spacing (and large when the phase is computed with
the wrong period); rate maps that are occupancy-normalised and folded on the torus; an older results folder
refused with the way out.

The run is the shared `demo_results` folder (tests/conftest.py); it is copied before anything is written."""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest
from hippo_nav.cli import main
from hippo_nav.pipeline.recording import MODULE_PHASE_FILE, RECORDING_FILE
from hippo_nav.recording import GRID_POPULATIONS
from hippo_nav.report.neural import (
    DPI,
    FIGURES,
    MEASURES_FILE,
    PAGE_WIDTH_IN,
    circular_error,
    decoded_phase_errors,
    load_run_recording,
    rate_maps,
)

MAX_RMS_ERROR_M = 1.0  # the demo's 60 frames: 0.31–0.34 m per module; 3.3 m with the period 10 % off
MAX_RMS_FRACTION = 0.04  # of the spacing P/k: 0.3 % (k = 1) to 1.4 % (k = 4)


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
    assert "neural_measures.json" in capsys.readouterr().out


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
