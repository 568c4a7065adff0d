"""Observers get data, never the system: a frozen per-frame event whose costly parts are read only when
asked, and only while they still describe that frame."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import QUIET, Frames
from hippo_nav import HippoNavError
from hippo_nav.engine import SpatialMemory
from hippo_nav.pipeline import FrameEvent, Pipeline, RunResult, config_from_dict
from hippo_nav.view_cells import TemplateViewConfig


class Keeper:
    """Keeps every event; reads the network of the frames named in `read`."""

    def __init__(self, read: set[int]) -> None:
        self.read, self.events, self.networks = read, [], []
        self.result: RunResult | None = None

    def on_frame(self, event: FrameEvent) -> None:
        self.events.append(event)
        if event.position in self.read:
            self.networks.append(event.network)

    def on_finish(self, result: RunResult) -> None:
        self.result = result


def test_events_are_frozen_data_and_read_the_networks_only_when_asked(demo, monkeypatch):
    reads = []
    real = SpatialMemory.hd_activity

    def counted(self):
        reads.append(1)
        return real(self)

    monkeypatch.setattr(SpatialMemory, "hd_activity", counted)
    keeper = Keeper(read={3})
    config = config_from_dict(
        {**QUIET, "output": {"figures": False, "state_frames": []}, "parts": {"view_cells": "template"}}
    )
    result = Pipeline(Frames(demo, 8), config, observers=[keeper]).run(None)
    # One frame asked for the networks; the recorder's final snapshot reads them once more.
    assert len(reads) == 2 and len(keeper.networks) == 1
    assert keeper.networks[0].hd.shape == (15, 128) and keeper.networks[0].ks == (1, 2, 4)
    assert keeper.result is result
    event = keeper.events[3]
    assert event.record is result.record.frames[3] and event.run.frames == 8
    top, bottom = TemplateViewConfig().crop_rows_frac
    assert event.view_rows == (round(top * 96), round(bottom * 96))
    with pytest.raises(dataclasses.FrozenInstanceError):
        event.position = 0  # type: ignore[misc]
    # What a frame's event was not asked for during the run cannot be read later: it would describe
    # the system after another frame. The last frame's still describes the system as it ended.
    with pytest.raises(HippoNavError, match="read after the system moved on"):
        _ = keeper.events[2].vertex_poses
    last = keeper.events[-1]
    assert result.metrics["correction"]["method"] == "none"  # no loop in 8 frames: the map is as it ended
    np.testing.assert_array_equal(last.vertex_poses, result.map_export["poses"])
    assert last.network.place.shape == (64, 64)


@pytest.mark.slow
def test_a_map_event_read_after_the_final_correction_is_refused(demo):
    """After a loop the final correction moves the vertices: the last frame's map is no longer there."""
    keeper = Keeper(read=set())
    result = Pipeline(Frames(demo, 200), config_from_dict(QUIET), observers=[keeper]).run(None)
    assert result.metrics["correction"]["method"] == "least_squares"
    last = keeper.events[-1]
    assert last.network.place.shape == (64, 64)  # the networks are as the last frame left them
    with pytest.raises(HippoNavError, match="read after the system moved on"):
        _ = last.vertex_poses


def test_each_event_carries_the_previous_frames_stage_times(demo):
    keeper = Keeper(read=set())
    result = Pipeline(Frames(demo, 5), config_from_dict(QUIET), observers=[keeper]).run(None)
    assert keeper.events[0].previous_stage_s is None
    for position in range(1, 5):
        times = keeper.events[position].previous_stage_s
        assert times == {stage: s[position - 1] for stage, s in result.record.stage_s.items()}


class FailsAtTheEnd(Keeper):
    """An observer whose last write finds the disk full."""

    def on_finish(self, result: RunResult) -> None:
        raise OSError(28, "No space left on device")


def test_an_observer_failing_at_the_end_keeps_the_results_and_lets_the_others_finish(demo, tmp_path):
    """The results are written before the observers finish: one that fails must not stop the others (the
    Rerun recording beside a video on a full disk) nor hide the results, which the error returns."""
    from hippo_nav.pipeline.observers import ObserverError

    keeper = Keeper(read=set())
    config = config_from_dict({**QUIET, "output": {"figures": False}})
    out = tmp_path / "run"
    with pytest.raises(
        ObserverError, match=r"FailsAtTheEnd failed at the end.*No space.*written to .*run\)"
    ) as err:
        Pipeline(Frames(demo, 5), config, observers=[FailsAtTheEnd(read=set()), keeper]).run(out)
    assert keeper.result is err.value.result and err.value.result.metrics["frames"] == 5
    assert (out / "metrics.json").is_file()
