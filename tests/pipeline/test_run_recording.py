"""A run's recording (`hippo_nav.pipeline.recording`): `recording.npz` loads as a `Recording` with every
population over every frame, in the networks' own frame (their decoded heading and position agree with the
truth without alignment), each recorded unit fires where its phase says, and `output.recording` turns it off.

The run is the shared `demo_results` folder (tests/conftest.py): the demo's first 60 frames, written once."""

from __future__ import annotations

import numpy as np
from conftest import DEMO_RUN_FRAMES, Frames
from hippo_nav.geometry import wrap_angle
from hippo_nav.pipeline import Pipeline, config_from_dict
from hippo_nav.pipeline.recording import MODULE_PHASE_FILE, RECORDING_FILE, ModulePhases
from hippo_nav.pipeline.records import UNITS_PER_AXIS
from hippo_nav.pipeline.results import PREVIOUS_RESULTS, RESULT_FILES, PreviousResults
from hippo_nav.recording import GRID_POPULATIONS, Recording

N = DEMO_RUN_FRAMES


def test_the_results_folder_holds_a_recording_of_every_population_over_every_frame(demo_results):
    assert {RECORDING_FILE, MODULE_PHASE_FILE} <= set(RESULT_FILES)  # --overwrite sets them aside
    rec = Recording.load(demo_results / RECORDING_FILE)
    assert set(rec.populations) == {"hd", *GRID_POPULATIONS, "place"}
    for name, rates in rec.populations.items():
        assert rates.dtype == np.float32 and rates.shape == (N, UNITS_PER_AXIS**2), name
        assert np.isfinite(rates).all() and rates.min() >= 0.0 and rates.max() > 0.0, name
        assert rec.unit_phase_rad[name].shape == (
            (UNITS_PER_AXIS**2,) if name == "hd" else (UNITS_PER_AXIS**2, 2)
        )
    for series in (rec.time_s, rec.position_m, rec.heading_rad, rec.speed_m_s, rec.decoded_position_m):
        assert len(series) == N and np.isfinite(series).all()
    np.testing.assert_allclose(np.diff(rec.time_s), rec.sample_dt_s)  # uniform sampling, as Recording says
    assert (rec.torus_period_m, rec.module_k, rec.lesioned) == (100.0, (1, 2, 4), (False, False, False))
    assert rec.metadata["position_source"] == "ground truth" and rec.metadata["frames"] == N
    np.testing.assert_allclose(rec.position_m[0], 0.0, atol=1e-9)  # metres from the start
    assert 5.0 < np.median(rec.speed_m_s) < 20.0  # the demo car's few m/s … tens of km/h
    phases = ModulePhases.load(demo_results / MODULE_PHASE_FILE)
    assert phases.tracked_rad.shape == phases.position_m.shape == (N, 3, 2)
    assert phases.start_tracked_rad.shape == (3, 2) and np.isfinite(phases.start_tracked_rad).all()
    assert len(phases.frame_index) == len(phases.timestamp_s) == N


def test_the_recording_is_in_the_networks_frame_where_decoded_and_true_agree_unaligned(demo_results):
    rec = Recording.load(demo_results / RECORDING_FILE)
    # The true track is turned by the networks' initial heading code: their estimates need no alignment.
    heading_error = np.abs(wrap_angle(rec.decoded_heading_rad - rec.heading_rad))
    assert np.max(heading_error) < 0.2
    assert np.max(np.linalg.norm(rec.decoded_position_m - rec.position_m, axis=1)) < 2.0
    assert np.ptp(rec.position_m, axis=0).max() > 30.0  # and the car did move


def test_each_recorded_grid_unit_fires_where_its_phase_says(demo_results):
    """The most active recorded unit of a module is the one nearest the decoded bump (modulo the module's
    lattice, 2π/k): the unit phases are in the activity's column order, θx first."""
    rec = Recording.load(demo_results / RECORDING_FILE)
    phases = ModulePhases.load(demo_results / MODULE_PHASE_FILE)
    for m, name in enumerate(GRID_POPULATIONS):
        cell_rad = 2 * np.pi / rec.module_k[m]
        unit_phase = rec.unit_phase_rad[name]
        sample_rad = np.diff(np.unique(unit_phase[:, 0]))[0]  # spacing of the recorded sub-grid
        strongest = unit_phase[np.argmax(rec.populations[name], axis=1)]
        offset = np.remainder(strongest - phases.tracked_rad[:, m] + cell_rad / 2, cell_rad) - cell_rad / 2
        # The nearest recorded unit is within half a sample spacing per axis (a bit more for a skewed bump).
        assert np.abs(offset).max() < 0.75 * sample_rad, name


def test_output_recording_false_writes_no_recording(demo, tmp_path):
    config = config_from_dict({"output": {"figures": False, "save_map": False, "recording": False}})
    Pipeline(Frames(demo, 4), config).run(tmp_path / "run")
    assert (tmp_path / "run" / "metrics.json").is_file()
    assert not (tmp_path / "run" / RECORDING_FILE).exists()
    assert not (tmp_path / "run" / MODULE_PHASE_FILE).exists()


def test_overwrite_sets_aside_the_recording_and_the_figures_drawn_from_it(tmp_path):
    folder = tmp_path / "run"
    (folder / "figures").mkdir(parents=True)
    for name in (RECORDING_FILE, MODULE_PHASE_FILE, "figures/neural_measures.json", "mine.txt"):
        (folder / name).write_text("x")
    PreviousResults.set_aside(folder)
    assert sorted(p.name for p in folder.iterdir()) == [PREVIOUS_RESULTS, "mine.txt"]  # the user's file stays
