"""A stereo pair given the wrong way round, not rectified, or one image given as both is named as such (`hippo_nav.vo.odometry` module
doc, 7): either leaves the odometry without a single depth, which looked like a textureless scene on every
frame ("dark, blurred or covered images?") although the images are fine."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from conftest import QUIET, Frames
from hippo_nav.datasets import KittiOdometry, StereoFrame
from hippo_nav.pipeline import Pipeline, config_from_dict
from hippo_nav.vo import StereoOdometry, VoParams


def _run(dataset, transform, n: int = 8) -> tuple[StereoOdometry, list[str]]:
    """The VO over the first `n` frames, each pair passed through `transform(left, right)`."""
    vo = StereoOdometry(dataset.calibration, VoParams())
    statuses = []
    for i in range(n):
        frame = dataset[i]
        left, right = transform(frame.left, frame.right)
        statuses.append(vo.process(StereoFrame(frame.index, frame.timestamp_s, left, right)).status)
    return vo, statuses


def _as_given(left, right):
    return left, right


def test_a_consistent_pair_is_not_called_faulty(demo):
    vo, statuses = _run(demo, _as_given)
    assert vo.stereo_fault is None
    assert statuses[1:] == ["ok"] * 7
    assert not any("swapped" in w or "rectified" in w for w in vo.warnings)


def test_swapped_images_are_named_with_what_to_do(demo, caplog):
    with caplog.at_level(logging.WARNING, logger="hippo_nav.vo"):
        vo, statuses = _run(demo, lambda left, right: (right, left))
    assert vo.stereo_fault == "swapped"
    # The pair gives no depth: without the verdict these frames read as a textureless scene.
    assert statuses[1:] == ["low_texture"] * 7
    (message,) = [w for w in vo.warnings if "swapped" in w]
    assert "image_0" in message and "negative disparity" in message
    assert sum("look swapped" in r.getMessage() for r in caplog.records) == 1  # said once


@pytest.mark.parametrize(("rows", "side"), [(5, "lower"), (-5, "higher")])
def test_an_unrectified_pair_is_named_with_its_row_offset(demo, rows, side):
    vo, statuses = _run(demo, lambda left, right: (left, np.roll(right, rows, axis=0)))
    assert vo.stereo_fault == "unrectified"
    assert statuses[1:] == ["low_texture"] * 7
    (message,) = [w for w in vo.warnings if "rectified" in w]
    assert f"px {side} than in the left image" in message
    median_px = float(message.split("a median ")[1].split(" px")[0])
    assert abs(median_px - 5) < 0.6


def test_one_image_given_as_both_is_named(demo):
    vo, statuses = _run(demo, lambda left, right: (left, left.copy()))
    assert vo.stereo_fault == "identical"
    assert statuses[1:] == ["low_texture"] * 7
    (message,) = [w for w in vo.warnings if "identical" in w]
    assert "image_1" in message


def test_a_pair_one_row_off_still_runs_and_is_not_called_unrectified(demo):
    # Within the row tolerance (1.5 px) the odometry still finds its depths: no verdict.
    vo, statuses = _run(demo, lambda left, right: (left, np.roll(right, 1, axis=0)))
    assert vo.stereo_fault is None
    assert statuses.count("ok") >= 6


@pytest.mark.data
@pytest.mark.parametrize("sequence", ["06", "01"])
def test_real_kitti_pairs_are_not_called_faulty(shared_data, sequence):
    vo, statuses = _run(KittiOdometry(shared_data / "kitti_odometry", sequence, 0, 12), _as_given, 12)
    assert vo.stereo_fault is None
    assert statuses.count("ok") == 11


def test_a_run_on_a_swapped_pair_says_so_at_its_end(demo, tmp_path, caplog):
    class Swapped(Frames):
        def __getitem__(self, i):
            frame = super().__getitem__(i)
            return StereoFrame(frame.index, frame.timestamp_s, frame.right, frame.left)

    with caplog.at_level(logging.WARNING):
        result = Pipeline(Swapped(demo, 12), config_from_dict(QUIET)).run(tmp_path / "out")
    assert result.metrics["data"]["stereo_fault"] == "swapped"
    (summary,) = [r.getMessage() for r in caplog.records if "of 12 frames" in r.getMessage()]
    assert "the stereo pair looks swapped" in summary and "dark, blurred" not in summary
