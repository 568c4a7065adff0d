"""Vocabulary files written and read: `hippo-nav vocabulary --out` keeps an existing file unless told
`--overwrite` (and never writes through a link), and a damaged vocabulary file (truncated, bit-flipped,
another format, empty, huge, a folder) is one `HippoNavError` naming the file, never a traceback or a panic."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hippo_nav._core import HippoNavError
from hippo_nav.cli import main
from hippo_nav.io.errors import MAX_DATA_FILE_BYTES
from hippo_nav.view_cells.words import _DEFAULT_VOCABULARY, Vocabulary, WordViewCells, WordViewConfig
from hypothesis import given, settings
from hypothesis import strategies as st

SHIPPED = _DEFAULT_VOCABULARY.read_bytes()


@pytest.fixture
def images(tmp_path) -> Path:
    """Three textured images (smoothed noise: ORB finds hundreds of corners in each)."""
    import cv2

    folder = tmp_path / "images"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        image = cv2.GaussianBlur(rng.integers(0, 256, (120, 160), dtype=np.uint8), (3, 3), 0)
        ok, png = cv2.imencode(".png", image)
        assert ok
        (folder / f"{i}.png").write_bytes(png.tobytes())
    return folder


def _train(out: Path, images: Path, *extra: str) -> int:
    return main(["vocabulary", "--out", str(out), "--images", str(images), "--branching", "2", "--levels", "2",
                 *extra])  # fmt: skip


def _one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hippo-nav: error:"), err
    assert "Traceback" not in err and "[Errno" not in err, err
    return lines[0]


def test_an_existing_out_file_is_kept_unless_overwrite_is_given(tmp_path, images, capsys):
    out = tmp_path / "mine.voc"
    out.write_bytes(b"my precious vocabulary")
    assert _train(out, images) == 2
    line = _one_line_error(capsys)
    assert str(out) in line and "--overwrite" in line
    assert out.read_bytes() == b"my precious vocabulary"
    assert _train(out, images, "--overwrite") == 0
    assert Vocabulary.load(out).branching == 2
    capsys.readouterr()
    assert main(["vocabulary", "--help"]) == 0
    assert "--overwrite" in capsys.readouterr().out


def test_a_link_at_out_is_replaced_not_written_through_and_a_folder_is_refused(tmp_path, images, capsys):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n", encoding="utf-8")
    out = tmp_path / "linked.voc"
    out.symlink_to(victim)
    assert _train(out, images) == 2  # a link is an existing name: kept without --overwrite
    assert "--overwrite" in _one_line_error(capsys)
    assert _train(out, images, "--overwrite") == 0
    assert victim.read_text(encoding="utf-8") == "precious\n" and not out.is_symlink()
    folder = tmp_path / "a_folder"
    folder.mkdir()
    assert _train(folder, images, "--overwrite") == 2
    assert "a folder" in _one_line_error(capsys)


def _refused(path: Path) -> str:
    with pytest.raises(HippoNavError) as caught:
        Vocabulary.load(path)
    message = str(caught.value)
    assert message.startswith(f"{path}:") and "\n" not in message, message
    return message


def test_damaged_vocabulary_files_are_one_error_naming_the_file(tmp_path):
    cases = {
        "empty.voc": b"",
        "truncated.voc": SHIPPED[: len(SHIPPED) // 3],
        "header_only.voc": SHIPPED[:60],
        "flipped.voc": SHIPPED[:1000] + bytes([SHIPPED[1000] ^ 0x10]) + SHIPPED[1001:],
        "json.voc": json.dumps({"words": [1, 2, 3]}).encode(),
        "png.voc": b"\x89PNG\r\n\x1a\n" + bytes(200),
        "zeros.voc": bytes(4096),
    }
    for name, data in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        _refused(path)
    huge = tmp_path / "huge.voc"
    with huge.open("wb") as f:  # sparse: no disk is used, and it is refused before it is read
        f.truncate(MAX_DATA_FILE_BYTES + 1)
    assert "MiB" in _refused(huge)
    folder = tmp_path / "folder.voc"
    folder.mkdir()
    assert "not a vocabulary file (a folder" in _refused(folder)


def test_a_damaged_vocabulary_in_the_config_is_one_error_naming_it(tmp_path):
    from hippo_nav.datasets.base import StereoCalibration
    from hippo_nav.synthetic import stereo_projections
    from hippo_nav.synthetic.render import KITTI_FOCAL_RATIO

    p0, p1 = stereo_projections((320, 96), 0.537, KITTI_FOCAL_RATIO)
    calibration = StereoCalibration(p0, p1, None, None, (320, 96))
    for path in (tmp_path / "cut.voc", tmp_path / "a_folder"):
        if path.suffix:
            path.write_bytes(SHIPPED[:-10])
        else:
            path.mkdir()
        what = "truncated" if path.suffix else "not a vocabulary file"
        with pytest.raises(HippoNavError, match=f"^{path}: .*{what}"):
            WordViewCells.for_camera(WordViewConfig(vocabulary=path), calibration)


@settings(max_examples=60, deadline=None)
@given(
    cut=st.integers(0, len(SHIPPED)),
    flips=st.lists(st.tuples(st.integers(0, len(SHIPPED) - 1), st.integers(1, 255)), max_size=4),
)
def test_truncated_or_bit_flipped_vocabularies_are_refused_with_the_file_named(cut, flips):
    data = bytearray(SHIPPED[:cut])
    for at, mask in flips:
        if at < len(data):
            data[at] ^= mask
    fd, name = tempfile.mkstemp(suffix=".voc")
    try:
        os.write(fd, bytes(data))
        os.close(fd)
        try:
            loaded = Vocabulary.load(name)
        except HippoNavError as err:
            assert str(err).startswith(f"{name}: ") and "\n" not in str(err), err
        else:  # only a change the format does not see (e.g. a hex digit's case in the header) loads
            assert bytes(loaded._native.to_bytes()) == SHIPPED
    finally:
        os.unlink(name)
