"""The plug points as docs/architecture.md promises them: a view descriptor and a closure proposer of one's own
are one module (`toy_parts.py`) and one registry line each. Their settings become config sections with their
defaults and checks, the closure chain runs them in the configured order, and a saved map keeps and checks
their state like the built-in parts'."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import QUIET
from hippo_nav import HippoNavError
from hippo_nav.closure import PROPOSERS
from hippo_nav.memory import read_memory
from hippo_nav.pipeline import config_from_dict, run
from hippo_nav.plugs import Part
from hippo_nav.view_cells import DESCRIPTORS
from toy_parts import NearestVertexConfig, NearestVertexProposer, ThumbnailCells, ThumbnailConfig

CHAIN = ["relocalisation", "nearest", "view_cell"]


@pytest.fixture
def toys(monkeypatch):
    # What a newcomer writes besides the module: one line in each registry.
    monkeypatch.setitem(DESCRIPTORS, "thumbnail", Part(ThumbnailCells, ThumbnailConfig, "thumbnail_cells"))
    monkeypatch.setitem(PROPOSERS, "nearest", Part(NearestVertexProposer, NearestVertexConfig, "nearest"))


def _config(**sections):
    parts = {"view_cells": "thumbnail", "closure": sections.pop("chain", CHAIN)}
    return config_from_dict({**QUIET, "parts": parts, **sections})


@pytest.mark.slow
def test_a_toy_descriptor_and_proposer_run_the_demo_and_live_on_in_its_map(toys, tmp_path):
    config = _config(thumbnail_cells={"threshold": 0.4}, closure={"nearest": {"radius_m": 5.0}})
    first = run(tmp_path / "first", config=config, progress=False)
    notes = first.metrics["closure_attempts"]
    quality = first.metrics["closure_quality"]
    assert notes.get("accepted_nearest", 0) >= 3 and quality["false_closures"] == 0, (notes, quality)
    assert first.metrics["view_cells"] > 0
    # Their sections are in the resolved config, with the defaults the run left alone.
    written = json.loads((tmp_path / "first" / "config.json").read_text())
    assert written["thumbnail_cells"] == {"width_px": 24, "threshold": 0.4}
    assert written["closure"]["nearest"] == {"radius_m": 5.0, "min_inliers": 20}
    assert written["parts"]["closure"] == CHAIN
    # The saved map holds their state, under their names.
    memory = read_memory(tmp_path / "first")
    assert memory.views["cells.thumbnails"].shape == (first.metrics["view_cells"], 8, 24)
    assert int(memory.keyframes["nearest.proposed"]) >= notes["accepted_nearest"]  # accepted or refused
    assert memory.info["depends_on"]["view_cells"] == {"width_px": 24}
    # A later session starts inside it: relocalised by the chain's first proposer.
    second = run(tmp_path / "second", config=config, progress=False, memory_from=tmp_path / "first")
    loaded = second.metrics["loaded_map"]
    assert loaded["view_cells"] == first.metrics["view_cells"] and loaded["relocalised"], loaded
    # Thumbnails of another size cannot be matched with the saved ones: refused, naming the setting.
    other = _config(thumbnail_cells={"width_px": 16}, closure={"nearest": {"radius_m": 5.0}})
    with pytest.raises(HippoNavError, match=r"view_cells\.width_px = 24, this run has 16"):
        run(tmp_path / "third", config=other, progress=False, memory_from=tmp_path / "first")


@pytest.mark.slow
def test_a_resumed_run_gives_each_proposer_its_saved_state(toys, tmp_path):
    from hippo_nav.pipeline import SlamSystem

    config = _config()
    run(tmp_path / "first", config=config, progress=False, stop=150)
    saved = read_memory(tmp_path / "first")
    system = SlamSystem(first_calibration(), config, memory=saved, resume=True)
    assert system.closure is not None
    nearest = dict(system.closure.proposers)["nearest"]
    assert isinstance(nearest, NearestVertexProposer) and nearest.proposed == int(
        saved.keyframes["nearest.proposed"]
    )
    assert nearest.proposed > 0


def first_calibration():
    from hippo_nav.pipeline import open_input

    return open_input(stop=1).calibration


@pytest.mark.slow
def test_a_proposer_is_removed_or_reordered_in_the_config_alone(toys):
    counts = {}
    for chain in (["nearest", "view_cell"], ["view_cell", "nearest"], ["view_cell"]):
        result = run(None, config=_config(chain=chain), progress=False)
        notes = result.metrics["closure_attempts"]
        counts[tuple(chain)] = notes.get("accepted_nearest", 0)
        assert result.metrics["closure_quality"]["false_closures"] == 0, notes
    # First in the chain, it proposes more of the closures than second; removed, none.
    assert counts[("nearest", "view_cell")] > counts[("view_cell", "nearest")] >= 0
    assert counts[("view_cell",)] == 0


def test_a_part_of_ones_own_has_its_settings_checked_like_a_built_in(toys):
    with pytest.raises(HippoNavError, match=r"closure\.nearest\.radius_m: Input should be greater than 0"):
        _config(closure={"nearest": {"radius_m": -1.0}})
    with pytest.raises(HippoNavError, match=r"thumbnail_cells\.widht_px: Extra inputs are not permitted"):
        _config(thumbnail_cells={"widht_px": 16})
    with pytest.raises(HippoNavError, match=r"parts\.closure: 'nearest' listed twice"):
        _config(chain=["nearest", "nearest"])


def test_a_registered_part_has_its_section_without_being_chosen(toys):
    defaults = config_from_dict({})
    assert defaults.section("thumbnail_cells") == ThumbnailConfig()
    assert defaults.closure.section("nearest") == NearestVertexConfig()
    np.testing.assert_equal(defaults.parts.closure, ["relocalisation", "view_cell", "proximity", "home"])
