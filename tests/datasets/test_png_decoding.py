"""PNG frames decoded by the `png` crate (`_core.decode_png`, used by `decode_image_bytes`) are OpenCV's pixels:
for every kind it takes, byte for byte what `cv2.imdecode(IMREAD_UNCHANGED)` gives; every other kind, and every
damaged file, is left to OpenCV (None), so what a user sees for a bad frame does not change. Its speed:
docs/results.md, "Cost"."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hippo_nav._core import decode_png
from hippo_nav.datasets.common import decode_image_bytes
from hypothesis import given, settings
from hypothesis import strategies as st


def _image(shape: tuple[int, ...], dtype: type = np.uint8, seed: int = 0) -> np.ndarray:
    """Smooth structure and noise: every PNG filter type gets used."""
    rng = np.random.default_rng(seed)
    top = 255 if dtype == np.uint8 else 65535
    rows, cols = shape[:2]
    ramp = np.add.outer(np.arange(rows) * 3, np.arange(cols) * 2) % top
    image = ramp.reshape(rows, cols, *([1] * (len(shape) - 2))) + rng.integers(0, 40, shape)
    return np.clip(image, 0, top).astype(dtype)


def _png(image: np.ndarray, *params: int) -> bytes:
    ok, encoded = cv2.imencode(".png", image, list(params))
    assert ok
    return encoded.tobytes()


def _opencv(data: bytes) -> np.ndarray | None:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)


def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)


@pytest.mark.parametrize("shape", [(96, 320), (37, 53, 3), (20, 31, 4), (1, 1), (376, 1241)])
@pytest.mark.parametrize(
    "params",
    [
        (),
        (cv2.IMWRITE_PNG_COMPRESSION, 0),
        (cv2.IMWRITE_PNG_COMPRESSION, 9),
        (cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY),
        (cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE),
    ],
)
def test_eight_bit_gray_and_colour_pngs_decode_to_opencvs_pixels(shape, params) -> None:
    data = _png(_image(shape, seed=len(params)), *params)
    ours = decode_png(data)
    assert ours is not None, "an 8-bit gray or colour PNG is decoded here"
    assert _same(ours, _opencv(data))  # gray (rows, columns); colour in OpenCV's BGR(A) order
    assert _same(decode_image_bytes(data, "frame.png"), _opencv(data))


def test_other_kinds_are_left_to_opencv() -> None:
    sixteen = _png(_image((30, 40), np.uint16))
    assert decode_png(sixteen) is None  # 16-bit: OpenCV decodes it
    assert _same(decode_image_bytes(sixteen, "depth.png"), _opencv(sixteen))
    jpeg = cv2.imencode(".jpg", _image((30, 40)))[1].tobytes()
    assert decode_png(jpeg) is None
    gray = _png(_image((30, 40)))
    # Read as gray on request (not as stored): OpenCV's conversion, not this decoder.
    assert _same(
        decode_image_bytes(gray, "x.png", cv2.IMREAD_GRAYSCALE),
        cv2.imdecode(np.frombuffer(gray, np.uint8), cv2.IMREAD_GRAYSCALE),
    )


def test_a_png_with_a_transparent_colour_is_left_to_opencv() -> None:
    """A tRNS chunk (one gray level transparent) inserted after IHDR: OpenCV may add alpha; left to it."""
    import struct
    import zlib

    data = _png(_image((8, 8)))
    body = b"tRNS" + struct.pack(">H", 7)
    chunk = struct.pack(">I", 2) + body + struct.pack(">I", zlib.crc32(body))
    with_trns = data[:33] + chunk + data[33:]
    assert decode_png(with_trns) is None
    assert _same(decode_image_bytes(with_trns, "x.png"), _opencv(with_trns))


def test_damaged_pngs_are_left_to_opencv() -> None:
    data = _png(_image((96, 320)))
    truncated = [data[:n] for n in (8, 20, 40, len(data) // 2, len(data) - 12, len(data) - 1)]
    flipped = bytearray(data)
    flipped[len(data) // 2] ^= 0x40  # inside the image data: its CRC no longer matches
    for bad in [*truncated, bytes(flipped)]:
        assert decode_png(bad) is None
        assert _same(decode_image_bytes(bad, "x.png"), _opencv(bad))


@settings(max_examples=150, deadline=None)
@given(
    cut=st.integers(0, 10_000),
    flips=st.lists(st.tuples(st.integers(0, 10_000), st.integers(1, 255)), max_size=3),
    colour=st.booleans(),
)
def test_a_mangled_png_never_decodes_to_other_pixels_than_opencvs(cut, flips, colour) -> None:
    """Cut short and bytes flipped anywhere (headers, checksums, compressed data): this decoder either refuses
    it or gives exactly OpenCV's pixels, never an exception."""
    data = bytearray(_png(_image((24, 33, 3) if colour else (24, 33))))
    for at, mask in flips:
        data[at % len(data)] ^= mask
    mangled = bytes(data[: len(data) - cut % len(data)])
    ours = decode_png(mangled)
    if ours is not None:
        assert _same(ours, _opencv(mangled))


def test_real_kitti_frames_decode_to_opencvs_pixels(shared_data) -> None:
    folder = shared_data / "kitti_odometry" / "sequences" / "06"
    frames = sorted((folder / "image_0").glob("*.png"))[:3] + sorted((folder / "image_1").glob("*.png"))[:3]
    if not frames:
        pytest.skip("no KITTI 06 frames in the shared data")
    for path in frames:
        data = path.read_bytes()
        ours = decode_png(data)
        assert ours is not None and _same(ours, _opencv(data)), path.name
