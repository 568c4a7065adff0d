"""Pose files are read at the edge: whatever a KITTI or TUM file holds (extreme or malformed numbers, wrong
field counts, swapped fields, a valid file cut short, random bytes), the readers either return poses or raise
one `DatasetError` line naming the file; never another exception and never a NumPy overflow warning (the
test suite turns warnings into errors)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hippo_nav.cli import main
from hippo_nav.io import DatasetError, read_kitti_poses, read_tum
from hypothesis import given, settings
from hypothesis import strategies as st

SETTINGS = settings(max_examples=80, deadline=None)

KITTI_LINE = "1 0 0 0.5 0 1 0 -0.25 0 0 1 2"
TUM_LINE = "1000.5 0.5 -0.25 2 0 0 0 1"

# Tokens a broken file holds: numbers of every size, NaN/inf spellings, text, separators.
TOKENS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(allow_nan=False, allow_infinity=False, min_value=-2, max_value=2).map(repr),
    st.integers(min_value=-(10**400), max_value=10**400).map(str),
    st.sampled_from(
        ["nan", "-inf", "Infinity", "1e308", "-1e308", "1e-320", "0", "1", "-1", "x", ",", "#", "1_0"]
    ),
    st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=6),
)
LINES = st.lists(st.lists(TOKENS, min_size=0, max_size=14).map(" ".join), max_size=6).map("\n".join)


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("poses")


def _read(reader, path: Path) -> None:
    try:
        reader(path)
    except DatasetError as err:
        message = str(err)
        assert "\n" not in message and message.startswith(str(path)), message
        assert len(message) < 1000, message[:200]


def _write(folder: Path, text: str | bytes) -> Path:
    path = folder / "poses.txt"
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8")
    return path


READERS = st.sampled_from([read_kitti_poses, read_tum])


@given(reader=READERS, text=LINES)
@SETTINGS
def test_any_lines_of_tokens_are_read_or_one_line(folder, reader, text):
    _read(reader, _write(folder, text))


@given(reader=READERS, data=st.binary(max_size=300))
@SETTINGS
def test_random_bytes_are_one_line(folder, reader, data):
    _read(reader, _write(folder, data))


@given(
    reader=READERS,
    lines=st.integers(min_value=1, max_value=4),
    line=st.integers(min_value=0, max_value=3),
    field=st.integers(min_value=0, max_value=11),
    token=TOKENS,
    action=st.sampled_from(["replace", "drop", "insert", "swap", "cut"]),
)
@SETTINGS
def test_a_mutated_valid_file_is_read_or_one_line(folder, reader, lines, line, field, token, action):
    good = KITTI_LINE if reader is read_kitti_poses else TUM_LINE
    rows = [good.split() for _ in range(lines)]
    if reader is read_tum:  # strictly increasing timestamps in the valid file
        for i, row in enumerate(rows):
            row[0] = str(1000 + i)
    row = rows[min(line, lines - 1)]
    field = min(field, len(row) - 1)
    if action == "replace":
        row[field] = token
    elif action == "drop":
        del row[field]
    elif action == "insert":
        row.insert(field, token)
    elif action == "swap":
        row[0], row[field] = row[field], row[0]
    text = "\n".join(" ".join(r) for r in rows) + "\n"
    if action == "cut":
        text = text[: len(text) * field // 12]
    _read(reader, _write(folder, text))


@pytest.mark.parametrize(
    ("reader", "text", "says"),
    [
        (read_kitti_poses, "1e200 0 0 0 0 1e200 0 0 0 0 1e200 0\n", "not a rotation"),
        (read_kitti_poses, "1 0 0 1e308 0 1 0 0 0 0 1 0\n", "positions are metres"),
        (read_tum, "0 0 0 0 1e200 1e200 0 1\n", "quaternion norm is over 1e\\+200"),
        (read_tum, "1e308 0 0 0 0 0 0 1\n-1e308 0 0 0 0 0 0 1\n", "TUM timestamps are seconds"),
        (read_tum, "0 1e308 1e308 1e308 0 0 0 1\n", "positions are metres"),
    ],
)
def test_extreme_numbers_are_one_line_without_overflow(folder, reader, text, says):
    path = _write(folder, text)
    with pytest.raises(DatasetError, match=says) as info:
        reader(path)
    assert str(info.value).startswith(f"{path}:1: ")


def test_a_folder_or_a_fifo_is_refused_without_waiting(tmp_path):
    fifo = tmp_path / "poses.txt"
    os.mkfifo(fifo)
    for reader in (read_kitti_poses, read_tum):
        with pytest.raises(DatasetError, match="is a folder, not a pose file"):
            reader(tmp_path)
        with pytest.raises(DatasetError, match="not a regular file"):
            reader(fifo)


def test_valid_files_still_read(folder):
    poses = read_kitti_poses(_write(folder, f"{KITTI_LINE}\n{KITTI_LINE}\n"))
    assert poses.shape == (2, 4, 4) and poses[1, 2, 3] == 2.0
    stamps, tum = read_tum(_write(folder, f"# t x y z qx qy qz qw\n{TUM_LINE}\n"))
    np.testing.assert_array_equal(stamps, [1000.5])
    np.testing.assert_allclose(tum[0, :3, 3], [0.5, -0.25, 2])


def test_the_command_line_reports_a_bad_pose_file_in_one_line(tmp_path, capsys):
    odometry = tmp_path / "odometry.txt"
    odometry.write_text("1e200 0 0 0 0 1e200 0 0 0 0 1e200 0\n")
    out = tmp_path / "run"
    assert main(["run", "--odometry", str(odometry), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"hippo-nav: error: {odometry}:1: ")
    assert "not a rotation" in err and not out.exists()
