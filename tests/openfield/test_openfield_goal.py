"""The open-field goal of docs/neuro.md, on the default 20-minute session: every grid module's measured units
pass the 90° grid-score shuffle threshold (the model's lattice is square), none passes the 60° one, the
spacings keep the design's 1 : ½ : ¼ within 5 %, and the ring's units are tuned to their design heading.
Slow (a 20-minute session is ~5 minutes of simulation): run by `make test-all` and CI."""

from __future__ import annotations

import pytest

pytest.importorskip("opexebo")
pytest.importorskip("ratinabox")

from hippo_nav.openfield import OpenFieldConfig, record_session
from hippo_nav.recording import GRID_POPULATIONS
from hippo_nav.recording.measures import measure_recording


@pytest.mark.slow
def test_a_20_minute_session_has_square_grid_cells_in_every_module():
    recording = record_session(OpenFieldConfig(seed=1))
    measures = measure_recording(recording, units_per_population=16, shuffles=10, seed=1).to_dict()
    for population in GRID_POPULATIONS:
        summary = measures["spatial"][population]
        assert summary["fraction_passing_90"] >= 0.9, (population, summary["fraction_passing_90"])
        assert summary["fraction_passing_60"] <= 0.1, (population, summary["fraction_passing_60"])
    for population, design in measures["design_spacing_ratios"].items():
        assert measures["module_spacing_ratios"][population] == pytest.approx(design, rel=0.05)
    hd = measures["head_direction"]
    assert hd["fraction_passing"] == 1.0 and hd["direction_error_max_abs_deg"] < 10.0
