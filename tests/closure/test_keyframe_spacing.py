"""Keyframes at a spacing (`closure.keyframe_spacing_m`): a new vertex keeps a stereo keyframe only when the
last one was made that far back, the proposers measure the vertices that keep one, the confirmation takes the
nearest keyframed neighbours, and a loop still closes, every closure true, with about half the extractions."""

from __future__ import annotations

from concurrent.futures import Future
from types import SimpleNamespace

import numpy as np
import pytest
from hippo_nav._core import HippoNavError
from hippo_nav.closure import ClosureConfig, Keyframe, KeyframeStore
from hippo_nav.io import write_kitti_poses
from hippo_nav.pipeline import Pipeline, config_from_dict
from hippo_nav.synthetic import drifting_odometry
from hippo_nav.vo.replay import ReplayOdometry


def _done(value) -> Future:
    future: Future = Future()
    future.set_result(value)
    return future


class _Extractions:
    """A store's extractor that records which frames it was asked for and returns a marker keyframe."""

    def __init__(self) -> None:
        self.frames: list[int] = []

    def __call__(self, left, right, offset_px=None):
        self.frames.append(int(left))
        one = np.full((1, 1), left)
        return Keyframe(
            np.zeros((1, 2), np.float32) + one, np.zeros((1, 128), np.uint8), np.ones((1, 3), np.float32)
        )


def _store(spacing_m: float) -> tuple[KeyframeStore, _Extractions]:
    calibration = SimpleNamespace(
        fx=700.0, fy=700.0, cx=300.0, cy=90.0, baseline_m=0.5, image_size_px=(600, 180), K=np.eye(3)
    )
    store = KeyframeStore(calibration, ClosureConfig(keyframe_spacing_m=spacing_m))
    extractions = _Extractions()
    store.extract = extractions  # type: ignore[assignment]
    return store, extractions


_WORKER = SimpleNamespace(submit=lambda work, *args: _done(work(*args)))


def _new_vertex(store: KeyframeStore, vertex: int, odometer_m: float) -> None:
    frame = SimpleNamespace(index=vertex, left=vertex, right=vertex)
    store.begin_frame(frame, None)  # type: ignore[arg-type]
    outcome = SimpleNamespace(created=True, vertex=vertex, loop_closure=None)
    store.after_map(frame, outcome, _WORKER, odometer_m)  # type: ignore[arg-type]


def test_a_vertex_keeps_a_keyframe_only_when_the_last_was_made_the_spacing_back():
    store, extractions = _store(5.0)
    for vertex in range(7):  # a vertex every 3 m
        _new_vertex(store, vertex, 3.0 * vertex)
    assert extractions.frames == [0, 2, 4, 6]
    assert store.keyframed(range(7)) == [0, 2, 4, 6] and len(store) == 4
    # The confirmation's neighbours: the nearest keyframed vertex on each side.
    assert store._keyframed_neighbours(3, 7) == [2, 4]
    assert store._keyframed_neighbours(0, 7) == [2]

    every, extractions = _store(0.0)
    for vertex in range(7):
        _new_vertex(every, vertex, 3.0 * vertex)
    assert extractions.frames == list(range(7)) and every.keyframed([5, 1, 3]) == [5, 1, 3]
    assert every._keyframed_neighbours(3, 7) == [2, 4]


def test_a_keyframe_a_proposer_extracted_is_kept_and_restarts_the_spacing():
    store, extractions = _store(5.0)
    _new_vertex(store, 0, 0.0)
    frame = SimpleNamespace(index=1, left=1, right=1)
    store.begin_frame(frame, None)  # type: ignore[arg-type]
    assert store.current()[1] == "ok"  # a proposer asked for this frame's keyframe (at 3 m)
    store.after_map(frame, SimpleNamespace(created=True, vertex=1), _WORKER, 3.0)  # type: ignore[arg-type]
    _new_vertex(store, 2, 6.0)  # 3 m after the kept one: none
    _new_vertex(store, 3, 9.0)
    assert store.keyframed(range(4)) == [0, 1, 3] and extractions.frames == [0, 1, 3]


def test_the_spacing_outlives_a_saved_memory_and_a_new_session_keyframes_from_its_start():
    store, _ = _store(5.0)
    for vertex in range(3):
        _new_vertex(store, vertex, 3.0 * vertex)  # keyframes at 0 and 6 m
    saved = store.export_state()
    resumed, extractions = _store(5.0)
    resumed.restore_state(saved)
    _new_vertex(resumed, 3, 9.0)  # resumed: 3 m after the last one
    _new_vertex(resumed, 4, 12.0)
    assert extractions.frames == [4]
    # A new session's odometer starts again at 0, behind the loaded memory's last keyframe.
    session, extractions = _store(5.0)
    session.restore_state(saved)
    _new_vertex(session, 3, 0.0)
    assert extractions.frames == [3]
    # A memory saved before the spacing existed (no odometer of the last keyframe) restores.
    older, extractions = _store(5.0)
    older.restore_state({k: v for k, v in saved.items() if k != "last_keyframe_odometer_m"})
    _new_vertex(older, 3, 9.0)
    assert extractions.frames == [3]
    # A NaN point (a memory edited with its checksums recomputed) is refused: it would become a NaN closure.
    damaged = dict(saved)
    damaged["points_m"] = saved["points_m"].copy()
    damaged["points_m"][0, 2] = np.nan
    with pytest.raises(HippoNavError, match="points_m holds NaN"):
        _store(5.0)[0].restore_state(damaged)


@pytest.mark.slow
def test_a_drifting_loop_closes_with_keyframes_at_every_other_vertex(demo, tmp_path):
    # The demo drives 1.4 laps of a 190 m loop (a vertex every 2-3 m); the odometry drifts 3 % in scale and
    # 0.15° a frame. With keyframes 5 m apart the loop is closed by the vertices that keep one.
    truth = demo.ground_truth()
    drifted = drifting_odometry(truth, scale_error=0.03, yaw_bias_deg_per_frame=0.15)
    replay = ReplayOdometry(write_kitti_poses(tmp_path / "odometry.txt", drifted), demo)
    config = config_from_dict(
        {"output": {"figures": False, "save_map": False}, "closure": {"keyframe_spacing_m": 5.0}}
    )
    metrics = Pipeline(demo, config, odometry=replay).run(None).metrics
    quality, errors = metrics["closure_quality"], metrics["errors"]
    assert metrics["keyframes"] <= 0.6 * metrics["vertices"], (metrics["keyframes"], metrics["vertices"])
    assert quality["closures"] >= 3 and quality["false_closures"] == 0, quality
    assert errors["corrected"]["ate_2d_m"] < 0.5 * errors["vo"]["ate_2d_m"], errors
