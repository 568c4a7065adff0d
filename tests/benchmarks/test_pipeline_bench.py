"""Whole-pipeline speed (`make bench`; skipped by the default test run).

One round = every frame of a sequence through VO, view cells, the spatial-memory network (default sizes)
and the experience map, images read from disk included. The measure that matters is frames per second
against the camera's 10 Hz. A baseline runs in the same rounds, interleaved with the measured pipeline so
that both see the same machine load: the pipeline as it was before the speed work, reproduced through its
config (every stage one after another on one thread, the VO detecting and stereo-matching every corner
anew, `test_vo_bench.PREVIOUS_VO`, ORB keyframes). `extra_info` holds both frame rates, their ratio (`speedup` > 1: the
current pipeline is faster), every thread's CPU a frame and its ratio (`cpu_ratio` < 1: less than the
baseline's), the time per stage and each stage's share of a frame, and the 10 Hz camera
period as a ratio (`camera_period_ratio` < 1 means faster than real time). The view-cell benchmark takes the
other view descriptor as its baseline instead. Real KITTI frames (1241×376,
sequence 06, 51 stereo pairs) when ../shared/data is present, the synthetic demo (320×96) always.
"""

from __future__ import annotations

import pytest
from hippo_nav.closure import DEFAULT_PROPOSERS
from hippo_nav.datasets import KittiOdometry
from hippo_nav.pipeline import Pipeline, config_from_dict
from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence
from test_vo_bench import PREVIOUS_VO

CAMERA_PERIOD_S = 0.1
OUTPUT = {"figures": False, "save_map": False}


# ORB keyframes, as every keyframe was before SIFT became the default: the baseline stays the same pipeline.
PREVIOUS = {
    "overlap_front_end": False,
    "vo": PREVIOUS_VO.model_dump(),
    "closure": {"descriptor": "orb"},
}


def _bench(benchmark, dataset, current_sections=None, previous_sections=PREVIOUS) -> None:
    current = config_from_dict({"output": OUTPUT, **(current_sections or {})})
    previous = config_from_dict({"output": OUTPUT, **previous_sections})
    timings: dict[str, list[dict]] = {"current": [], "previous": []}

    def baseline():
        timings["previous"].append(Pipeline(dataset, previous).run(None).metrics["timing"])

    def one_run():
        timings["current"].append(Pipeline(dataset, current).run(None).metrics["timing"])

    benchmark.pedantic(one_run, setup=baseline, rounds=2, iterations=1, warmup_rounds=0)
    best = {name: max(runs, key=lambda t: t["frames_per_s"]) for name, runs in timings.items()}
    info = benchmark.extra_info
    info["frames"] = best["current"]["frames"]
    info["frames_per_s"] = best["current"]["frames_per_s"]
    info["frames_per_s_previous"] = best["previous"]["frames_per_s"]
    info["speedup"] = info["frames_per_s"] / info["frames_per_s_previous"]
    info["camera_period_ratio"] = 1.0 / (info["frames_per_s"] * CAMERA_PERIOD_S)
    info["per_frame_ms"] = best["current"]["per_frame_ms"]
    info["share_of_frame"] = best["current"]["share_of_frame"]
    info["per_frame_ms_previous"] = best["previous"]["per_frame_ms"]
    # Every thread's CPU a frame, the least of the rounds: what a frame costs the machine (`cpu_ratio` < 1: less
    # than the baseline's).
    cpu = {name: min(t["cpu_ms_per_frame"] for t in runs) for name, runs in timings.items()}
    info["cpu_ms_per_frame"], info["cpu_ms_per_frame_previous"] = cpu["current"], cpu["previous"]
    info["cpu_ratio"] = cpu["current"] / cpu["previous"]
    print(
        f"\n{dataset.name}: {info['frames_per_s']:.1f} frames/s (baseline "
        f"{info['frames_per_s_previous']:.1f}, speed-up {info['speedup']:.2f}×; CPU a frame "
        f"{info['cpu_ms_per_frame']:.0f} ms, {info['cpu_ratio']:.2f}× the baseline's); "
        f"ms per frame: {info['per_frame_ms']}"
    )


def test_pipeline_demo_sequence(benchmark):
    benchmark.group = "pipeline"
    demo = KittiOdometry(demo_sequence(), DEMO_SEQUENCE)
    demo.name = "synthetic demo loop"
    _bench(benchmark, demo)


@pytest.mark.data
def test_pipeline_real_kitti_06(benchmark, shared_data):
    benchmark.group = "pipeline"
    data = KittiOdometry(shared_data / "kitti_odometry", "06")
    data.name = "KITTI 06 frames 0-50"
    _bench(benchmark, data)


@pytest.mark.data
@pytest.mark.parametrize("view_cells", ["template", "words"])
def test_pipeline_real_kitti_06_by_view_cells(benchmark, shared_data, view_cells):
    """The current pipeline with each view descriptor, against the other one in the same rounds (the
    baseline here is the other descriptor, not the previous pipeline): what the word view cells cost."""
    benchmark.group = "pipeline by view cells"
    other = "words" if view_cells == "template" else "template"
    data = KittiOdometry(shared_data / "kitti_odometry", "06")
    data.name = f"KITTI 06 frames 0-50, {view_cells} view cells (baseline: {other})"
    _bench(benchmark, data, {"parts": {"view_cells": view_cells}}, {"parts": {"view_cells": other}})


@pytest.mark.data
def test_pipeline_real_kitti_06_windowed_vo(benchmark, shared_data):
    """The current pipeline (the VO refined over a window of keyframes) against the same pipeline with the
    frame-to-frame VO alone, in the same rounds: what the windowed refinement costs the whole system."""
    benchmark.group = "pipeline by VO"
    data = KittiOdometry(shared_data / "kitti_odometry", "06")
    data.name = "KITTI 06 frames 0-50, windowed VO (baseline: frame to frame)"
    _bench(benchmark, data, {}, {"vo": {"window": {"max_keyframes": 0}}})


@pytest.mark.data
def test_pipeline_real_kitti_06_disparity_self_calibration(benchmark, shared_data):
    """The current pipeline (the VO estimating its disparity offset on every tracked frame) against the
    same pipeline with the offset fixed, in the same rounds: what the self-calibration costs the system."""
    benchmark.group = "pipeline by VO"
    data = KittiOdometry(shared_data / "kitti_odometry", "06")
    data.name = "KITTI 06 frames 0-50, disparity self-calibration (baseline: offset fixed)"
    _bench(benchmark, data, {}, {"vo": {"disparity_self_calibration": False}})


@pytest.mark.data
def test_pipeline_real_kitti_06_refined_matches(benchmark, shared_data):
    """The current pipeline (every KLT match refined with a warped window, `vo.refine_matches`) against the
    same pipeline on KLT's matches as they are, in the same rounds: what the refinement costs the system."""
    benchmark.group = "pipeline by VO"
    data = KittiOdometry(shared_data / "kitti_odometry", "06")
    data.name = "KITTI 06 frames 0-50, refined matches (baseline: KLT's)"
    _bench(benchmark, data, {}, {"vo": {"refine_matches": False}})


@pytest.mark.data
def test_pipeline_real_kitti_06_sift_keyframes(benchmark, shared_data):
    """The current pipeline (SIFT keyframes, `closure.descriptor`) against the same pipeline with ORB
    keyframes, in the same rounds: what describing every new vertex's keyframe by SIFT costs the system."""
    benchmark.group = "pipeline by keyframe descriptor"
    data = KittiOdometry(shared_data / "kitti_odometry", "06")
    data.name = "KITTI 06 frames 0-50, SIFT keyframes (baseline: ORB)"
    _bench(benchmark, data, {"closure": {"descriptor": "sift"}}, {"closure": {"descriptor": "orb"}})


def test_pipeline_birdseye_out_and_back(benchmark):
    """Bird's-eye closures on (`closure.birdseye`) against the same pipeline without them, in the same
    rounds, on the rendered out-and-back street of `tests/closure/test_birdseye.py` (a street driven there and
    back, with posts): what the bird's-eye search costs where the map has old places to search."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(
        "test_birdseye", Path(__file__).parents[1] / "closure" / "test_birdseye.py"
    )
    assert spec is not None and spec.loader is not None
    route = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(route)
    benchmark.group = "pipeline with bird's-eye closures"
    data = route.out_and_back_street()
    data.name = "out-and-back street with posts, bird's-eye closures (baseline: off)"
    on = {"parts": {"closure": [*DEFAULT_PROPOSERS, "birdseye"]}}
    _bench(benchmark, data, on, {"parts": {"closure": list(DEFAULT_PROPOSERS)}})
