"""The per-frame system apart from its runner: stepped by hand it decides what the runner records; its parts
are chosen by the config's `parts` section and can be replaced; the end of a run is a pure function."""

from __future__ import annotations

import threading
from typing import ClassVar

import numpy as np
import pytest
from conftest import QUIET, Frames
from hippo_nav import HippoNavError
from hippo_nav._defaults import ConfigSection
from hippo_nav.closure import ClosureAttempt, ClosureChain, ClosureContext
from hippo_nav.pipeline import Pipeline, SlamSystem, config_from_dict, parts
from hippo_nav.pipeline.assemble import assemble_result
from hippo_nav.pipeline.results import RunFacts, evaluate
from hippo_nav.plugs import Part
from hippo_nav.view_cells import TemplateViewCells, TemplateViewConfig
from hippo_nav.vo import StereoOdometry

N = 30


@pytest.fixture(scope="module")
def reference(demo):
    """A 30-frame run of the demo through the runner, its front end on the calling thread."""
    config = config_from_dict({**QUIET, "overlap_front_end": False})
    return Pipeline(Frames(demo, N), config).run(None)


def test_the_system_stepped_by_hand_decides_what_the_runner_records(demo, reference):
    data = Frames(demo, N)
    system = SlamSystem(data.calibration, config_from_dict(QUIET))
    odometry = StereoOdometry(data.calibration, system.config.vo)
    records = []
    for frame in data:
        step = odometry.process(frame)
        records.append(system.step(frame, step.camera_prev_from_camera_cur, step.status).record)
    assert system.frames == N
    for name in ("view_cell", "view_status", "vertex", "loop_closure", "closure_note", "motion_flag"):
        assert [getattr(r, name) for r in records] == reference.record.column(name), name
    np.testing.assert_array_equal(
        np.stack([r.online_pose for r in records]), np.stack(reference.record.column("online_pose"))
    )
    # The system's memory is what a later run would keep: the map, the view cells, the keyframes.
    memory = system.memory
    assert len(memory.experience_map) == reference.metrics["vertices"]
    assert len(memory.view_recall) == reference.metrics["view_cells"]
    assert isinstance(memory.closure, ClosureChain) and memory.closure.stored > 0


class WorkerDescribedTemplate(TemplateViewCells):
    """The template descriptor, described on the front end's worker (a frame ahead of the back end)."""

    describe_on_worker = True
    threads: ClassVar[set[int]] = set()  # the threads `describe` ran on, over every instance

    def describe(self, frame):
        WorkerDescribedTemplate.threads.add(threading.get_ident())
        return super().describe(frame)


class SilentProposer:
    """A closure proposer that never proposes."""

    def __init__(self, config: ConfigSection) -> None:
        self.frames = 0

    def propose(self, context: ClosureContext) -> ClosureAttempt:
        self.frames += 1
        return ClosureAttempt()

    def after_map(self, outcome) -> None:
        pass


def test_a_view_descriptor_plugs_in_by_a_class_and_a_config_choice(demo, monkeypatch):
    monkeypatch.setitem(
        parts.VIEW_CELLS,
        "worker_template",
        Part(WorkerDescribedTemplate.for_camera, TemplateViewConfig, "views"),
    )
    config = config_from_dict({**QUIET, "parts": {"view_cells": "worker_template"}})
    result = Pipeline(Frames(demo, N), config).run(None)
    template = config_from_dict({**QUIET, "overlap_front_end": False, "parts": {"view_cells": "template"}})
    reference = Pipeline(Frames(demo, N), template).run(None)
    # Described on the front end's worker thread, never on the calling one; the same cells either way.
    assert WorkerDescribedTemplate.threads and threading.get_ident() not in WorkerDescribedTemplate.threads
    assert result.record.column("view_cell") == reference.record.column("view_cell")
    np.testing.assert_array_equal(result.corrected_world_from_camera, reference.corrected_world_from_camera)


@pytest.mark.slow
def test_a_closure_proposer_plugs_in_and_the_map_only_closes_what_is_proposed(demo, monkeypatch):
    made: list[SilentProposer] = []

    def silent(config):
        made.append(SilentProposer(config))
        return made[-1]

    monkeypatch.setitem(parts.CLOSURE_PROPOSERS, "silent", Part(silent, ConfigSection, "silent"))
    data = Frames(demo, 200)
    config = config_from_dict({**QUIET, "parts": {"closure": ["silent"]}})
    result = Pipeline(data, config).run(None)
    assert made[0].frames == 200  # asked on every frame
    assert result.metrics["loop_closures"] == 0
    # The store keeps every vertex's keyframe whoever proposes (a later proposer may measure it).
    assert result.metrics["keyframes"] == result.metrics["vertices"]
    assert result.metrics["familiar_view_frames"] > 0  # there were revisits to close
    # No proposer asked for this frame's keyframe: every one was made for a vertex, on the slow-work thread.
    assert result.metrics["keyframe_extractions"] == {
        "by_proposers": 0,
        "kept_by_a_vertex": 0,
        "for_new_vertices": result.metrics["vertices"],
    }


class MeasuringProposer(SilentProposer):
    """Asks for this frame's keyframe on every frame (as a proposer about to measure), proposes nothing."""

    def propose(self, context: ClosureContext) -> ClosureAttempt:
        self.frames += 1
        keyframe, _ = context.keyframes.current()
        assert keyframe is not None and context.keyframes.current()[0] is keyframe  # once a frame
        return ClosureAttempt()


def test_the_keyframes_a_proposer_extracts_are_counted_and_a_new_vertex_keeps_its_frames(demo, monkeypatch):
    monkeypatch.setitem(
        parts.CLOSURE_PROPOSERS, "measuring", Part(MeasuringProposer, ConfigSection, "measuring")
    )
    config = config_from_dict({**QUIET, "parts": {"closure": ["measuring"]}})
    result = Pipeline(Frames(demo, 60), config).run(None)
    vertices = result.metrics["vertices"]
    assert 1 < vertices < 60
    # Extracted on every frame for the proposer; a frame that made a vertex gave it that keyframe, so none was
    # extracted again for a vertex, and the rest (frames without a new vertex) were the proposer's own cost.
    assert result.metrics["keyframe_extractions"] == {
        "by_proposers": 60,
        "kept_by_a_vertex": vertices,
        "for_new_vertices": 0,
    }
    assert result.metrics["keyframes"] == vertices


def test_an_unknown_part_is_refused_naming_the_choices():
    with pytest.raises(
        HippoNavError, match=r"parts\.view_cells: .*unknown 'orb'; choose from template, words \(got 'orb'\)"
    ):
        config_from_dict({"parts": {"view_cells": "orb"}})


def test_the_end_of_a_run_is_a_pure_function_of_record_and_map(reference):
    record, export = reference.record, reference.map_export
    poses_before = export["poses"].copy()
    again = assemble_result("again", record, export, 0.3, None, interrupted=False)
    np.testing.assert_array_equal(again.corrected_world_from_camera, reference.corrected_world_from_camera)
    np.testing.assert_array_equal(again.vo_world_from_camera, reference.vo_world_from_camera)
    assert again.ground_truth is None and again.metrics == {} and len(again.record) == N
    np.testing.assert_array_equal(export["poses"], poses_before)  # its inputs are left as they were
    # Its metrics need the result and a few facts, never a pipeline.
    facts = RunFacts(
        frames_requested=N, note="", seed=0, lesioned=[False, False, False], closure_mode="Geometric",
        min_loop_separation_m=50.0, view_cells=reference.metrics["view_cells"], keyframes=0, keyframe_bytes=0,
        data_warnings=[], stereo_bias_px=None, disparity_offset_px=None, missing_frames=0,
        frames_without_timestamp=0,
    )  # fmt: skip
    metrics = evaluate(again, facts, {"method": "none"}, None)
    assert metrics["frames"] == N and metrics["loop_closures"] == reference.metrics["loop_closures"]
    assert "errors" not in metrics  # no ground truth given
