"""A session's closures onto a loaded map are scored against the truth like any other: the memory keeps where
each vertex was made and where the run went (`truth.npz`, in the dataset's own frame), and a later session on
the same sequence reads them back into its own results' frame."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import QUIET
from hippo_nav.memory import TRUTH_FILE, read_memory
from hippo_nav.pipeline import Pipeline, config_from_dict
from hippo_nav.pipeline.truth import loaded_truth
from test_memory import LAP, Slice


@pytest.fixture(scope="module")
def day_one(demo, tmp_path_factory) -> Path:
    """The demo's first lap, run as a dataset of its own (the same name as the second session's)."""
    out = tmp_path_factory.mktemp("day_one") / "run"
    Pipeline(Slice(demo, 0, LAP), config_from_dict(QUIET)).run(out)
    return out


def test_a_memory_keeps_where_each_vertex_was_made_and_where_the_run_went(demo, day_one):
    memory = read_memory(day_one)
    metrics = json.loads((day_one / "metrics.json").read_text())
    vertex, path = memory.truth["vertex_position_m"], memory.truth["path_position_m"]
    assert vertex.shape == (metrics["vertices"], 3) and np.isfinite(vertex).all()
    gt = demo.ground_truth()[:LAP, :3, 3]  # the dataset's own frame, not rebased
    np.testing.assert_array_equal(path, gt)
    # Each vertex lies where the truth says the agent was when it was made (frames.csv: vertex_created).
    lines = (day_one / "frames.csv").read_text().splitlines()
    header = lines[0].split(",")
    made = {}
    for position, line in enumerate(lines[1:]):
        row = dict(zip(header, line.split(",")))
        if row["vertex_created"] == "1":
            made[int(row["vertex"])] = position
    assert len(made) == len(vertex)
    for v, position in made.items():
        np.testing.assert_array_equal(vertex[v], gt[position])
    assert memory.info["truth"] == {"source": demo.name}
    assert (day_one / "memory" / TRUTH_FILE).is_file()


def test_a_later_sessions_closures_onto_the_loaded_map_are_scored(demo, day_one, tmp_path):
    """Day 2 (the second lap) closes onto day 1's vertices: each closure is scored against the truth (before,
    precision and recall were None), every frame of the second lap counts as a revisit, and the memory it
    saves holds both days' truth."""
    result = Pipeline(Slice(demo, LAP + 5, 195), config_from_dict(QUIET), memory=read_memory(day_one)).run(
        tmp_path / "day_two"
    )
    quality = result.metrics["closure_quality"]
    onto = quality["onto_loaded_map"]
    # Measured: 12 closures onto day 1's vertices, all true, the farthest 2.1 m; recall 1.0 over 50 revisits.
    assert onto["closures"] >= 5 and onto["true_closures"] == onto["closures"], quality
    assert quality["precision"] == 1.0 and quality["max_closure_distance_m"] < 3.0, quality
    assert quality["revisit_frames"] == len(result.record) and quality["recall"] >= 0.9, quality
    both = read_memory(tmp_path / "day_two")
    assert both.truth["path_position_m"].shape == (LAP + len(result.record), 3)
    assert both.truth["vertex_position_m"].shape == (result.metrics["vertices"], 3)
    np.testing.assert_array_equal(
        both.truth["vertex_position_m"][: len(read_memory(day_one).truth["vertex_position_m"])],
        read_memory(day_one).truth["vertex_position_m"],
    )


def test_a_loaded_truth_of_another_sequence_is_left_unscored_and_said(demo, day_one, tmp_path):
    other = Slice(demo, LAP + 5, 175)
    other.name = "another_sequence"
    result = Pipeline(other, config_from_dict(QUIET), memory=read_memory(day_one)).run(tmp_path / "other")
    onto = result.metrics["closure_quality"]["onto_loaded_map"]
    assert "another frame" in onto["unscored"] and "'another_sequence'" in onto["unscored"]


def test_the_loaded_truth_is_moved_into_the_runs_rebased_frame(demo, day_one):
    memory = read_memory(day_one)
    gt = demo.ground_truth()[LAP + 5 : 195]
    truth, why = loaded_truth(memory, demo.name, gt)
    assert why is None and truth is not None
    # Day 1's path, seen from day 2's first pose: where day 2 starts, day 1 passed within metres of the origin
    # of day 2's frame (the loop's second lap); the dataset's frame has its origin at day 1's start.
    start = np.linalg.inv(gt[0])
    expected = memory.truth["path_position_m"] @ start[:3, :3].T + start[:3, 3]
    np.testing.assert_allclose(truth.path_position_m, expected)
    assert np.linalg.norm(truth.path_position_m, axis=1).min() < 3.0
    assert loaded_truth(memory, demo.name, None) == (None, "this run has no ground truth")
