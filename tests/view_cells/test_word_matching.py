"""The word cells' verification matches descriptors in Rust (`_core.hamming_ratio_matches`): the same matches as
OpenCV's brute-force `knnMatch(k=2)` with Lowe's ratio test, which it replaced, on real features and on
descriptors built to tie; bad input is one clear error."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hippo_nav import HippoNavError, _core


def _opencv(query: np.ndarray, stored: np.ndarray, ratio: float) -> tuple[list[int], list[int]]:
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(query, stored, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < ratio * p[1].distance]
    return [m.queryIdx for m in good], [m.trainIdx for m in good]


def _rust(query: np.ndarray, stored: np.ndarray, ratio: float) -> tuple[list[int], list[int]]:
    q, s = _core.hamming_ratio_matches(query, stored, ratio)
    assert q.dtype == np.int64 and s.dtype == np.int64
    return q.tolist(), s.tolist()


def test_the_same_matches_as_opencv_on_the_demos_features(demo):
    orb = cv2.ORB_create(500)
    described = [orb.detectAndCompute(demo[i].left, None)[1] for i in (0, 3, 60, 140)]
    compared = 0
    for a in described:
        for b in described:
            for ratio in (0.6, 0.8, 1.0):
                expected = _opencv(a, b, ratio)
                assert _rust(a, b, ratio) == expected
                compared += len(expected[0])
    assert compared > 1000  # real matches, not empty lists


def test_ties_and_tiny_stores_match_opencv():
    rng = np.random.default_rng(0)
    # Few distinct descriptors: many queries have two or more stored ones at the same distance.
    palette = rng.integers(0, 256, size=(6, 32), dtype=np.uint8)
    stored = palette[rng.integers(0, 6, size=40)]
    query = palette[rng.integers(0, 6, size=50)] ^ (rng.random((50, 32)) < 0.02).astype(np.uint8)
    for ratio in (0.5, 0.8, 1.0):
        assert _rust(query, stored, ratio) == _opencv(query, stored, ratio)
    for n in (0, 1, 2):  # no second nearest below two stored descriptors
        small = stored[:n].reshape(n, 32)
        assert _rust(query, small, 0.8) == (_opencv(query, small, 0.8) if n else ([], []))


def test_bad_input_is_one_clear_error():
    good = np.zeros((3, 32), np.uint8)
    with pytest.raises(HippoNavError, match="ratio"):
        _core.hamming_ratio_matches(good, good, float("nan"))
    with pytest.raises(HippoNavError, match="ratio"):
        _core.hamming_ratio_matches(good, good, 1.5)
    with pytest.raises(HippoNavError, match="descriptors"):
        _core.hamming_ratio_matches(np.zeros((3, 31), np.uint8), good, 0.8)
