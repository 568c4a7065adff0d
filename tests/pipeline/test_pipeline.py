"""The whole pipeline: conventions, config, robustness, and the loop closure on a synthetic KITTI loop."""

from __future__ import annotations

import json
import logging
import os
import threading

import numpy as np
import pytest
from conftest import QUIET, Frames
from hippo_nav import HippoNavError
from hippo_nav.datasets import KittiOdometry
from hippo_nav.io import read_kitti_poses, read_tum
from hippo_nav.pipeline import (
    Pipeline,
    PipelineConfig,
    config_from_dict,
    load_config,
    write_config,
)
from hippo_nav.synthetic import (
    default_cache_dir,
    kitti_trajectory,
    render_cached,
    scale_trajectory,
)
from hippo_nav.vo import StereoOdometry, VoParams

# A real KITTI loop shape: sequence 05, frames 700–1600 (a 560 m block driven once, then ~50 m of it
# again), every 4th frame, scaled by 0.35 so that a 10 Hz rendering moves ≤ 1.6 m and turns ≤ 2.1 rad/s
# per second — 225 frames, 234 m. The revisit starts at frame 730 + the loop, i.e. position ≈ 186.
LOOP_SEQUENCE = ("05", 700, 1600, 4, 0.35)
REVISIT_FROM = 180


@pytest.fixture(scope="module")
def kitti_loop(shared_data) -> KittiOdometry:
    """The synthetic stereo loop along KITTI 05's ground truth (rendered once, then cached)."""
    sequence, start, stop, stride, scale = LOOP_SEQUENCE
    pose_file = shared_data / "kitti_odometry" / "poses" / f"{sequence}.txt"
    poses = scale_trajectory(kitti_trajectory(pose_file, start, stop, stride), scale)
    root = render_cached(poses, default_cache_dir() / "test_loop05", sequence, seed=0)
    return KittiOdometry(root, sequence)


def test_config_round_trips_and_names_bad_fields(tmp_path):
    config = config_from_dict({"seed": 3, "lesions": {"dorsal": True}, "injection": {"initial_strength": 2}})
    path = write_config(config, tmp_path / "c.json")
    again = load_config(path)
    assert again == config
    assert again.engine_config().lesioned == [False, False, True]
    assert json.loads(path.read_text())["engine"]["torus_period_m"] == config.engine.torus_period_m
    with pytest.raises(HippoNavError, match=r"injection\.decay_per_frame"):
        config_from_dict({"injection": {"decay_per_frame": 2.0}})
    with pytest.raises(HippoNavError, match="lesions.hippocampus"):
        config_from_dict({"lesions": {"hippocampus": True}})
    (tmp_path / "broken.json").write_text('{"seed": 1,\n "map": }')
    with pytest.raises(HippoNavError, match=r"broken\.json:2"):
        load_config(tmp_path / "broken.json")
    assert PipelineConfig().with_lesions("ventral", "dorsal").engine_config().lesioned == [True, False, True]


def test_a_short_run_is_deterministic_and_writes_every_result(demo, tmp_path):
    """Two runs give the same results, the second with the front end on the calling thread: running the
    odometry frames ahead (the default) changes nothing but the speed."""
    data = Frames(demo, 25)
    config = config_from_dict(QUIET)
    overlapped = Pipeline(data, config)
    measure = overlapped.odometry.process
    vo_threads: set[int] = set()

    def process(frame):
        vo_threads.add(threading.get_ident())
        return measure(frame)

    overlapped.odometry.process = process  # type: ignore[method-assign]
    # The odometry's worker is a frame's critical path: the views are described on the loader and a new
    # vertex's keyframe is extracted on a thread of its own, neither on the odometry's nor the calling one.
    work_threads: dict[str, set[int]] = {"describe": set(), "keyframe": set()}

    def on_thread(name, work):
        def run(*args):
            work_threads[name].add(threading.get_ident())
            return work(*args)

        return run

    view_cells, closure = overlapped.system.view_cells, overlapped.system.closure
    assert view_cells.describe_on_worker
    view_cells.describe = on_thread("describe", view_cells.describe)  # type: ignore[method-assign]
    closure.store.extract = on_thread("keyframe", closure.store.extract)  # type: ignore[method-assign,union-attr]
    first = overlapped.run(tmp_path / "a")
    sequential = config.model_copy(update={"overlap_front_end": False})
    # Frames are loaded ahead on one thread of their own, beside the odometry's: each once, in order (a bag
    # reader need not be thread-safe), never on the calling thread.
    assert [i for i, _ in data.reads] == list(range(25))
    readers = {thread for _, thread in data.reads}
    assert len(readers) == 1 and threading.get_ident() not in readers
    assert len(vo_threads) == 1 and not vo_threads & (readers | {threading.get_ident()})
    assert work_threads["describe"] == readers
    keyframe_threads = work_threads["keyframe"]
    assert len(keyframe_threads) == 1 and not keyframe_threads & (
        vo_threads | readers | {threading.get_ident()}
    )
    data.reads.clear()
    second = Pipeline(data, sequential).run(tmp_path / "b")
    np.testing.assert_array_equal(first.corrected_world_from_camera, second.corrected_world_from_camera)
    np.testing.assert_array_equal(first.vo_world_from_camera, second.vo_world_from_camera)
    np.testing.assert_array_equal(first.neural_world_from_camera, second.neural_world_from_camera)
    assert first.record.view_cell == second.record.view_cell
    assert first.record.column("vo_status") == second.record.column("vo_status")
    out = tmp_path / "a"
    for name in ("vo", "online", "corrected", "neural"):
        assert read_kitti_poses(out / f"trajectory_{name}.kitti.txt").shape == (25, 4, 4)
        times, _ = read_tum(out / f"trajectory_{name}.tum.txt")
        np.testing.assert_allclose(times, data.timestamps_s, atol=1e-6)
    resolved = json.loads((out / "config.json").read_text())
    assert {"engine", "vo", "views", "injection", "map", "lesions"} <= resolved.keys()
    assert load_config(out / "config.json") == config.model_validate(resolved)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == 25 and not metrics["interrupted"]
    stages = {"load", "vo", "views", "engine", "closure", "map", "record"}
    assert set(metrics["timing"]["per_frame_ms"]) == set(metrics["timing"]["share_of_frame"]) == stages
    assert metrics["timing"]["frames_per_s"] > 0 and metrics["timing"]["frames_per_s_sequential"] > 0
    # Every thread's CPU over the loop: some, and not more than the machine's cores could give in its wall time.
    timing = metrics["timing"]
    assert timing["cpu_ms_per_frame"] > 0 and 0 < timing["cores_busy"] <= (os.cpu_count() or 1) + 0.5
    assert (out / "bump_table.csv").read_text().count("\n") > 5
    assert (out / "map.bin").stat().st_size > 0 and (out / "frames.csv").read_text().count("\n") == 26


def _interrupt_at_12(i: int) -> None:
    if i == 12:
        raise KeyboardInterrupt


def test_interrupt_keeps_the_frames_processed(demo, quiet, tmp_path):
    result = Pipeline(Frames(demo, 40, on_load=_interrupt_at_12), quiet).run(tmp_path)
    assert result.interrupted and result.metrics["frames"] == 12
    assert read_kitti_poses(tmp_path / "trajectory_corrected.kitti.txt").shape == (12, 4, 4)
    assert json.loads((tmp_path / "metrics.json").read_text())["interrupted"] is True


class _FailingOdometry:
    """Wraps a VO: raises on chosen frames, or reports an absurd 1 km step."""

    def __init__(self, inner, fail: set[int], absurd: set[int]):
        self.inner, self.fail, self.absurd, self.i = inner, fail, absurd, 0

    def process(self, frame):
        i, self.i = self.i, self.i + 1
        step = self.inner.process(frame)
        if i in self.fail:
            raise HippoNavError("no features")
        if i in self.absurd:
            jump = np.eye(4)
            jump[2, 3] = 1000.0
            return type("Step", (), {"camera_prev_from_camera_cur": jump, "status": "ok"})()
        return step


def test_vo_failures_and_absurd_motion_are_flagged_not_fatal(demo, caplog):
    data = Frames(demo, 20)
    odometry = _FailingOdometry(
        StereoOdometry(data.calibration, VoParams()), fail={6, 7}, absurd={12, 14, 15}
    )
    with caplog.at_level("WARNING", logger="hippo_nav"):
        result = Pipeline(data, odometry=odometry).run(None)
    # Absurd motion is said, once for each stretch of clamped frames (12; 14-15), naming its speed.
    said = [r.getMessage() for r in caplog.records if "beyond the networks' limits" in r.getMessage()]
    assert len(said) == 2 and all("check the odometry" in line for line in said), said
    record = result.record
    assert len(record) == 20
    assert record.vo_status[6] == record.vo_status[7] == "failed"
    # The prior is the last good step: the failed frames repeat frame 5's motion.
    assert record.speed_m_s[6] == pytest.approx(record.speed_m_s[5], rel=1e-4)
    assert record.motion_flag[12] == "clamped" and abs(record.speed_m_s[12]) <= 35.0
    assert np.isfinite(result.corrected_world_from_camera).all()


class _DriftingOdometry:
    """A VO with the drift of a real one: its steps 2 % too long and turned 0.1° per frame to the left.

    The stereo VO on clean synthetic images drifts far less (≈ 0.2 m ATE over this 234 m loop) than any
    VO on real images, so to show what the loop closure corrects, the test gives it a realistic drift."""

    def __init__(self, inner, yaw_bias_rad: float = np.radians(0.1), scale: float = 1.02):
        self.inner, self.yaw_bias_rad, self.scale = inner, yaw_bias_rad, scale

    def process(self, frame):
        import cv2

        step = self.inner.process(frame)
        t = step.camera_prev_from_camera_cur.copy()
        if step.status != "first":
            t[:3, :3] = t[:3, :3] @ cv2.Rodrigues(np.array([0.0, -self.yaw_bias_rad, 0.0]))[0]
            t[:3, 3] *= self.scale
        return type("Step", (), {"camera_prev_from_camera_cur": t, "status": step.status})()


@pytest.mark.slow
def test_synthetic_kitti_loop_is_closed_and_correction_beats_the_vo(kitti_loop, tmp_path):
    # The stereo VO as it is: the revisit closes the loop, the figures are written, and the corrected
    # map stays within the map's resolution of the truth.
    result = Pipeline(kitti_loop, PipelineConfig()).run(tmp_path)
    closures = np.array(result.metrics["loop_closure_frames"])
    assert (closures >= REVISIT_FROM).any(), closures
    assert result.map_export["link_is_loop"].any()
    assert result.metrics["errors"]["corrected"]["ate_2d_m"] < 2.0
    for name in ("cognitive_map.png", "rate_maps.png"):
        assert (tmp_path / name).stat().st_size > 10_000, name
    assert len(list(tmp_path.glob("neural_state_*.png"))) >= 2

    # With a real VO's drift the closure must pull the map back: the corrected map beats the VO.
    odometry = _DriftingOdometry(StereoOdometry(kitti_loop.calibration, VoParams()))
    config = config_from_dict(QUIET)
    drifted = Pipeline(kitti_loop, config, odometry=odometry).run(None)
    closures = np.array(drifted.metrics["loop_closure_frames"])
    assert (closures >= REVISIT_FROM).any(), closures
    errors = drifted.metrics["errors"]
    assert errors["vo"]["ate_2d_m"] > 3.0  # the drift is real
    assert errors["corrected"]["ate_2d_m"] < 0.5 * errors["vo"]["ate_2d_m"]
    assert errors["corrected"]["ate_3d_m"] < 0.5 * errors["vo"]["ate_3d_m"]


@pytest.mark.slow
@pytest.mark.data
def test_real_kitti_frames_run_and_write_metrics_and_figures(shared_data, tmp_path):
    data = KittiOdometry(shared_data / "kitti_odometry", "06")
    result = Pipeline(data, PipelineConfig()).run(tmp_path)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["frames"] == len(data) == 51
    assert metrics["errors"]["vo"]["ate_3d_m"] is not None
    assert metrics["vo_status_counts"].get("ok", 0) >= 45
    assert result.metrics["distance_gt_m"] > 10
    for name in metrics["figures"]:
        assert (tmp_path / name).stat().st_size > 10_000, name
    assert "cognitive_map.png" in metrics["figures"] and "rate_maps.png" in metrics["figures"]


def test_a_run_with_every_grid_module_lesioned_says_the_neural_estimate_cannot_move(demo, caplog):
    """Inactivating the whole MEC is an experiment a lab can run, but its neural trajectory stays at the start
    (the place cells get no grid input): the run says so up front rather than exiting 0 with a flat line."""
    every = config_from_dict({"lesions": {"ventral": True, "intermediate": True, "dorsal": True}})
    with caplog.at_level(logging.WARNING, logger="hippo_nav.pipeline"):
        Pipeline(Frames(demo, 3), every)
    assert "every grid module is lesioned" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="hippo_nav.pipeline"):
        Pipeline(Frames(demo, 3), config_from_dict({"lesions": {"ventral": True, "intermediate": True}}))
    assert "lesioned" not in caplog.text
