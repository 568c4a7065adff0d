"""Whole-pipeline speed (`make bench`; skipped by the default test run).

One round = every frame of a sequence through VO, view cells, the spatial-memory network (default sizes)
and the experience map, images read from disk included. The measure that matters is frames per second
against the camera's 10 Hz; `extra_info` holds the frame rate and the time split per stage (ms per
frame) of the last round, and the 10 Hz camera period as the baseline ratio (`camera_period_ratio` < 1
means faster than real time). Real KITTI frames (1241×376, sequence 06, 51 stereo pairs) when
../shared/data is present, the synthetic demo (320×96) always.
"""

from __future__ import annotations

import pytest
from hippo_nav.datasets import KittiOdometry
from hippo_nav.pipeline import Pipeline, config_from_dict
from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence

CAMERA_PERIOD_S = 0.1


def _bench(benchmark, dataset) -> None:
    config = config_from_dict({"output": {"figures": False, "save_map": False}})
    results = []

    def one_run():
        results.append(Pipeline(dataset, config).run(None))

    benchmark.pedantic(one_run, rounds=2, iterations=1, warmup_rounds=0)
    timing = results[-1].metrics["timing"]
    benchmark.extra_info["frames"] = timing["frames"]
    benchmark.extra_info["frames_per_s"] = timing["frames_per_s"]
    benchmark.extra_info["camera_period_ratio"] = 1.0 / (timing["frames_per_s"] * CAMERA_PERIOD_S)
    benchmark.extra_info["per_frame_ms"] = timing["per_frame_ms"]
    print(f"\n{dataset.name}: {timing['frames_per_s']:.1f} frames/s; ms per frame: {timing['per_frame_ms']}")


def test_pipeline_demo_sequence(benchmark):
    benchmark.group = "pipeline"
    demo = KittiOdometry(demo_sequence(), DEMO_SEQUENCE)
    demo.name = "synthetic demo loop"
    _bench(benchmark, demo)


@pytest.mark.data
def test_pipeline_real_kitti_06(benchmark, shared_data):
    benchmark.group = "pipeline"
    _bench(benchmark, KittiOdometry(shared_data / "kitti_odometry", "06"))
