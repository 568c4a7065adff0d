"""Decoding a KITTI-size gray PNG frame (1241 × 376, smooth structure and camera-like noise): OpenCV's libpng
(what every frame cost before) against the `png` crate (`_core.decode_png`, what `decode_image_bytes` uses for
8-bit PNGs now), group `png_decoding`; both give the same pixels (checked before timing). In the pipeline:
docs/results.md, "Cost"."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hippo_nav import _core


@pytest.fixture(scope="module")
def kitti_size_png() -> bytes:
    rng = np.random.default_rng(3)
    rows, cols = 376, 1241
    scene = cv2.GaussianBlur(rng.normal(128, 60, (rows // 8, cols // 8)), (0, 0), 1.5)
    image = cv2.resize(scene, (cols, rows), interpolation=cv2.INTER_CUBIC) + rng.normal(0, 3, (rows, cols))
    return cv2.imencode(".png", np.clip(image, 0, 255).astype(np.uint8))[1].tobytes()


@pytest.mark.parametrize("how", ["opencv", "png_crate"])
def test_png_decoding(benchmark, kitti_size_png: bytes, how: str) -> None:
    def opencv() -> np.ndarray:
        return cv2.imdecode(np.frombuffer(kitti_size_png, np.uint8), cv2.IMREAD_UNCHANGED)

    ours = _core.decode_png(kitti_size_png)
    assert ours is not None and np.array_equal(ours, opencv())
    benchmark.group = "png_decoding"
    if how == "opencv":
        benchmark(opencv)
    else:
        benchmark(_core.decode_png, kitti_size_png)
